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
   frames: Procrustes-aligned joint and vertex errors (mm) and the same unaligned. The fits run
   once per fit seed (`--seeds`), all from the same initial estimate; the means come with the
   lowest and highest of their per-seed values (the seed spread).
2. Error against run time: the presets on one clip (the first `flip` clip; every preset fits
   the same RUNTIME_FRAMES frames of it, spread evenly, so that `full` fits in a session on a
   CPU), their anytime curves, and the fit time from which each stays within 5% of the `full`
   preset's final L1 and joint error.
3. The stability sweep (stability.py).

Every fit goes through pipeline.fit.fit (what `harp fit` runs) with the curve recorder of
`harp fit --curve`; `--jobs N` runs N fits at once, each in a process of its own (executors.py).
Finished work is kept and skipped on a rerun; a stopped fit is resumed. Outputs in DIR: study.md
(tables in that order), study.json, plots/, and the runs (sequences/, fits/CLIP/seedS/,
results/seedS/, runtime/, stability/ or stability_fast/, logs/ of the worker processes).
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
from ..executors import Cell, CellFailure, run_cells
from .study_report import write_outputs
from .study_runs import finished_or_fitted, initialised, read_json, sequence_frame_count, write_json

CASES = ("init gt-noise", "init MediaPipe", "HARP-sil", "HARP-full", "HARP-known")
FIGURES = ("joint_mm", "vertex_mm", "joint_camera_mm", "vertex_camera_mm", "joint_end_over_min")
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
              seeds=(0,), jobs=1, threads=None, executor="local", address=None, **fit_options):
    """Run the study's sections into `out`; returns the study dict (also study.json/study.md).
    `fit_options` go to every fit (e.g. max_steps, resolution for small tests); --quick caps
    every stage at QUICK_STEPS steps and runs a small stability sweep (one case per kind, at
    most 4 steps per stage); `stability_scale` is the sweep's scale (stability.SCALES; default
    "fast", with --quick "tiny"); `stability_kinds` keeps the sweep's cases of those kinds.
    The refinement fits run once per fit seed in `seeds` (every seed from the same initial
    estimate); the run-time section's with the first. `jobs` fits run at once, each in a process
    of its own with `threads` torch threads, or with `executor` "ray" each a task on the Ray
    cluster at `address` (executors.py)."""
    out = Path(out)
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown:
        raise StudyError(f"unknown study section {unknown[0]!r}; choose from {', '.join(SECTIONS)}")
    seeds = tuple(dict.fromkeys(int(seed) for seed in seeds))
    if not seeds:
        raise StudyError("the study needs at least one seed")
    if quick:
        fit_options.setdefault("max_steps", QUICK_STEPS)
    selected = dataset_clips(dataset, clips) if {"refinement", "runtime"} & set(sections) else []
    study = {"dataset": str(dataset), "preset": preset, "quick": quick, "fit_options": fit_options,
             "seeds": list(seeds), "jobs": jobs, "sections": {}}
    started = time.time()
    cells, assemble = [], []
    cell_progress = progress if jobs <= 1 and executor == "local" else "none"   # workers draw no progress bars
    if "refinement" in sections:
        refinement_cells, gather = refinement_plan(selected, out, preset, seeds, log, fit_options, cell_progress)
        cells += refinement_cells
        assemble.append(("refinement", gather))
    if "runtime" in sections:
        flips = [clip for clip in selected if clip.motion == "flip"] or selected
        frames = {"max_frames": runtime_frames} if runtime_frames else {}
        runtime_cells, gather = runtime_plan(flips[0], out, runtime_presets, log,
                                             {**frames, "seed": seeds[0], **fit_options}, cell_progress)
        cells = runtime_cells[::-1] + cells      # the slowest preset (listed last) first: the workers end together
        assemble.append(("runtime", gather))
    if cells:
        try:
            run_cells(cells, jobs=jobs, threads=threads, log=log, logs=out / "logs", executor=executor,
                      address=address, ship="never")       # the cells share the study's sequences: one filesystem
        except CellFailure as failure:
            raise StudyError(f"{len(failure.failures)} of the study's fits failed (the rest is kept; rerun to "
                             f"resume): {failure}") from failure
    for name, gather in assemble:
        study["sections"][name] = gather()
    if "stability" in sections:
        scale = stability_scale or ("tiny" if quick else "fast")
        folder = out / ("stability" if scale == "tiny" else f"stability_{scale}")
        study["sections"]["stability"] = run_stability_sweep(folder, quick=quick, scale=scale, log=log,
                                                             kinds=stability_kinds)
    study["seconds"] = time.time() - started
    write_outputs(out, study)
    return study


# ----------------------------------------------------------------------------- 1. refinement

