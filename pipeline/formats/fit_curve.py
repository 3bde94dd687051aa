"""curve.json: the anytime curve of a fit, figures measured while it ran (JSON and the standard
library only; one home of the format). Written by `harp fit --curve` into the avatar folder,
read by `harp plot` and `harp study`.

    {"format": "harp-fit-curve", "version": 1, "sequence": ..., "preset": ...,
     "measure_seconds": time spent measuring (not part of any point's fit_seconds),
     "points": [{"fit_seconds", "stage", "step", "silhouette_iou_mean", "silhouette_iou_min",
                 "psnr_mean", "l1_mean", "ms_ssim_mean"?, "joint_mm"?, "joint_camera_mm"?,
                 "vertex_mm"?, "vertex_camera_mm"?, "albedo_mae"?, "albedo_psnr"?}, ...],
     "validation"?: [{"fit_seconds", "stage", "step", "psnr_mean", "l1_mean", "silhouette_iou_mean",
                      "refine_steps"}, ...]}   (the fit's checks on the frames it kept out)

fit_seconds is the fit's own time when the figures were taken (setup and measuring excluded);
it never decreases along the list. Errors against the truth (joints, vertices: Procrustes-
aligned and camera-frame mm; albedo in the visible UV area) are there on synthetic clips only.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

CURVE_FILE = "curve.json"
FORMAT_NAME = "harp-fit-curve"
FORMAT_VERSION = 1

# figure name: (label, lower is better)
FIGURES = {
    "l1_mean": ("L1 in the mask", True),
    "psnr_mean": ("PSNR in the mask (dB)", False),
    "silhouette_iou_mean": ("silhouette IoU", False),
    "ms_ssim_mean": ("MS-SSIM", False),
    "joint_mm": ("joint error, Procrustes (mm)", True),
    "vertex_mm": ("vertex error, Procrustes (mm)", True),
    "joint_camera_mm": ("joint error, camera frame (mm)", True),
    "albedo_mae": ("albedo MAE (visible UV area)", True),
}


class FitCurveError(ValueError):
    """A curve.json is missing or unreadable (one-line message)."""


def write_curve(folder, curve: dict) -> Path:
    """Write folder/curve.json atomically; `curve` holds at least "points" (a list of dicts)."""
    path = Path(folder) / CURVE_FILE
    temporary = path.with_suffix(".tmp")
    temporary.write_text(json.dumps(_plain({"format": FORMAT_NAME, "version": FORMAT_VERSION, **curve}), indent=1))
    temporary.replace(path)
    return path


def read_curve(folder) -> dict:
    """The curve of the fit in `folder` (or the curve.json file itself)."""
    path = Path(folder)
    path = path / CURVE_FILE if path.is_dir() else path
    if not path.is_file():
        raise FitCurveError(f"no {CURVE_FILE} in {path.parent} (fit with --curve)")
    try:
        curve = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise FitCurveError(f"cannot read {path}: {error}") from None
    if curve.get("format") != FORMAT_NAME or curve.get("version") != FORMAT_VERSION:
        raise FitCurveError(f"{path} is not a {FORMAT_NAME} file of version {FORMAT_VERSION}")
    return curve


def _plain(value):
    """JSON has no NaN: non-finite numbers become null, numpy scalars plain numbers."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, (str, bool, int)) or value is None:
        return value
    value = float(value)
    return value if math.isfinite(value) else None
