"""The average adult right hand our template is built from: joint chains, radii, rest frames.

All numbers are metres in model space (wrist joint at the origin, +x thumb side, +y distal,
+z palmar). Sources of the proportions: adult hand anthropometry (hand length about 0.185 m,
breadth across the metacarpal heads about 0.085 m, phalanx ratios close to 1 : 0.62 : 0.52 for
the long fingers, the middle finger about 10% longer than the index, the pinky about 20% shorter).
"""
from __future__ import annotations

import dataclasses

import numpy as np

FINGERS = ("thumb", "index", "middle", "ring", "pinky")  # MediaPipe order

# MANO joint index of each finger's three joints (see formats/hand_model_file.JOINT_NAMES).
FINGER_JOINTS = {
    "index": (1, 2, 3), "middle": (4, 5, 6), "pinky": (7, 8, 9),
    "ring": (10, 11, 12), "thumb": (13, 14, 15),
}

WRIST_CUT_Y = -0.012          # hand-only mode ends in a flat cut at this y
ELBOW_Y = -0.262              # elbow joint (forearm length, wrist to elbow)
FOREARM_END_Y = -0.287        # the forearm mesh ends just past the olecranon
WRIST_CENTRE_XZ = (-0.001, 0.001)  # axis of the wrist/forearm cross-sections


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _rotation(axis, angle):
    """Rotation matrix about a unit axis (Rodrigues), angle in radians."""
    axis = _unit(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@dataclasses.dataclass(frozen=True)
class Finger:
    """One digit: a chain of three joints and a tip, with a radius at each of the four points.

    `base` is the first joint (MCP for fingers, CMC for the thumb). `direction` is the rest
    direction of the first bone; `palmar` the direction the pad faces (the bone's local +z,
    i.e. where flexion bends it). `rest_flexion` bends the chain at each joint (radians).
    """

    name: str
    base: tuple
    direction: tuple
    palmar: tuple
    lengths: tuple          # first, second, third bone (the third ends at the fingertip skin)
    radii: tuple            # at base, joint 2, joint 3, tip
    rest_flexion: tuple     # at base, joint 2, joint 3
    flatness: float = 0.9   # palmar-dorsal over lateral thickness of the cross-section

    def chain(self):
        """Joint positions (4, 3) including the fingertip, and the rest frames (3, 3, 3)."""
        y = _unit(self.direction)
        z = _unit(np.asarray(self.palmar) - np.dot(self.palmar, y) * y)
        x = np.cross(y, z)
        frame = np.stack([x, y, z], axis=1)
        points = [np.asarray(self.base, dtype=np.float64)]
        frames = []
        for length, flexion in zip(self.lengths, self.rest_flexion):
            frame = _rotation(frame[:, 0], flexion) @ frame
            frames.append(frame)
            points.append(points[-1] + length * frame[:, 1])
        return np.stack(points), np.stack(frames)


def _spread(angle_deg):
    """Direction in the palm plane, rotated from +y towards the thumb side by angle."""
    a = np.radians(angle_deg)
    return (np.sin(a), np.cos(a), 0.0)


HAND_FINGERS = {
    "thumb": Finger("thumb", base=(0.0205, 0.0195, 0.0095), direction=(0.60, 0.76, 0.22),
                    palmar=(-0.80, 0.05, 0.60), lengths=(0.044, 0.031, 0.0295),
                    radii=(0.0122, 0.0104, 0.0094, 0.0082),
                    rest_flexion=(0.0, np.radians(12), np.radians(8)), flatness=0.88),
    "index": Finger("index", base=(0.0315, 0.0845, -0.0010), direction=_spread(7.0), palmar=(0, 0, 1),
                    lengths=(0.0415, 0.0245, 0.0220), radii=(0.0098, 0.0087, 0.0077, 0.0069),
                    rest_flexion=(0.0, np.radians(3), np.radians(2))),
    "middle": Finger("middle", base=(0.0100, 0.0885, -0.0010), direction=_spread(1.0), palmar=(0, 0, 1),
                     lengths=(0.0455, 0.0285, 0.0235), radii=(0.0100, 0.0089, 0.0079, 0.0071),
                     rest_flexion=(0.0, np.radians(3), np.radians(2))),
    "ring": Finger("ring", base=(-0.0105, 0.0850, -0.0010), direction=_spread(-5.5), palmar=(0, 0, 1),
                   lengths=(0.0425, 0.0275, 0.0225), radii=(0.0094, 0.0084, 0.0074, 0.0067),
                   rest_flexion=(0.0, np.radians(3), np.radians(2))),
    "pinky": Finger("pinky", base=(-0.0298, 0.0775, -0.0010), direction=_spread(-13.0), palmar=(0, 0, 1),
                    lengths=(0.0335, 0.0195, 0.0200), radii=(0.0083, 0.0073, 0.0065, 0.0059),
                    rest_flexion=(0.0, np.radians(3), np.radians(2))),
}

# Outline of the palm in the xy plane (counter-clockwise); the palm is this polygon rounded by
# PALM_ROUNDING and extruded to a half-thickness PALM_HALF_THICKNESS + PALM_ROUNDING in z.
PALM_OUTLINE = np.array([
    (-0.0200, 0.0040), (0.0180, 0.0040), (0.0255, 0.0350), (0.0335, 0.0800),
    (0.0115, 0.0860), (-0.0105, 0.0820), (-0.0300, 0.0745), (-0.0290, 0.0380),
])
PALM_ROUNDING = 0.0092
PALM_HALF_THICKNESS = 0.0036
PALM_CENTRE_Z = 0.0005

# Soft-tissue masses of the palm: (centre, radii).
THENAR = ((0.0215, 0.0290, 0.0095), (0.0165, 0.0250, 0.0125))
HYPOTHENAR = ((-0.0235, 0.0340, 0.0060), (0.0110, 0.0270, 0.0105))

# Wrist/forearm cross-section half-widths (x, z) along y: (y, half_width_x, half_thickness_z).
FOREARM_PROFILE = (
    (0.010, 0.0270, 0.0172),
    (WRIST_CUT_Y, 0.0275, 0.0175),
    (-0.060, 0.0300, 0.0205),
    (-0.120, 0.0340, 0.0262),
    (-0.175, 0.0365, 0.0300),
    (-0.220, 0.0355, 0.0305),
    (ELBOW_Y, 0.0335, 0.0300),
    (FOREARM_END_Y, 0.0300, 0.0270),
)


def forearm_half_axes(y):
    """Half-width (x) and half-thickness (z) of the wrist/forearm section at height y."""
    ys = np.array([p[0] for p in FOREARM_PROFILE])[::-1]
    ax = np.array([p[1] for p in FOREARM_PROFILE])[::-1]
    az = np.array([p[2] for p in FOREARM_PROFILE])[::-1]
    return np.interp(y, ys, ax), np.interp(y, ys, az)


def wrist_frame():
    """Rest frame of the wrist joint: flexion about +x bends the hand towards the palm."""
    return np.eye(3)


def forearm_frame():
    """Rest frame of the forearm bone (elbow -> wrist, along +y)."""
    return np.eye(3)


# Anatomical joint limits, radians, per local component (flexion about x, twist about y,
# deviation about z). Flexion is positive towards the palm; deviation positive towards the
# pinky side for fingers. Ranges follow clinical active ranges of motion.
def joint_limits_deg():
    """(16, 3, 2) limits in degrees in MANO joint order; see module docstring of joint_limits."""
    lim = np.zeros((16, 3, 2))
    lim[0] = [(-70, 75), (-20, 20), (-25, 35)]      # wrist: extension/flexion, twist, radial/ulnar
    long_fingers = {
        "index": (-25, 20), "middle": (-20, 20), "ring": (-20, 20), "pinky": (-20, 30)}
    for name, deviation in long_fingers.items():
        mcp, pip, dip = FINGER_JOINTS[name]
        lim[mcp] = [(-30, 90), (-15, 15), deviation]
        lim[pip] = [(-5, 110), (-8, 8), (-8, 8)]
        lim[dip] = [(-15, 85), (-8, 8), (-8, 8)]
    cmc, mcp, ip = FINGER_JOINTS["thumb"]
    lim[cmc] = [(-25, 55), (-35, 35), (-40, 45)]    # opposition = flexion + twist + deviation
    lim[mcp] = [(-15, 65), (-15, 15), (-15, 15)]
    lim[ip] = [(-20, 85), (-10, 10), (-10, 10)]
    return lim


def default_joint_limits():
    """(16, 3, 2) anatomical limits in radians (see joint_limits_deg)."""
    return np.radians(joint_limits_deg())
