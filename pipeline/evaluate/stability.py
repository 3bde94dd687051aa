"""The study's stability sweep ("stiff and extreme cases"): the fit under one change at a
time, started from `gt-noise`, at one of two scales (SweepScale):

    tiny    exact 4-frame 64 px clips, 10 steps per stage (a few minutes: CI's --quick)
    fast    exact 30-frame 256 px clips at `fast`'s whole schedule, each fit's curve recorded
            (the scale users run: several hours on one core, resumable case by case)

The cases (sweep_cases):

    baseline     the unperturbed fit every other case is compared with
    weights      every regularisation weight (all but silhouette and photometric) x0.01, x0.1,
                 x10, x100
    rates        every learning rate x0.1 and x10, and all of them x10
    poses        a fist in self-contact, fingers bent 10-20 degrees past their limits, crossed
                 fingers
    shapes       the shape at +3 and -3 standard deviations (every shape coefficient)
    framing      a hand 50 px across; a hand 600 px across (a 720 px image); the fingers cut by
                 the image's top edge
    inputs       heavy mask noise (ragged, jittered outlines, holes and blobs); masks with holes;
                 every third frame under-exposed (x0.25) or over-exposed (x3, clipped); a clip of
                 1 frame and of 3 frames

For each: whether it finished, how often it rolled back, its non-finite events, the final loss,
the Procrustes-aligned joint error against the truth (and the initial one), the fitted frames'
L1, both also as a ratio to the baseline's, and whether its input is degraded (less or worse
data than the baseline's: its error may rise; every other case should stay within 20% of the
baseline's joint error). Nothing may end non-finite; a run that had to roll back says so.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import NamedTuple

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
LEARNING_RATES = tuple(f.name for f in FitSettings.__dataclass_fields__.values() if f.name.startswith("lr_"))
WITHIN_BASELINE = 1.2      # a case with undegraded input should end within 20% of the baseline's joint error


@dataclasses.dataclass(frozen=True)
class SweepScale:
    name: str
    frames: int
    size: int                 # image side of the clips, pixels
    steps: int | None         # steps per stage at most; None: the preset's whole schedule
    fit_options: dict
    curves: bool              # record each fit's curve (curve.json)

    def describe(self):
        steps = f"{self.steps} steps per stage" if self.steps else f"`{self.fit_options['preset']}`'s whole schedule"
        return f"exact {self.size} px clips of {self.frames} frames, {steps}, from `gt-noise`"


SCALES = {
    "tiny": SweepScale("tiny", frames=4, size=64, steps=10, curves=False,
                       fit_options=dict(texture_size=64, batch_size=2, shadows="off", resolution=64)),
    "fast": SweepScale("fast", frames=30, size=256, steps=None, curves=True, fit_options=dict(preset="fast")),
}


class SweepCase(NamedTuple):
    kind: str
    name: str
    clip: str              # a key of CLIPS
    overrides: dict        # FitSettings overrides
    degraded: bool         # the input holds less or worse data than the baseline's

    @property
    def key(self):
        return f"{self.kind}-{self.name}".replace(" ", "_")


def sweep_cases(quick=False):
    """Every case of the sweep: the baseline, the clips' cases, the rates, the weights (the order
    they run in: the longest kind last); --quick keeps the first of each kind."""
    cases = [SweepCase("baseline", "unperturbed", "relaxed", {}, False)]
    cases += [SweepCase(kind, name, clip, {}, degraded) for kind, name, clip, degraded in CLIP_CASES]
    defaults = FitSettings()
    for rate in LEARNING_RATES:
        for scale in RATE_SCALES:
            cases.append(SweepCase("rates", f"{rate} x{scale:g}", "relaxed", {rate: getattr(defaults, rate) * scale},
                                   False))
    cases.append(SweepCase("rates", "all x10", "relaxed",
                           {rate: getattr(defaults, rate) * 10 for rate in LEARNING_RATES}, False))
    for term in (name for name in WEIGHTS if name not in DATA_TERMS):
        for scale in WEIGHT_SCALES:
            weights = {name: value * (scale if name == term else 1.0) for name, value in WEIGHTS.items()}
            cases.append(SweepCase("weights", f"{term} x{scale:g}", "relaxed", {"weights": weights}, False))
    if quick:
        kinds = {}
        for case in cases:
            kinds.setdefault(case.kind, case)
        cases = list(kinds.values())
    return cases


# (kind, case, clip, degraded input) of the cases that change the clip, not the settings
CLIP_CASES = (
    ("poses", "fist", "fist", False),
    ("poses", "hyper-extended", "hyperextended", False),
    ("poses", "crossed fingers", "crossed", False),
    ("shapes", "shape +3 sd", "shape_plus3", False),
    ("shapes", "shape -3 sd", "shape_minus3", False),
    ("framing", "hand 50 px across", "small_hand", True),
    ("framing", "hand 600 px across", "large_hand", False),
    ("framing", "fingers cut by the edge", "cut_by_edge", True),
    ("inputs", "heavy mask noise", "noisy_masks", True),
    ("inputs", "masks with holes", "mask_holes", True),
    ("inputs", "under-exposed frames", "underexposed", True),
    ("inputs", "over-exposed frames", "overexposed", True),
    ("inputs", "1 frame", "one_frame", True),
    ("inputs", "3 frames", "three_frames", True),
)


def _clip_spec(name, scale):
    """write_clip's arguments for the clip `name` at `scale`, and what is done to it afterwards."""
    frames, size = scale.frames, scale.size
    spec = dict(pose=RELAXED, frames=frames, size=size)
    changes = {
        "relaxed": {}, "noisy_masks": {}, "mask_holes": {}, "underexposed": {}, "overexposed": {},
        "fist": dict(pose=NAMED_POSES["fist"], azimuth=60.0),
        "hyperextended": dict(pose=hyperextended_pose(), azimuth=70.0),
        "crossed": dict(pose=NAMED_POSES["crossed"], azimuth=20.0),
        "shape_plus3": dict(betas=3.0),
        "shape_minus3": dict(betas=-3.0),
        "small_hand": dict(hand_px=min(50, int(0.8 * size))),
        # 600 px where the working images are large enough to show it; the tiny scale keeps the ratio
        "large_hand": dict(size=720, hand_px=600) if size >= 256 else dict(size=int(1.2 * size), hand_px=size),
        "cut_by_edge": dict(shift=(0.0, -0.35)),
        "one_frame": dict(frames=1),
        "three_frames": dict(frames=3),
    }
    if name not in changes:
        raise KeyError(f"no sweep clip {name!r}")
    spec.update(changes[name])
    return spec


