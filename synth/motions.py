"""Hand motions (numpy): per-frame joint rotations and a rotation of the whole hand.

    motion = make_motion("fingers", frame_count=150, fps=30, limits=data.joint_limits, mode="arm", seed=0)
    motion.pose (F, 16, 3)    local axis-angle per joint (right-hand convention), radians
    motion.rotation (F, 3)    axis-angle of the whole hand in model space, about the hand's pivot

`flip` turns the hand palm to back and back about its long axis (fingers relaxed), `fingers`
flexes, extends and spreads the fingers and touches each fingertip with the thumb, `random` is
a smooth random walk inside the joint limits with a gently wobbling hand. Every pose is
clipped into the limits. The wrist joint (0) moves only in hand+forearm mode (in hand-only
mode it would duplicate the global rotation). A left hand mirrors these with
pipeline.handmodel.mirror.mirror_axis_angle.
"""
from __future__ import annotations

import dataclasses

import numpy as np

MOTIONS = ("flip", "fingers", "random")
FINGER_JOINTS = {"index": (1, 2, 3), "middle": (4, 5, 6), "pinky": (7, 8, 9), "ring": (10, 11, 12),
                 "thumb": (13, 14, 15)}


@dataclasses.dataclass
class Motion:
    pose: np.ndarray       # (F, 16, 3)
    rotation: np.ndarray   # (F, 3)


def _pose(per_joint_degrees):
    pose = np.zeros((16, 3))
    for joint, degrees in per_joint_degrees.items():
        pose[joint] = np.radians(degrees)
    return pose


def _all_fingers(mcp, pip, dip, thumb=((0, 0, 0), (0, 0, 0), (0, 0, 0))):
    joints = {}
    for name in ("index", "middle", "ring", "pinky"):
        a, b, c = FINGER_JOINTS[name]
        joints[a], joints[b], joints[c] = mcp, pip, dip
    joints.update(zip(FINGER_JOINTS["thumb"], thumb))
    return joints


RELAXED = _pose(_all_fingers((12, 0, 0), (18, 0, 0), (8, 0, 0), ((5, 0, 5), (8, 0, 0), (8, 0, 0))))
OPEN = _pose(_all_fingers((0, 0, 0), (3, 0, 0), (2, 0, 0)))
FIST = _pose(_all_fingers((85, 0, 0), (100, 0, 0), (55, 0, 0), ((35, 15, 20), (35, 0, 0), (45, 0, 0))))
SPREAD = _pose({1: (0, 0, -18), 4: (0, 0, -4), 10: (0, 0, 10), 7: (-5, 0, 24), 13: (-15, 0, -30),
                2: (3, 0, 0), 5: (3, 0, 0), 8: (3, 0, 0), 11: (3, 0, 0)})
OPPOSITION = {  # thumb tip on each fingertip (found by minimising their distance inside the limits)
    "index": _pose({13: (11, -1, 1), 14: (17, 0, 0), 15: (17, 0, 0), 1: (39, -1, 0), 2: (57, 0, 0), 3: (34, 0, 0)}),
    "middle": _pose({13: (20, 0, 2), 14: (17, 0, 0), 15: (11, 0, 0), 4: (40, 4, -4), 5: (61, 2, -2), 6: (38, 1, -2)}),
    "ring": _pose({13: (26, -3, 5), 14: (27, -1, 2), 15: (12, 0, 1), 10: (42, 5, -5), 11: (60, 2, -3), 12: (36, 1, -2)}),
    "pinky": _pose({13: (30, -7, 9), 14: (33, -4, 4), 15: (28, -1, 3), 7: (48, 6, -5), 8: (56, 3, -4), 9: (28, 1, -3)}),
}
FINGERS_SEQUENCE = (OPEN, FIST, OPEN, SPREAD, OPEN, OPPOSITION["index"], OPPOSITION["middle"],
                    OPPOSITION["ring"], OPPOSITION["pinky"], OPEN)


def _ease(u):
    return 0.5 - 0.5 * np.cos(np.pi * u)


def _keyframes(poses, u):
    """Eased piecewise interpolation through equally spaced key poses at phases u (F,) in [0, 1]."""
    poses = np.asarray(poses)
    position = np.clip(u, 0, 1) * (len(poses) - 1)
    index = np.minimum(position.astype(int), len(poses) - 2)
    weight = _ease(position - index)[:, None, None]
    return poses[index] * (1 - weight) + poses[index + 1] * weight


def _smooth_signal(rng, times, count, frequencies=(0.15, 0.6)):
    """(F, count) smooth random signals in about [-1, 1]: a few sinusoids per channel."""
    waves = 4
    freq = rng.uniform(*frequencies, size=(count, waves))
    phase = rng.uniform(0, 2 * np.pi, size=(count, waves))
    amplitude = rng.uniform(0.5, 1.0, size=(count, waves))
    signal = (amplitude * np.sin(2 * np.pi * freq * times[:, None, None] + phase)).sum(-1)
    return np.tanh(1.2 * signal / np.sqrt((amplitude ** 2).sum(-1) / 2))


def make_motion(name, frame_count, fps, limits, mode="hand", seed=0):
    """Motion `name` over `frame_count` frames at `fps`; limits (16, 3, 2) radians (right hand)."""
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; choose one of {MOTIONS}")
    u = np.arange(frame_count) / max(frame_count - 1, 1)
    times = np.arange(frame_count) / fps
    rotation = np.zeros((frame_count, 3))
    if name == "flip":
        pose = np.repeat(RELAXED[None], frame_count, axis=0)
        rotation[:, 1] = np.pi * (0.5 - 0.5 * np.cos(2 * np.pi * u))  # 0 -> 180 deg -> 0 about +y
        if mode == "arm":
            pose[:, 0, 0] = np.radians(10) * np.sin(2 * np.pi * u)
    elif name == "fingers":
        pose = _keyframes(FINGERS_SEQUENCE, u)
    else:
        rng = np.random.default_rng([seed, 4])
        curl = 0.5 + 0.5 * _smooth_signal(rng, times, 5, (0.1, 0.4))  # per digit, 0 open .. 1 fist
        spread = _smooth_signal(rng, times, 1)[:, 0]
        pose = np.repeat(OPEN[None], frame_count, axis=0)
        for k, digit in enumerate(("thumb", "index", "middle", "ring", "pinky")):
            joints = list(FINGER_JOINTS[digit])
            pose[:, joints] = OPEN[joints] + curl[:, k, None, None] * (FIST[joints] - OPEN[joints])
        pose = pose + np.maximum(spread, 0)[:, None, None] * (1 - curl.mean(1))[:, None, None] * SPREAD[None]
        pose = pose + 0.08 * _smooth_signal(rng, times, 48, (0.2, 0.8)).reshape(frame_count, 16, 3)
        rotation = 0.45 * _smooth_signal(rng, times, 3, (0.05, 0.25))
    if mode != "arm":
        pose[:, 0] = 0
    pose = np.clip(pose, limits[..., 0], limits[..., 1])
    return Motion(pose=pose, rotation=rotation)
