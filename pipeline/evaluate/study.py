"""`harp study DATASET --out DIR`: the pose-refinement study (appendix E.4) and the error against
run time of the presets, over a folder of synthetic clips as synth/dataset.py writes them
(`IDENTITY_MOTION_VIEW_LIGHTING/`), and the stability sweep (stability.py).

1. Pose refinement, per clip, from the initial estimate `gt-noise` (the ground truth with 10
   degrees on every joint and 1 cm on the wrist, the appendix-like level; every fit starts
   there): the initial estimates (`gt-noise`, and MediaPipe's, in the true template mode);
   HARP-sil (geometry terms only: the alignment and a geometry stage as long as HARP-full's
   geometry and joint stages together); HARP-full (the preset); HARP-known (the `fingers` clip
   with shape, displacements, textures and light of the same identity's `flip` HARP-full fit,
   frozen: only per-frame poses and translations move, all terms on). Errors on the fitted
   frames: Procrustes-aligned joint and vertex errors (mm) and the same unaligned.
2. Error against run time: the presets on one clip (the first `flip` clip; every preset fits
   the same RUNTIME_FRAMES frames of it, spread evenly, so that `full` fits in a session on a
   CPU), their anytime curves, and the fit time from which each stays within 5% of the `full`
   preset's final L1 and joint error.
3. The stability sweep (stability.py).

Every fit goes through pipeline.fit.fit (what `harp fit` runs) with the curve recorder of
`harp fit --curve`. Finished work is kept and skipped on a rerun; a stopped fit is resumed.
Outputs in DIR: study.md (tables in that order), study.json, plots/, and the runs (sequences/,
fits/, runtime/, stability/ or stability_fast/).
"""
from __future__ import annotations

import dataclasses
import fnmatch
import math
import time
from pathlib import Path

import numpy as np

from ..fit import settings_for
from ..fit.frames import select_frames
from ..formats.fit_curve import read_curve
from ..formats.initial_estimate import read_initial_estimate
from .poses import PoseScorer, evaluate_poses
from .stability import run_stability_sweep
from .study_report import write_outputs
from .study_runs import finished_or_fitted, initialised, read_json, sequence_frame_count, write_json

CASES = ("init gt-noise", "init MediaPipe", "HARP-sil", "HARP-full", "HARP-known")
FIGURES = ("joint_mm", "vertex_mm", "joint_camera_mm", "vertex_camera_mm")
RUNTIME_PRESETS = ("preview", "fast", "full", "paper")
RUNTIME_FRAMES = 30     # frames every preset fits in the run-time section (0: each preset's own)
WITHIN = 0.05           # "within 5% of the full preset's final figure"
QUICK_STEPS = 30        # --quick: steps per stage at most
SECTIONS = ("refinement", "runtime", "stability")


class StudyError(ValueError):
    """The study cannot run (one-line message)."""


@dataclasses.dataclass(frozen=True)
class Clip:
    name: str
    folder: Path
    identity: str
    motion: str


def dataset_clips(dataset, pattern=None):
    """The clips of a dataset folder (sequence folders named IDENTITY_MOTION_VIEW_LIGHTING with
    ground truth), optionally filtered by a comma-separated list of shell patterns."""
    dataset = Path(dataset)
    if not dataset.is_dir():
        raise StudyError(f"dataset folder not found: {dataset}")
    patterns = [p.strip() for p in pattern.split(",")] if pattern else ["*"]
    clips = []
    for folder in sorted(p for p in dataset.iterdir() if (p / "sequence.json").is_file() and (p / "gt.npz").is_file()):
        parts = folder.name.split("_")
        if len(parts) >= 2 and any(fnmatch.fnmatch(folder.name, p) for p in patterns):
            clips.append(Clip(folder.name, folder, parts[0], parts[1]))
    if not clips:
        raise StudyError(f"no synthetic clips (IDENTITY_MOTION_... folders with gt.npz) in {dataset}"
                         + (f" matching {pattern}" if pattern else ""))
    return clips


