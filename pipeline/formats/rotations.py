"""Axis-angle rotations in numpy, for the parts that run without torch (synth, the Blender add-on):
axis-angle is the convention at every API boundary (DESIGN.md). The torch versions the fit
differentiates live in pipeline/handmodel/rotations.py; tests check that both agree."""
from __future__ import annotations

import numpy as np


def axis_angle_to_matrix(axis_angle):
    """(..., 3) axis-angle vectors (radians) -> (..., 3, 3) rotation matrices (Rodrigues)."""
    w = np.asarray(axis_angle, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    x, y, z = np.moveaxis(w, -1, 0)
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(w.shape + (3,))
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_quaternion(matrix):
    """(..., 3, 3) rotations -> (..., 4) unit quaternions (w, x, y, z) with w >= 0."""
    m = np.asarray(matrix, dtype=np.float64)
    trace = np.trace(m, axis1=-2, axis2=-1)
    # squared magnitudes of the four components, each from the diagonal (Shepperd's method)
    candidates = np.stack([1 + trace, 1 + 2 * m[..., 0, 0] - trace,
                           1 + 2 * m[..., 1, 1] - trace, 1 + 2 * m[..., 2, 2] - trace], axis=-1)
    best = candidates.argmax(-1)
    d = {  # 4 * q_i * q_j from the off-diagonal entries
        "wx": m[..., 2, 1] - m[..., 1, 2], "wy": m[..., 0, 2] - m[..., 2, 0], "wz": m[..., 1, 0] - m[..., 0, 1],
        "xy": m[..., 0, 1] + m[..., 1, 0], "xz": m[..., 0, 2] + m[..., 2, 0], "yz": m[..., 1, 2] + m[..., 2, 1],
    }
    big = np.sqrt(np.maximum(np.take_along_axis(candidates, best[..., None], -1)[..., 0], 1e-300))
    rows = [
        [big, d["wx"] / big, d["wy"] / big, d["wz"] / big],
        [d["wx"] / big, big, d["xy"] / big, d["xz"] / big],
        [d["wy"] / big, d["xy"] / big, big, d["yz"] / big],
        [d["wz"] / big, d["xz"] / big, d["yz"] / big, big],
    ]
    q = np.choose(best[..., None] * np.ones(4, dtype=int), [np.stack(r, -1) for r in rows]) / 2
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def quaternion_to_axis_angle(q):
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3) axis-angle, angle in [0, pi]."""
    q = np.asarray(q, dtype=np.float64)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    sin_half = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2 * np.arctan2(sin_half, q[..., 0])
    scale = np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-300), 2.0)
    return q[..., 1:] * scale[..., None]


def axis_angle_to_quaternion(axis_angle):
    """(..., 3) axis-angle -> (..., 4) quaternion (w, x, y, z)."""
    w = np.asarray(axis_angle, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1, keepdims=True)
    scale = np.where(theta > 1e-12, np.sin(theta / 2) / np.maximum(theta, 1e-300), 0.5)
    return np.concatenate([np.cos(theta / 2), w * scale], axis=-1)


def matrix_to_axis_angle(matrix):
    """(..., 3, 3) rotations -> (..., 3) axis-angle (radians), exact near 0 and pi."""
    return quaternion_to_axis_angle(matrix_to_quaternion(matrix))


def slerp_axis_angle(start, end, t):
    """(..., 3) axis-angle rotations from `start` to `end` (..., 3) at fraction `t` (broadcast
    to their leading shape), along the shortest arc between them."""
    q0, q1 = axis_angle_to_quaternion(start), axis_angle_to_quaternion(end)
    dot = (q0 * q1).sum(-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    angle = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
    sine = np.sin(angle)
    t = np.broadcast_to(np.asarray(t, dtype=np.float64), q0.shape[:-1])[..., None]
    small = sine < 1e-9
    w0 = np.where(small, 1 - t, np.sin((1 - t) * angle) / np.where(small, 1.0, sine))
    w1 = np.where(small, t, np.sin(t * angle) / np.where(small, 1.0, sine))
    q = w0 * q0 + w1 * q1
    return quaternion_to_axis_angle(q / np.linalg.norm(q, axis=-1, keepdims=True))
