"""Keypoint files: 2D hand keypoints per frame (numpy and the standard library only; one home of
the format, read by `harp init --init keypoints FILE` and written by the MediaPipe detection as
SEQUENCE/keypoints.json).

Keypoints are 21 points in MediaPipe order (0 wrist, 1-4 thumb, 5-8 index, 9-12 middle,
13-16 ring, 17-20 pinky) in pixels of the sequence's frames, with the origin at the top-left
corner of the image (a pixel centre is at column + 0.5; pipeline/formats/camera.py). Frames
without keypoints are linearly interpolated in time (held constant before the first and after
the last known frame) and flagged `detected = False`.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

KEYPOINT_COUNT = 21
KEYPOINT_FILE_FORMAT = "harp-keypoints"


class KeypointError(ValueError):
    """Keypoints could not be detected or read (one-line message)."""


@dataclasses.dataclass
class Keypoints2D:
    """Per-frame 2D keypoints of one hand in a clip of F frames."""

    points: np.ndarray                  # (F, 21, 2) pixels, corner origin; interpolated where not detected
    detected: np.ndarray                # (F,) bool: the frame had its own detection
    score: np.ndarray                   # (F,) confidence in [0, 1] (0 where not detected)
    world: np.ndarray | None = None     # (F, 21, 3) MediaPipe's metric world landmarks, metres
    handedness_ok: np.ndarray | None = None  # (F,) bool: the detector's label matched the side
    other_hand: np.ndarray | None = None     # (F, 21, 2) the other hand's landmarks where two were found, else NaN
    source: str = "mediapipe"

    @property
    def frame_count(self) -> int:
        return int(self.points.shape[0])

    def summary(self) -> dict:
        """Detection rate and handedness agreement, for logs and init.npz metadata."""
        entry = {"source": self.source, "frames": self.frame_count,
                 "detected": int(self.detected.sum()), "detection_rate": float(self.detected.mean())}
        if self.handedness_ok is not None and self.detected.any():
            entry["handedness_agreement"] = float(self.handedness_ok[self.detected].mean())
        return entry


def interpolate_missing(values, detected):
    """Linear interpolation over time of (F, ...) values at frames where `detected` is False;
    held constant before the first and after the last detected frame."""
    values = np.array(values, dtype=np.float64)
    known = np.flatnonzero(detected)
    if len(known) == 0:
        raise KeypointError("no frame has keypoints to interpolate from")
    flat = values.reshape(len(values), -1)
    frames = np.arange(len(values))
    for column in range(flat.shape[1]):
        flat[:, column] = np.interp(frames, known, flat[known, column])
    return flat.reshape(values.shape)


def read_keypoint_file(path, frame_count, width, height):
    """Keypoints2D from a keypoint file of F = frame_count frames (docs/initialisation.md):

    - `.npy`: array (F, 21, 2) pixels, or (F, 21, 3) with a per-keypoint confidence last;
    - `.npz`: `keypoints` (F, 21, 2) pixels, optional `score` (F,);
    - `.json`: {"format": "harp-keypoints", "version": 1, "keypoints": F lists of 21 [x, y]
      (or null for a frame without keypoints), optional "score": F numbers}, or the bare list.
    A frame whose keypoints are all NaN (or null) has none and is interpolated."""
    path = Path(path)
    if not path.is_file():
        raise KeypointError(f"keypoint file not found: {path}")
    score = None
    try:
        if path.suffix.lower() == ".npy":
            array = np.load(path, allow_pickle=False)
        elif path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                if "keypoints" not in archive.files:
                    raise KeypointError(f"{path} has no array named 'keypoints' (has {', '.join(archive.files)})")
                array = archive["keypoints"]
                score = archive["score"] if "score" in archive.files else None
        elif path.suffix.lower() == ".json":
            entry = json.loads(path.read_text())
            if isinstance(entry, dict):
                if entry.get("format", KEYPOINT_FILE_FORMAT) != KEYPOINT_FILE_FORMAT or "keypoints" not in entry:
                    raise KeypointError(f"{path} is not a {KEYPOINT_FILE_FORMAT} file (needs a 'keypoints' list)")
                score = entry.get("score")
                entry = entry["keypoints"]
            nan_frame = [[np.nan, np.nan]] * KEYPOINT_COUNT
            array = np.array([nan_frame if frame is None else frame for frame in entry], dtype=np.float64)
        else:
            raise KeypointError(f"keypoint file {path} must be .npy, .npz or .json")
    except KeypointError:
        raise
    except Exception as error:  # unreadable, ragged lists, non-numbers ...
        raise KeypointError(f"cannot read keypoint file {path}: {error}") from None
    array = np.asarray(array, dtype=np.float64)
    if array.ndim != 3 or array.shape[1] != KEYPOINT_COUNT or array.shape[2] not in (2, 3):
        raise KeypointError(f"keypoints in {path} have shape {array.shape}, expected ({frame_count}, 21, 2)")
    if array.shape[0] != frame_count:
        raise KeypointError(f"{path} has keypoints for {array.shape[0]} frames, the sequence has {frame_count}")
    if array.shape[2] == 3:
        score = np.nan_to_num(array[..., 2]).mean(axis=1) if score is None else score
        array = array[..., :2]
    detected = np.isfinite(array).all(axis=(1, 2))
    if not detected.any():
        raise KeypointError(f"{path} has no frame with 21 finite keypoints")
    known = array[detected]
    if known.min() >= -1e-9 and known.max() <= 1 + 1e-9 and max(width, height) > 2:
        raise KeypointError(f"keypoints in {path} all lie in [0, 1]: they look normalised; "
                            f"give pixels (multiply x by {width} and y by {height})")
    centres = known.mean(axis=1)
    outside = (centres[:, 0] < 0) | (centres[:, 0] > width) | (centres[:, 1] < 0) | (centres[:, 1] > height)
    if outside.all():
        raise KeypointError(f"keypoints in {path} lie outside the {width}x{height} image in every frame")
    score = np.where(detected, 1.0, 0.0) if score is None else np.asarray(score, dtype=np.float64).reshape(-1)
    if score.shape != (frame_count,):
        raise KeypointError(f"score in {path} has {score.size} values, expected {frame_count}")
    return Keypoints2D(points=interpolate_missing(np.where(np.isfinite(array), array, 0.0), detected),
                       detected=detected, score=np.where(detected, score, 0.0), source="keypoints")


def write_keypoint_file(path, keypoints: Keypoints2D) -> Path:
    """Write Keypoints2D as a .json keypoint file (frames without detection as null)."""
    frames = [points.round(3).tolist() if found else None
              for points, found in zip(keypoints.points, keypoints.detected)]
    path = Path(path)
    path.write_text(json.dumps({"format": KEYPOINT_FILE_FORMAT, "version": 1, "keypoints": frames,
                                "score": np.round(keypoints.score, 4).tolist()}) + "\n")
    return path