def run_study(dataset, out, clips=None, quick=False, preset="fast", sections=SECTIONS, progress="none", log=print,
              runtime_presets=RUNTIME_PRESETS, runtime_frames=RUNTIME_FRAMES, stability_scale=None, stability_kinds=None,
              **fit_options):
    """Run the study's sections into `out`; returns the study dict (also study.json/study.md).
    `fit_options` go to every fit (e.g. max_steps, resolution for small tests); --quick caps
    every stage at QUICK_STEPS steps and runs a small stability sweep (one case per kind, at
    most 4 steps per stage); `stability_scale` is the sweep's scale (stability.SCALES; default
    "fast", with --quick "tiny"); `stability_kinds` keeps the sweep's cases of those kinds."""
    out = Path(out)
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown:
        raise StudyError(f"unknown study section {unknown[0]!r}; choose from {', '.join(SECTIONS)}")
    if quick:
        fit_options.setdefault("max_steps", QUICK_STEPS)
    selected = dataset_clips(dataset, clips) if {"refinement", "runtime"} & set(sections) else []
    study = {"dataset": str(dataset), "preset": preset, "quick": quick, "fit_options": fit_options, "sections": {}}
    started = time.time()
    if "refinement" in sections:
        study["sections"]["refinement"] = refinement(selected, out, preset, progress, log, fit_options)
    if "runtime" in sections:
        flips = [clip for clip in selected if clip.motion == "flip"] or selected
        frames = {"max_frames": runtime_frames} if runtime_frames else {}
        study["sections"]["runtime"] = runtime(flips[0], out, runtime_presets, progress, log,
                                               {**frames, **fit_options})
    if "stability" in sections:
        scale = stability_scale or ("tiny" if quick else "fast")
        folder = out / ("stability" if scale == "tiny" else f"stability_{scale}")
        study["sections"]["stability"] = run_stability_sweep(folder, quick=quick, scale=scale, log=log,
                                                             kinds=stability_kinds)
    study["seconds"] = time.time() - started
    write_outputs(out, study)
    return study


# ----------------------------------------------------------------------------- 1. refinement

def refinement(clips, out, preset, progress, log, fit_options):
    """Rows {clip, identity, motion, case, joint_mm, vertex_mm, joint_camera_mm, vertex_camera_mm,
    fit_seconds} and their means per motion and overall."""
    rows = []
    full_fits = {}
    ordered = sorted(clips, key=lambda clip: clip.motion != "flip")   # flip fits first: HARP-known needs them
    for number, clip in enumerate(ordered):
        log(f"[{number + 1}/{len(ordered)}] pose refinement on {clip.name}")
        result_file = out / "results" / f"{clip.name}.json"
        if result_file.is_file():
            clip_rows = read_json(result_file)
        else:
            clip_rows = _refine_clip(clip, out, preset, progress, log, fit_options, full_fits)
            write_json(result_file, clip_rows)
        if clip.motion == "flip":
            full_fits[clip.identity] = out / "fits" / clip.name / "full"
        rows += clip_rows
    return {"rows": rows, "means": _means(rows), "cases": list(CASES)}


def _refine_clip(clip, out, preset, progress, log, fit_options, full_fits):
    sequences, fits = out / "sequences" / clip.name, out / "fits" / clip.name
    noisy = initialised(clip.folder, sequences / "gt-noise", "gt-noise", log)
    mode = read_initial_estimate(noisy).mode          # the true template mode (from gt.npz)
    try:
        mediapipe = initialised(clip.folder, sequences / "mediapipe", "mediapipe", log, mode=mode)
    except ValueError as error:      # no hand found, say: the row says so
        mediapipe, failure = None, str(error)
    settings = settings_for(preset, sequence_frame_count(noisy))
    geometry, joint, _ = settings.steps
    runs = {"HARP-sil": dict(steps=(geometry + joint, 0, 0)), "HARP-full": {}}
    if clip.motion == "fingers":
        if clip.identity in full_fits:
            runs["HARP-known"] = dict(known_appearance=full_fits[clip.identity])
        else:
            log(f"{clip.name}: no flip clip of {clip.identity} in the study, so no HARP-known")
    rows, frames = [], None
    for case, options in runs.items():
        folder = fits / {"HARP-sil": "sil", "HARP-full": "full", "HARP-known": "known"}[case]
        report = finished_or_fitted(noisy, folder, log, progress=progress, preset=preset, **options, **fit_options)
        errors = evaluate_poses(folder, noisy)
        frames = np.asarray(errors["frames"])
        rows.append(_row(clip, case, errors["fit"], report["total_seconds"]))
        if case == "HARP-full":
            rows.insert(0, _row(clip, "init gt-noise", errors["initial"], None))
    frames = frames if frames is not None else select_frames(sequence_frame_count(noisy), settings.max_frames)
    if mediapipe is not None:
        rows.insert(1, _row(clip, "init MediaPipe", PoseScorer(mediapipe).initial_errors(frames), None))
    else:
        rows.insert(1, {**_row(clip, "init MediaPipe", {"joints": {}}, None), "note": failure})
    return rows


