"""init.npz: the initial estimate a fit starts from (numpy only; one home of the format).

Written into the sequence folder by `harp init` (MediaPipe, a keypoint file, or ground truth
plus noise for synthetic experiments) and read by the fit. Frames are the sequence's frames.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .npz_file import read_npz, write_npz
from .pose_arrays import pose_array_problems

FORMAT_NAME = "harp-initial-estimate"
FORMAT_VERSION = 1
FILE_NAME = "init.npz"
SOURCES = ("mediapipe", "keypoints", "gt-noise")


class InitialEstimateError(ValueError):
    """init.npz is missing, unreadable or inconsistent (one-line message)."""


@dataclasses.dataclass
class InitialEstimate:
    """Per-frame pose of the hand model (right or left side, hand or arm mode) in the camera
    frame, one shared shape, and 3D keypoints the fit's anchor term holds on to."""

    source: str                     # one of SOURCES
    mode: str                       # "hand" or "arm"
    side: str                       # "right" or "left"
    betas: np.ndarray               # (S,)
    pose: np.ndarray                # (F, 16, 3) local axis-angle, radians
    global_orient: np.ndarray       # (F, 3) axis-angle, model -> camera, about the wrist
    transl: np.ndarray              # (F, 3) wrist position in the camera frame, metres
    keypoints3d: np.ndarray         # (F, 21, 3) the model's keypoints at this estimate, metres
    residual_px: np.ndarray         # (F,) mean 2D keypoint residual of the estimate (0 if unknown)
    detected: np.ndarray            # (F,) bool: the frame had its own detection (not interpolated)
    metadata: dict = dataclasses.field(default_factory=dict)

    @property
    def frame_count(self) -> int:
        return int(self.pose.shape[0])

    def validate(self) -> None:
        problems = []
        if self.source not in SOURCES:
            problems.append(f"source {self.source!r} is not one of {SOURCES}")
        problems += pose_array_problems(self, {"residual_px": (), "detected": ()})
        if problems:
            raise InitialEstimateError("invalid initial estimate: " + "; ".join(problems))


_ARRAYS = ("betas", "pose", "global_orient", "transl", "keypoints3d", "residual_px", "detected")


def write_initial_estimate(folder, estimate: InitialEstimate) -> Path:
    estimate.validate()
    header = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "source": estimate.source,
              "mode": estimate.mode, "side": estimate.side, "metadata": estimate.metadata}
    return write_npz(Path(folder) / FILE_NAME, header, {name: np.asarray(getattr(estimate, name)) for name in _ARRAYS})


def read_initial_estimate(folder) -> InitialEstimate:
    path = Path(folder) / FILE_NAME
    if not path.is_file():
        raise InitialEstimateError(f"no initial estimate at {path}; run `harp init` first")
    header, arrays = read_npz(path, FORMAT_NAME, FORMAT_VERSION, InitialEstimateError, required=_ARRAYS,
                              what="initial estimate")
    estimate = InitialEstimate(source=header.get("source"), mode=header.get("mode"), side=header.get("side"),
                               metadata=header.get("metadata", {}), **arrays)
    estimate.validate()
    return estimate