def write_sweep_clip(folder, name, scale):
    """The sweep's clip `name` at `scale`: an exact render (exact_clips.write_clip), then the
    masks or frames spoilt as the case asks, then the `gt-noise` start."""
    spec = _clip_spec(name, scale)
    info = write_clip(folder, spec.pop("pose"), **spec)
    rng = np.random.default_rng(0)
    for index in range(info.frame_count):
        if name in ("noisy_masks", "mask_holes"):
            path = seq.mask_path(folder, info, index)
            spoil = noisy_mask if name == "noisy_masks" else holed_mask
            seq.write_png(path, spoil(seq.read_mask(path), rng))
        elif name in ("underexposed", "overexposed") and index % 3 == 1:
            path = seq.frame_path(folder, info, index)
            gain = 0.25 if name == "underexposed" else 3.0
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            cv2.imwrite(str(path), np.clip(image.astype(np.float32) * gain, 0, 255).round().astype(np.uint8))
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
    return _never_empty(mask) * 255


def holed_mask(mask, rng, holes=4, radius_share=0.06):
    """A mask (H, W) bool with `holes` discs cut out of the hand, each `radius_share` of the
    hand's height across (a segmenter that lost a patch of skin). Returns uint8 (255 = hand)."""
    mask = mask.astype(np.uint8)
    rows, columns = np.nonzero(mask)
    if not len(rows):
        return _never_empty(mask) * 255
    radius = max(1, int(radius_share * (rows.max() - rows.min() + 1)))
    for pick in rng.choice(len(rows), size=holes, replace=False):
        cv2.circle(mask, (int(columns[pick]), int(rows[pick])), radius, 0, -1)
    return _never_empty(mask) * 255