def _row(clip, case, errors, seconds):
    figures = {"joint_mm": errors["joints"].get("procrustes_mm_mean"),
               "joint_camera_mm": errors["joints"].get("camera_mm_mean"),
               "vertex_mm": errors.get("vertices", {}).get("procrustes_mm_mean"),
               "vertex_camera_mm": errors.get("vertices", {}).get("camera_mm_mean")}
    return {"clip": clip.name, "identity": clip.identity, "motion": clip.motion, "case": case, **figures,
            "fit_seconds": seconds}


def _means(rows):
    """{motion or "all": {case: {figure: mean}}} over the clips that have the case."""
    means = {}
    for motion in sorted({row["motion"] for row in rows}) + ["all"]:
        chosen = [row for row in rows if motion == "all" or row["motion"] == motion]
        means[motion] = {}
        for case in CASES:
            of_case = [row for row in chosen if row["case"] == case]
            if of_case:
                means[motion][case] = {figure: _mean([row[figure] for row in of_case]) for figure in FIGURES}
                means[motion][case]["clips"] = len(of_case)
    return means


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


# ----------------------------------------------------------------------------- 2. run time

def runtime(clip, out, presets, progress, log, fit_options):
    """Each preset fitted to `clip` (gt-noise initialisation) with its curve; the fit time from
    which each stays within WITHIN of the `full` preset's (or the last preset's) final L1 and
    joint error."""
    noisy = initialised(clip.folder, out / "sequences" / clip.name / "gt-noise", "gt-noise", log)
    folders = {}
    for preset in presets:
        log(f"run time: preset {preset} on {clip.name}")
        folders[preset] = out / "runtime" / clip.name / preset
        finished_or_fitted(noisy, folders[preset], log, progress=progress, preset=preset, **fit_options)
    curves = {preset: read_curve(folder)["points"] for preset, folder in folders.items()}
    reference = "full" if "full" in curves else presets[-1]
    final = curves[reference][-1]
    targets = {name: final[name] * (1 + WITHIN) for name in ("l1_mean", "joint_mm") if final.get(name) is not None}
    table = []
    for preset, points in curves.items():
        reached = {name: _settled_time(points, lambda p, n=name: _at_most(p, n, target))
                   for name, target in targets.items()}
        both = _settled_time(points, lambda p: all(_at_most(p, n, t) for n, t in targets.items()))
        last = points[-1]
        table.append({"preset": preset, "fit_seconds": last["fit_seconds"], "final_l1": last.get("l1_mean"),
                      "final_joint_mm": last.get("joint_mm"), "seconds_to_l1": reached.get("l1_mean"),
                      "seconds_to_joint": reached.get("joint_mm"), "seconds_to_both": both})
    return {"clip": clip.name, "frames": fit_options.get("max_frames"), "reference": reference, "within": WITHIN,
            "targets": targets, "table": table,
            "fits": {preset: str(folder) for preset, folder in folders.items()}}


def _at_most(point, name, target):
    value = point.get(name)
    return value is not None and math.isfinite(value) and value <= target


def _settled_time(points, condition):
    """The fit time from which `condition` holds at every later point of the curve (a figure
    that dips under its target and rises again has not reached it), or None."""
    settled = None
    for point in points:
        settled = (settled if settled is not None else point["fit_seconds"]) if condition(point) else None
    return settled
