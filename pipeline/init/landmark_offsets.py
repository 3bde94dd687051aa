"""Where MediaPipe puts its hand landmarks on our hand model (`harp init --landmark-offsets`).

The model's keypoints are its own (the synthetic clips' ground truth uses them). MediaPipe's
landmarks sit elsewhere on the hand: its wrist nearer the fingers, its thumb base further along,
its fingertips inside the tips; in the image they spread about 5% less than the model's
keypoints. Taken for the model's keypoints, they make the initial fit place the hand 6 - 9% too
far, which MediaPipe's size estimate then offsets or adds to (docs/initialisation.md, "MediaPipe's
landmarks on the model": the option is measured there and off by default).

The offsets (pipeline/assets/mediapipe_landmarks.json, fitted by tools/calibrate_landmarks.py)
move each keypoint, rigidly with its bone, to where MediaPipe's landmark is on the hand. With
the option the initial fit compares MediaPipe's landmarks with the keypoints moved so; whatever
comes after it (init.npz keypoints3d, the fit's anchor, evaluation) keeps the model's own.
"""
from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import numpy as np

from ..handmodel.mirror import mirror_points

OFFSETS_FILE = Path(__file__).resolve().parents[1] / "assets" / "mediapipe_landmarks.json"


@functools.lru_cache(maxsize=None)
def _right_hand_offsets() -> tuple:
    entry = json.loads(OFFSETS_FILE.read_text())
    offsets = np.asarray(entry["offsets_mm"], dtype=np.float64) / 1000
    if offsets.shape != (21, 3) or not np.isfinite(offsets).all():
        raise ValueError(f"{OFFSETS_FILE} holds no 21 x 3 finite offsets")
    return tuple(map(tuple, offsets))


def mediapipe_offsets(side: str) -> np.ndarray:
    """(21, 3) metres: MediaPipe's landmarks minus the model's keypoints, in the rest frame of a
    `side` hand."""
    offsets = np.array(_right_hand_offsets())
    return offsets if side == "right" else mirror_points(offsets)


def on_mediapipe_landmarks(model):
    """A HandModel like `model` whose first 21 keypoints are MediaPipe's landmarks (the offsets
    added in its rest frame, so they move rigidly with their bones)."""
    from ..handmodel.lbs import HandModel

    keypoints = np.array(model.data.keypoints, dtype=np.float64)
    keypoints[:21] += mediapipe_offsets(model.side)
    return HandModel(dataclasses.replace(model.data, keypoints=keypoints), dtype=model.v_template.dtype,
                     device=model.v_template.device)
