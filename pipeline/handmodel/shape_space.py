"""The linear shape space: named displacement fields of the template, one per shape parameter.

Each field is smooth over the surface and defined for any point, so the same field moves the
vertices, the joints and the keypoints: joint positions are exactly linear in beta. One unit of
beta is roughly one standard deviation of adult variation; beta = 0 is the average hand.
Parameters 10 and 11 act below the wrist cut only, so they leave hand-only mode unchanged.
"""
from __future__ import annotations

import numpy as np

from . import anatomy
from .digit_coordinates import all_digit_coordinates, digit_membership, smooth_ramp, smoothstep

SHAPE_PARAMETERS = (
    ("scale", "overall size, +5% per unit (about the wrist)"),
    ("palm_width", "palm breadth across the knuckles, +3% per unit; the digits move apart rigidly"),
    ("palm_length", "palm length wrist to knuckles, +3.5% per unit; the digits move distally"),
    ("palm_thickness", "palm thickness (dorsal to palmar), +6% per unit"),
    ("thumb_length", "thumb length from its CMC joint, +4% per unit"),
    ("index_length", "index finger length from its knuckle, +4% per unit"),
    ("middle_length", "middle finger length from its knuckle, +4% per unit"),
    ("ring_length", "ring finger length from its knuckle, +4% per unit"),
    ("pinky_length", "little finger length from its knuckle, +4% per unit"),
    ("finger_thickness", "girth of all five digits, +4% per unit"),
    ("forearm_length", "forearm length wrist to elbow, +5% per unit (hand+forearm mode)"),
    ("forearm_girth", "forearm girth, +6% per unit (hand+forearm mode)"),
)
DIGIT_BASE_BLEND = 0.006
THICKNESS_FADE_IN = 0.025


def _chain_point(finger, arc):
    """Point of a digit's joint polyline at arc length `arc` (extended past both ends)."""
    chain, _ = finger.chain()
    lengths = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    starts = np.r_[0.0, np.cumsum(lengths)[:-1]]
    segment = np.clip(np.searchsorted(starts, arc, side="right") - 1, 0, 2)
    direction = (chain[segment + 1] - chain[segment]) / lengths[segment][:, None]
    return chain[segment] + (arc - starts[segment])[:, None] * direction


def shape_directions(points, parts=None):
    """(N, 3, 12) displacement of each point per unit of each shape parameter."""
    n = len(points)
    coordinates = all_digit_coordinates(points)
    affinity = digit_membership(coordinates, parts)
    dirs = np.zeros((n, 3, len(SHAPE_PARAMETERS)))
    x, y, z = points.T

    # how much each point is carried rigidly by each digit's base (0 in the palm proper)
    digitness = np.stack([affinity[:, d] * smoothstep((coordinates[name].arc + DIGIT_BASE_BLEND)
                                                      / (2 * DIGIT_BASE_BLEND))
                          for d, name in enumerate(anatomy.FINGERS, start=1)], axis=1)
    bases = np.stack([anatomy.HAND_FINGERS[name].base for name in anatomy.FINGERS])
    # the palm's shape fields carry the four fingers rigidly from their knuckles; the thumb's
    # metacarpal lies inside the palm, so it is stretched with it (no shear across its web)
    fingers = digitness[:, 1:]
    carried = (1 - fingers.sum(1))[:, None] * points + fingers @ bases[1:]
    palm_mid_x = 0.5 * (anatomy.PALM_OUTLINE[:, 0].min() + anatomy.PALM_OUTLINE[:, 0].max())

    dirs[:, :, 0] = 0.05 * points
    dirs[:, 0, 1] = 0.03 * (carried[:, 0] - palm_mid_x) * smoothstep(carried[:, 1] / 0.05)
    dirs[:, 1, 2] = 0.035 * smooth_ramp(carried[:, 1], 0.01)
    palm_only = 1 - digitness.sum(1)
    dirs[:, 2, 3] = 0.06 * (z - anatomy.PALM_CENTRE_Z) * palm_only * smoothstep((y + 0.01) / 0.03)
    for d, name in enumerate(anatomy.FINGERS):
        finger = anatomy.HAND_FINGERS[name]
        c = coordinates[name]
        along = _chain_point(finger, np.maximum(c.arc, 0.0)) - np.asarray(finger.base)
        dirs[:, :, 4 + d] = 0.04 * affinity[:, d + 1, None] * along
        # girth fades in over the proximal phalanx so that webs do not fold between digits
        girth = affinity[:, d + 1] * smoothstep(c.arc / THICKNESS_FADE_IN)
        dirs[:, :, 9] += 0.04 * girth[:, None] * (points - c.nearest)
    below_cut = anatomy.WRIST_CUT_Y - 0.004 - y
    dirs[:, 1, 10] = -0.05 * smooth_ramp(below_cut, 0.004)
    cx, cz = anatomy.WRIST_CENTRE_XZ
    girth = 0.06 * smoothstep((anatomy.WRIST_CUT_Y - y) / 0.04)
    dirs[:, 0, 11] = girth * (x - cx)
    dirs[:, 2, 11] = girth * (z - cz)
    return dirs
