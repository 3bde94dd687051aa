"""Linear-blend-skinning weights of the template (numpy, computed once at build time).

Along each digit the weights are a 1-D partition of unity in arc length: the palm hands over to
the first bone, the first to the second and so on, each with a smoothstep centred on the joint
and as wide as the digit is thick there. Across the hand the digit membership (see
digit_coordinates) mixes these chains with the palm, so web skin between two digits follows
both, while skin that belongs to a digit never follows a neighbouring digit's joints. In
hand+forearm mode the forearm bone takes over below the wrist.
"""
from __future__ import annotations

import numpy as np

from . import anatomy
from .digit_coordinates import all_digit_coordinates, digit_membership, smoothstep

MAX_INFLUENCES = 4
BLEND_WIDTH = {"thumb": (0.9, 0.95, 0.9), "finger": (0.75, 0.9, 0.9)}  # x digit radius, per joint
WRIST_BLEND_HALF_WIDTH = 0.014
# skin within MEMBERSHIP_INNER digit radii of a digit's axis follows it fully, none beyond
# MEMBERSHIP_OUTER: tighter than the shape fields', so bending drags little palm skin along
MEMBERSHIP_INNER, MEMBERSHIP_OUTER = 1.1, 1.9
FOREARM_JOINT = 16


def dense_skinning_weights(points, parts, with_forearm):
    """(N, 16 or 17) weights, rows summing to 1, before pruning to MAX_INFLUENCES."""
    coordinates = all_digit_coordinates(points)
    affinity = digit_membership(coordinates, parts, inner=MEMBERSHIP_INNER, outer=MEMBERSHIP_OUTER)
    weights = np.zeros((len(points), 17 if with_forearm else 16))
    weights[:, 0] = affinity[:, 0]
    for digit, name in enumerate(anatomy.FINGERS, start=1):
        finger = anatomy.HAND_FINGERS[name]
        c = coordinates[name]
        widths = BLEND_WIDTH["thumb" if name == "thumb" else "finger"]
        steps = [smoothstep((c.arc - c.joint_arcs[k] + widths[k] * finger.radii[k])
                            / (2 * widths[k] * finger.radii[k])) for k in range(3)]
        a = affinity[:, digit]
        first, second, third = anatomy.FINGER_JOINTS[name]
        weights[:, 0] += a * (1 - steps[0])
        weights[:, first] += a * (steps[0] - steps[1])
        weights[:, second] += a * (steps[1] - steps[2])
        weights[:, third] += a * steps[2]
    if with_forearm:
        forearm = 1 - smoothstep((points[:, 1] + WRIST_BLEND_HALF_WIDTH) / (2 * WRIST_BLEND_HALF_WIDTH))
        weights *= (1 - forearm)[:, None]
        weights[:, FOREARM_JOINT] = forearm
    return weights


def prune_weights(weights, max_influences=MAX_INFLUENCES, floor=1e-4):
    """Keep the largest `max_influences` weights per row (dropping tiny ones), renormalised.

    Returns (indices (N, k) int32, weights (N, k) float64); unused slots have weight 0."""
    order = np.argsort(-weights, axis=1, kind="stable")[:, :max_influences]
    kept = np.take_along_axis(weights, order, axis=1)
    kept = np.where(kept >= floor, kept, 0.0)
    kept /= kept.sum(1, keepdims=True)
    order = np.where(kept > 0, order, 0)
    return order.astype(np.int32), kept
