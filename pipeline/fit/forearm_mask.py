"""Where the mask's forearm goes (hand + forearm models): per frame, the direction from the
wrist that the forearm takes in the mask, the `forearm_direction` term's target.

The silhouette term pulls the model's forearm only where its outline already lies near the
mask's; a forearm the initial pose points elsewhere (the keypoints say nothing about it) stays
there, most of all where the mask runs out of the picture. So, from the wrist and the middle
knuckle of the initial estimate projected into the frame: the mask's pixels farther than
FOREARM_START palm lengths beyond the wrist, along the hand's axis, are the forearm. Where they
reach the image's edge, the target is the middle of that exit (where the forearm leaves the
picture: far from the wrist, so its direction is sure); otherwise their centroid. Frames whose
mask shows less forearm than MIN_FOREARM palm lengths squared get no target.
"""
from __future__ import annotations

import numpy as np

MIDDLE_KNUCKLE = 9      # keypoint index of the middle finger's knuckle (MediaPipe's order)
FOREARM_START = 0.5     # palm lengths beyond the wrist where the mask counts as forearm
MIN_FOREARM = 0.3       # forearm pixels needed, in palm lengths squared
MIN_EXIT = 0.1          # pixels on the image's edge needed for an exit, in palm lengths
BORDER_PX = 2           # this close to the image's edge is on it


def forearm_target(mask, wrist, knuckle):
    """(unit direction (2,) in pixels from the wrist, found) for a mask (H, W) bool and the
    wrist and middle knuckle (2,) in pixels (corner origin)."""
    height, width = mask.shape
    wrist, knuckle = np.asarray(wrist, np.float64), np.asarray(knuckle, np.float64)
    axis = wrist - knuckle
    palm = float(np.linalg.norm(axis))
    if not np.isfinite(palm) or palm < 2:
        return np.zeros(2), False
    axis /= palm
    rows, cols = np.nonzero(mask)
    offset = np.stack([cols + 0.5 - wrist[0], rows + 0.5 - wrist[1]], axis=1)
    beyond = offset @ axis > FOREARM_START * palm
    if beyond.sum() < MIN_FOREARM * palm ** 2:
        return np.zeros(2), False
    on_edge = beyond & ((rows < BORDER_PX) | (cols < BORDER_PX) | (rows >= height - BORDER_PX)
                        | (cols >= width - BORDER_PX))
    points = offset[on_edge] if on_edge.sum() >= max(3.0, MIN_EXIT * palm) else offset[beyond]
    direction = points.mean(0)
    length = float(np.linalg.norm(direction))
    if length < 1e-6:
        return np.zeros(2), False
    return direction / length, True


def forearm_targets(masks, wrists, knuckles):
    """((F, 2) unit directions, (F,) bool found) for masks (F, H, W) bool and the wrists and middle
    knuckles (F, 2) in pixels."""
    found = [forearm_target(mask, wrist, knuckle) for mask, wrist, knuckle in zip(masks, wrists, knuckles)]
    return np.array([direction for direction, _ in found]), np.array([ok for _, ok in found], dtype=bool)
