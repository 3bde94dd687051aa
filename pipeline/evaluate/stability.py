"""The study's stability sweep ("stiff and extreme cases"): the fit on tiny exact clips
(exact_clips.py: 4 frames, 64 px, started from `gt-noise`) under one change at a time:

    weights      every regularisation weight (all but silhouette and photometric) x0.01, x0.1,
                 x10, x100
    rates        every learning rate x0.1 and x10, and all of them x10
    poses        a fist, fingers bent 10-20 degrees past their limits, crossed fingers
    masks        heavy mask noise (ragged, jittered outlines, holes and blobs)

For each: whether it finished, how often it rolled back, its non-finite events, the final loss
and its final Procrustes-aligned joint error against the truth (and the initial one). Nothing
may end non-finite; a run that had to roll back says so.
"""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from synth.motions import RELAXED

from ..fit import fit
from ..fit.settings import WEIGHTS, FitSettings
from ..formats import sequence_folder as seq
from ..handmodel.poses import NAMED_POSES
from ..init import initialise_sequence
from .exact_clips import hyperextended_pose, write_clip
from .poses import evaluate_poses
from .study_runs import read_json, write_json

DATA_TERMS = ("silhouette", "photometric")
WEIGHT_SCALES = (0.01, 0.1, 10.0, 100.0)
RATE_SCALES = (0.1, 10.0)
FIT_OPTIONS = dict(progress="none", texture_size=64, batch_size=2, shadows="off", resolution=64, device="cpu")
STEPS, QUICK_STEPS = 10, 4
LEARNING_RATES = tuple(f.name for f in FitSettings.__dataclass_fields__.values() if f.name.startswith("lr_"))


def sweep_cases(quick=False):
    """(kind, name, clip name, settings overrides) of every run; --quick keeps one per kind."""
    cases = []
    terms = [name for name in WEIGHTS if name not in DATA_TERMS]
    for term in terms:
        for scale in WEIGHT_SCALES:
            weights = {name: value * (scale if name == term else 1.0) for name, value in WEIGHTS.items()}
            cases.append(("weights", f"{term} x{scale:g}", "relaxed", {"weights": weights}))
    defaults = FitSettings()
    for rate in LEARNING_RATES:
        for scale in RATE_SCALES:
            cases.append(("rates", f"{rate} x{scale:g}", "relaxed", {rate: getattr(defaults, rate) * scale}))
    cases.append(("rates", "all x10", "relaxed", {rate: getattr(defaults, rate) * 10 for rate in LEARNING_RATES}))
    cases += [("poses", "fist", "fist", {}), ("poses", "hyper-extended", "hyperextended", {}),
              ("poses", "crossed fingers", "crossed", {}), ("masks", "heavy mask noise", "noisy_masks", {})]
    if quick:
        kinds = {}
        for case in cases:
            kinds.setdefault(case[0], case)
        cases = list(kinds.values())
    return cases


def write_sweep_clip(folder, name):
    """The sweep's clips: exact renders of a pose (relaxed; a fist, hyper-extended or crossed
    fingers seen from an angle) and the relaxed clip with heavy mask noise."""
    poses = {"relaxed": (RELAXED, 0.0), "fist": (NAMED_POSES["fist"], 60.0),
             "hyperextended": (hyperextended_pose(), 70.0), "crossed": (NAMED_POSES["crossed"], 20.0),
             "noisy_masks": (RELAXED, 0.0)}
    pose, azimuth = poses[name]
    info = write_clip(folder, pose, size=64, azimuth=azimuth)
    if name == "noisy_masks":
        rng = np.random.default_rng(0)
        for index in range(info.frame_count):
            path = seq.mask_path(folder, info, index)
            seq.write_png(path, noisy_mask(seq.read_mask(path), rng))
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


def noisy_mask(mask, rng, jitter_px=2, band_px=3, flip=0.3, blobs=3):
    """A mask (H, W) bool made ragged: grown or shrunk by up to `jitter_px`, a `flip` share of
    the pixels within `band_px` of the outline inverted, and `blobs` small discs added or cut
    out. Returns uint8 (255 = hand); never empty."""
    mask = mask.astype(np.uint8)
    radius = int(rng.integers(-jitter_px, jitter_px + 1))
    if radius:
        kernel = np.ones((2 * abs(radius) + 1,) * 2, np.uint8)
        mask = cv2.dilate(mask, kernel) if radius > 0 else cv2.erode(mask, kernel)
    kernel = np.ones((2 * band_px + 1,) * 2, np.uint8)
    band = (cv2.dilate(mask, kernel) - cv2.erode(mask, kernel)).astype(bool)
    mask = np.where(band & (rng.random(mask.shape) < flip), 1 - mask, mask)
    height, width = mask.shape
    for _ in range(blobs):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        cv2.circle(mask, centre, int(rng.integers(2, 5)), int(rng.integers(0, 2)), -1)
    if mask.sum() < seq.MIN_MASK_PIXELS:
        mask[height // 2 - 3:height // 2 + 3, width // 2 - 3:width // 2 + 3] = 1
    return mask * 255


def run_stability_sweep(out, quick=False, log=print):
    """Run the sweep into `out` (clips/, fits/, one result file per case, kept on a rerun);
    returns {"rows": [...], "all_finite": bool}."""
    out = Path(out)
    rows = []
    cases = sweep_cases(quick)
    for number, (kind, name, clip_name, overrides) in enumerate(cases):
        key = f"{kind}-{name}".replace(" ", "_")
        result_file = out / "results" / f"{key}.json"
        if result_file.is_file():
            rows.append(read_json(result_file))
            continue
        log(f"[{number + 1}/{len(cases)}] stability: {kind}, {name}")
        clip = out / "clips" / clip_name
        if not (clip / "init.npz").is_file():
            write_sweep_clip(clip, clip_name)
        row = _run_case(kind, name, clip, out / "fits" / key, overrides, QUICK_STEPS if quick else STEPS)
        write_json(result_file, row)
        rows.append(row)
    return {"rows": rows, "all_finite": all(row["finite"] for row in rows), "steps_per_stage": QUICK_STEPS if quick
            else STEPS}


def _run_case(kind, name, clip, folder, overrides, steps):
    row = {"kind": kind, "case": name, "finished": False, "error": None, "rollbacks": 0, "non_finite": 0,
           "final_loss": None, "finite": False, "joint_mm": None, "initial_joint_mm": None, "events": []}
    try:
        report = fit(clip, folder, max_steps=steps, **FIT_OPTIONS, **overrides)
    except Exception as error:  # a crash is a finding of the sweep, not its end
        row["error"] = f"{type(error).__name__}: {error}"
        return row
    final = list(report["final_losses"].values())[-1]["loss"] if report["final_losses"] else math.nan
    errors = evaluate_poses(folder, clip)
    row.update(finished=True, events=report["events"],
               rollbacks=sum("rolled back" in event for event in report["events"]),
               non_finite=sum("non-finite" in event for event in report["events"]), final_loss=final,
               joint_mm=errors["fit"]["joints"]["procrustes_mm_mean"],
               initial_joint_mm=errors["initial"]["joints"]["procrustes_mm_mean"],
               iou_min=report["metrics"]["silhouette_iou_min"], psnr_mean=report["metrics"]["psnr_mean"])
    row["finite"] = all(isinstance(v, float) and math.isfinite(v)
                        for v in (row["final_loss"], row["joint_mm"], row["psnr_mean"]))
    return row