def refinement_plan(clips, out, preset, seeds, log, fit_options, progress="none"):
    """The refinement's cells (a clip and a fit seed each; a fingers clip after its identity's
    flip clip of the same seed, whose HARP-full fit its HARP-known takes) and a function that
    gathers their rows {clip, identity, motion, case, seed, joint_mm, vertex_mm, joint_camera_mm,
    vertex_camera_mm, fit_seconds} with their means per motion and overall and the spread of
    those means over the seeds. The initial estimates are made here, once per clip."""
    ordered = sorted(clips, key=lambda clip: clip.motion != "flip")   # flip fits first: HARP-known needs them
    starts = {}
    for number, clip in enumerate(ordered):
        log(f"[{number + 1}/{len(ordered)}] initial estimates of {clip.name}")
        starts[clip.name] = _initial_estimates(clip, out, log)
    flips = {clip.identity: clip for clip in ordered if clip.motion == "flip"}
    cells = []
    for seed in seeds:
        for clip in ordered:
            flip = flips.get(clip.identity) if clip.motion == "fingers" else None
            known = None if flip is None else str(_fits_folder(out, flip, seed) / "full")
            if clip.motion == "fingers" and flip is None:
                log(f"{clip.name}: no flip clip of {clip.identity} in the study, so no HARP-known")
            cells.append(Cell(_cell_name(clip, seed), refine_clip,
                              dict(clip=clip, seed=seed, out=out, preset=preset, starts=starts[clip.name],
                                   known_appearance=known, fit_options=fit_options, progress=progress),
                              after=() if flip is None else (_cell_name(flip, seed),)))

    def gather():
        rows = []
        for seed in seeds:
            for clip in ordered:
                rows += read_json(_result_file(out, clip, seed))
        return {"rows": rows, "means": _means(rows), "per_clip": _per_clip(rows), "seeds": list(seeds),
                "cases": list(CASES)}

    return cells, gather


def _cell_name(clip, seed):
    return f"{clip.name}_seed{seed}"


def _fits_folder(out, clip, seed):
    return Path(out) / "fits" / clip.name / f"seed{seed}"


def _result_file(out, clip, seed):
    return Path(out) / "results" / f"seed{seed}" / f"{clip.name}.json"


def _initial_estimates(clip, out, log):
    """{"gt-noise": folder, "mediapipe": folder or None, "mediapipe_failure": reason or None}."""
    sequences = Path(out) / "sequences" / clip.name
    noisy = initialised(clip.folder, sequences / "gt-noise", "gt-noise", log)
    mode = read_initial_estimate(noisy).mode          # the true template mode (from gt.npz)
    try:
        mediapipe = initialised(clip.folder, sequences / "mediapipe", "mediapipe", log, mode=mode)
        return {"gt-noise": noisy, "mediapipe": mediapipe, "mediapipe_failure": None}
    except ValueError as error:      # no hand found, say: the row says so
        return {"gt-noise": noisy, "mediapipe": None, "mediapipe_failure": str(error)}


def refine_clip(clip, seed, out, preset, starts, known_appearance, fit_options, log, progress="none"):
    """One cell: the clip's HARP-sil, HARP-full (and HARP-known) fits with fit seed `seed`, scored;
    its rows are written to results/seedS/CLIP.json (read back, not fitted, when there)."""
    result_file = _result_file(out, clip, seed)
    if result_file.is_file():
        return read_json(result_file)
    noisy, fits = starts["gt-noise"], _fits_folder(out, clip, seed)
    settings = settings_for(preset, sequence_frame_count(noisy))
    geometry, joint, _ = settings.steps
    runs = {"HARP-sil": dict(steps=(geometry + joint, 0, 0)), "HARP-full": {}}
    if known_appearance is not None:
        runs["HARP-known"] = dict(known_appearance=known_appearance)
    rows, frames = [], None
    for case, options in runs.items():
        folder = fits / {"HARP-sil": "sil", "HARP-full": "full", "HARP-known": "known"}[case]
        report = finished_or_fitted(noisy, folder, log, progress=progress, preset=preset, seed=seed, **options,
                                    **fit_options)
        errors = evaluate_poses(folder, noisy)
        frames = np.asarray(errors["frames"])
        rows.append({**_row(clip, case, seed, errors["fit"], report["total_seconds"]), **_curve_end(folder)})
        if case == "HARP-full":
            rows.insert(0, _row(clip, "init gt-noise", seed, errors["initial"], None))
    frames = frames if frames is not None else select_frames(sequence_frame_count(noisy), settings.max_frames)
    if starts["mediapipe"] is not None:
        rows.insert(1, _row(clip, "init MediaPipe", seed, PoseScorer(starts["mediapipe"]).initial_errors(frames),
                            None))
    else:
        rows.insert(1, {**_row(clip, "init MediaPipe", seed, {"joints": {}}, None),
                        "note": starts["mediapipe_failure"]})
    write_json(result_file, rows)
    return rows