def _never_empty(mask):
    if mask.sum() < seq.MIN_MASK_PIXELS:
        height, width = mask.shape
        mask[height // 2 - 3:height // 2 + 3, width // 2 - 3:width // 2 + 3] = 1
    return mask


def run_stability_sweep(out, quick=False, scale="tiny", log=print, cases=None, kinds=None):
    """Run the sweep at `scale` (a SCALES key) into `out` (clips/, fits/, one result file per
    case, kept on a rerun); `cases` (SweepCase list) replaces sweep_cases(quick), `kinds` keeps
    the cases of those kinds only. Returns {"rows": [...], "all_finite": bool, "scale": ...,
    "description": ...}."""
    out, scale = Path(out), SCALES[scale]
    steps = min(4, scale.steps or 4) if quick else scale.steps
    rows = []
    cases = sweep_cases(quick) if cases is None else cases
    if kinds:
        unknown = set(kinds) - {case.kind for case in sweep_cases()}
        if unknown:
            raise ValueError(f"no stability cases of kind {sorted(unknown)[0]!r}")
        cases = [case for case in cases if case.kind in kinds]
    for number, case in enumerate(cases):
        result_file = out / "results" / f"{case.key}.json"
        if result_file.is_file():
            rows.append(read_json(result_file))
            continue
        log(f"[{number + 1}/{len(cases)}] stability ({scale.name}): {case.kind}, {case.name}")
        clip = out / "clips" / case.clip
        if not (clip / "init.npz").is_file():
            write_sweep_clip(clip, case.clip, scale)
        row = _run_case(case, clip, out / "fits" / case.key, steps, scale)
        write_json(result_file, row)
        rows.append(row)
    _compare_with_baseline(rows)
    description = scale.describe() if steps == scale.steps else f"{scale.describe()} (capped at {steps} steps)"
    return {"rows": rows, "all_finite": all(row["finite"] for row in rows), "scale": scale.name,
            "steps_per_stage": steps, "description": description,
            "fits": {row["case"]: str(out / "fits" / row["key"]) for row in rows if row.get("curve")}}


def _run_case(case, clip, folder, steps, scale):
    row = {"kind": case.kind, "case": case.name, "key": case.key, "degraded": case.degraded, "finished": False, "error": None,
           "rollbacks": 0, "non_finite": 0, "final_loss": None, "finite": False, "joint_mm": None,
           "initial_joint_mm": None, "l1_mean": None, "events": [], "fit_seconds": None, "curve": False}
    observers = []
    if scale.curves:
        from .curve import CurveRecorder

        observers.append(CurveRecorder(folder))
    try:
        report = fit(clip, folder, observers=observers, max_steps=steps, progress="none", device="cpu",
                     **scale.fit_options, **case.overrides)
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
               iou_min=report["metrics"]["silhouette_iou_min"], psnr_mean=report["metrics"]["psnr_mean"],
               l1_mean=report["metrics"]["l1_mean"], fit_seconds=sum(report["stage_seconds"].values()),
               curve=bool(observers))
    row["finite"] = all(isinstance(v, float) and math.isfinite(v)
                        for v in (row["final_loss"], row["joint_mm"], row["psnr_mean"], row["l1_mean"]))
    return row


def _compare_with_baseline(rows):
    """Each row's joint error and L1 as ratios to the baseline's, and whether a case with
    undegraded input stays within WITHIN_BASELINE of the baseline's joint error."""
    baseline = next((row for row in rows if row["kind"] == "baseline" and row["finite"]), None)
    for row in rows:
        ratios = {}
        if baseline is not None and row["finite"] and row.get("l1_mean") is not None:
            ratios = {"joint_ratio": row["joint_mm"] / baseline["joint_mm"],
                      "l1_ratio": row["l1_mean"] / baseline["l1_mean"]}
        row.update(joint_ratio=ratios.get("joint_ratio"), l1_ratio=ratios.get("l1_ratio"))
        row["within_baseline"] = (None if row.get("degraded", False) or row["joint_ratio"] is None
                                  else row["joint_ratio"] <= WITHIN_BASELINE)
