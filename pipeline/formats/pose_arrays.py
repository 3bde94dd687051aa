"""Checks shared by the formats that store a hand pose per frame (gt.npz, init.npz): shapes of
the per-frame arrays and finiteness, as lists of one-line problems (numpy only)."""
from __future__ import annotations

import numpy as np


def pose_array_problems(record, extra_shapes=None, finite=()):
    """Problems with record.betas (S,), pose (F, 16, 3), global_orient (F, 3), transl (F, 3),
    keypoints3d (F, 21, 3) and any `extra_shapes` {name: shape after F}; the arrays named in
    `finite` (plus the pose parameters) must hold no NaN or Inf."""
    frames = record.pose.shape[0] if record.pose.ndim == 3 else -1
    expected = {"pose": (16, 3), "global_orient": (3,), "transl": (3,), "keypoints3d": (21, 3),
                **(extra_shapes or {})}
    problems = []
    if record.betas.ndim != 1:
        problems.append(f"betas has shape {record.betas.shape}, expected (S,)")
    for name, shape in expected.items():
        if getattr(record, name).shape != (frames, *shape):
            problems.append(f"{name} has shape {getattr(record, name).shape}, expected {(frames, *shape)}")
    if not problems:
        for name in ("betas", "pose", "global_orient", "transl", "keypoints3d", *finite):
            if not np.isfinite(getattr(record, name)).all():
                problems.append(f"{name} contains NaN or Inf")
    return problems