def _curve_end(folder):
    """The joint error at the fit's end over its curve's lowest (issue 34: at most 1.05)."""
    joints = [point["joint_mm"] for point in read_curve(folder)["points"] if point.get("joint_mm") is not None]
    return {"joint_end_over_min": joints[-1] / min(joints) if joints and min(joints) > 0 else None}


def _row(clip, case, seed, errors, seconds):
    figures = {"joint_mm": errors["joints"].get("procrustes_mm_mean"),
               "joint_camera_mm": errors["joints"].get("camera_mm_mean"),
               "vertex_mm": errors.get("vertices", {}).get("procrustes_mm_mean"),
               "vertex_camera_mm": errors.get("vertices", {}).get("camera_mm_mean"), "joint_end_over_min": None}
    return {"clip": clip.name, "identity": clip.identity, "motion": clip.motion, "case": case, "seed": seed,
            **figures, "fit_seconds": seconds}


def _means(rows):
    """{motion or "all": {case: {figure: mean, figure_spread: [lowest, highest] of the per-seed
    means, "clips": count}}} over the clips that have the case; the spread is None with one seed."""
    means = {}
    for motion in sorted({row["motion"] for row in rows}) + ["all"]:
        chosen = [row for row in rows if motion == "all" or row["motion"] == motion]
        means[motion] = {}
        for case in CASES:
            of_case = [row for row in chosen if row["case"] == case]
            if of_case:
                means[motion][case] = _summary(of_case)
                means[motion][case]["clips"] = len({row["clip"] for row in of_case})
    return means


def _per_clip(rows):
    """The rows of each clip and case over the seeds: [{clip, motion, case, figure: mean,
    figure_spread: [lowest, highest] or None, fit_seconds: mean, seeds}]."""
    keys = list(dict.fromkeys((row["clip"], row["case"]) for row in rows))
    table = []
    for clip, case in keys:
        of_cell = [row for row in rows if row["clip"] == clip and row["case"] == case]
        notes = sorted({row["note"] for row in of_cell if row.get("note")})
        table.append({"clip": clip, "motion": of_cell[0]["motion"], "case": case, **_summary(of_cell),
                      "fit_seconds": _mean([row.get("fit_seconds") for row in of_cell]),
                      **({"note": notes[0]} if notes else {})})
    return table


def _summary(rows):
    """Each figure's mean over `rows`, and the lowest and highest of its means per seed."""
    seeds = sorted({row.get("seed", 0) for row in rows})
    summary = {"seeds": len(seeds)}
    for figure in FIGURES:
        summary[figure] = _mean([row[figure] for row in rows])
        per_seed = [_mean([row[figure] for row in rows if row.get("seed", 0) == seed]) for seed in seeds]
        per_seed = [value for value in per_seed if value is not None]
        summary[f"{figure}_spread"] = [min(per_seed), max(per_seed)] if len(per_seed) > 1 else None
    return summary


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


# ----------------------------------------------------------------------------- 2. run time

def runtime_plan(clip, out, presets, log, fit_options, progress="none"):
    """The run-time section's cells (each preset fitted to `clip` from gt-noise, with its curve)
    and a function that gathers them: the fit time from which each stays within WITHIN of the
    `full` preset's (or the last preset's) final L1 and joint error."""
    noisy = initialised(clip.folder, out / "sequences" / clip.name / "gt-noise", "gt-noise", log)
    folders = {preset: out / "runtime" / clip.name / preset for preset in presets}
    cells = [Cell(f"runtime_{clip.name}_{preset}", fit_runtime_preset,
                  dict(sequence=noisy, folder=folder, preset=preset, fit_options=fit_options, progress=progress))
             for preset, folder in folders.items()]
    return cells, lambda: runtime_section(clip, folders, fit_options)


def fit_runtime_preset(sequence, folder, preset, fit_options, log, progress="none"):
    log(f"run time: preset {preset} into {folder}")
    finished_or_fitted(sequence, folder, log, progress=progress, preset=preset, **fit_options)
    return str(folder)


def runtime_section(clip, folders, fit_options):
    curves = {preset: read_curve(folder)["points"] for preset, folder in folders.items()}
    presets = list(folders)
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
                      "seconds_to_joint": reached.get("joint_mm"), "seconds_to_both": both,
                      **_curve_end(folders[preset])})
    return {"clip": clip.name, "frames": fit_options.get("max_frames"), "seed": fit_options.get("seed"),
            "reference": reference, "within": WITHIN, "targets": targets, "table": table,
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
