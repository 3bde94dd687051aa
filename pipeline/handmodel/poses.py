"""Named hand poses (local axis-angle per joint, radians), all inside the joint limits."""
from __future__ import annotations

import numpy as np

from .anatomy import FINGER_JOINTS


def _pose(per_joint_degrees):
    pose = np.zeros((16, 3))
    for joint, degrees in per_joint_degrees.items():
        pose[joint] = np.radians(degrees)
    return pose


def _curled(mcp, pip, dip, thumb):
    joints = {}
    for name in ("index", "middle", "ring", "pinky"):
        a, b, c = FINGER_JOINTS[name]
        joints[a], joints[b], joints[c] = (mcp, 0, 0), (pip, 0, 0), (dip, 0, 0)
    joints.update(zip(FINGER_JOINTS["thumb"], thumb))
    return joints


NAMED_POSES = {
    "rest": _pose({}),
    "fist": _pose(_curled(85, 100, 55, [(35, 15, 20), (35, 0, 0), (45, 0, 0)])),
    "spread": _pose({1: (0, 0, -18), 4: (0, 0, -4), 10: (0, 0, 10), 7: (-5, 0, 24), 13: (-15, 0, -30)}),
    "thumbs_up": _pose(_curled(85, 100, 55, [(-10, 0, 25), (0, 0, 0), (-5, 0, 0)])),
    "pinch": _pose({1: (40, 0, -1), 2: (54, 0, 0), 3: (30, 0, 0),   # thumb tip on index tip
                    13: (14, 0, 0), 14: (15, 0, 0), 15: (9, 0, 0)}),
    "crossed": _pose({1: (10, 0, 20), 2: (12, 0, 0), 3: (6, 0, 0),    # index over middle, each at
                      4: (25, 0, -20), 5: (15, 0, 0), 6: (8, 0, 0)}),  # its deviation limit
    "point": _pose({**_curled(85, 100, 55, [(35, 15, 20), (35, 0, 0), (45, 0, 0)]),
                    1: (0, 0, 0), 2: (0, 0, 0), 3: (0, 0, 0)}),
}
