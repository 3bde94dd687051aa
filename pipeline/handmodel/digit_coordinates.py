"""Coordinates of points relative to each digit's bone chain, shared by skinning and shape space.

For every point and digit: the arc length `s` along the digit's joint polyline (measured from
the first joint; negative inside the palm, where the first bone's line is extended backwards),
the nearest point on that polyline, and the distance to it relative to the digit's influence
radius. `digit_membership` turns these into a smooth partition between the palm and the digits.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from . import anatomy



@dataclasses.dataclass
class DigitCoordinates:
    arc: np.ndarray            # (N,) arc length along the chain, metres
    nearest: np.ndarray        # (N, 3) nearest point on the (extended) chain polyline
    relative_distance: np.ndarray  # (N,) distance / influence radius at that arc length
    joint_arcs: np.ndarray     # (3,) arc length of the three joints (first is 0)


def influence_radius(finger: anatomy.Finger, arc):
    """Radius of the region a digit's bones move, along its arc length."""
    joint_arcs = np.r_[0.0, np.cumsum(finger.lengths)]
    radii = np.array(finger.radii) * (1.35 if finger.name == "thumb" else 1.0)
    return np.interp(arc, joint_arcs, radii)


def digit_coordinates(points, finger: anatomy.Finger) -> DigitCoordinates:
    chain, _ = finger.chain()
    lengths = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    joint_arcs = np.r_[0.0, np.cumsum(lengths)]
    best_distance = np.full(len(points), np.inf)
    arc = np.zeros(len(points))
    nearest = np.zeros_like(points)
    for k in range(3):
        a, b = chain[k], chain[k + 1]
        direction = (b - a) / lengths[k]
        t = (points - a) @ direction
        lo = -np.inf if k == 0 else 0.0
        hi = np.inf if k == 2 else lengths[k]
        t = np.clip(t, lo, hi)
        candidate = a + t[:, None] * direction
        distance = np.linalg.norm(points - candidate, axis=1)
        better = distance < best_distance
        best_distance = np.where(better, distance, best_distance)
        arc = np.where(better, joint_arcs[k] + t, arc)
        nearest = np.where(better[:, None], candidate, nearest)
    relative = best_distance / influence_radius(finger, np.clip(arc, 0, joint_arcs[-1]))
    return DigitCoordinates(arc, nearest, relative, joint_arcs[:3])


def all_digit_coordinates(points):
    return {name: digit_coordinates(points, anatomy.HAND_FINGERS[name]) for name in anatomy.FINGERS}


def digit_membership(coordinates, parts=None, inner=1.15, outer=2.2):
    """(N, 6) partition over (palm, thumb, ..., pinky) with wide, soft borders, for shape fields.

    A point within `inner` influence radii of a digit's axis belongs wholly to it; membership
    falls smoothly to zero at `outer` radii. Where digits overlap they share; the palm takes the
    rest. Points labelled as a digit by `parts` belong only to it and the palm."""
    membership = np.stack([1 - smoothstep((coordinates[name].relative_distance - inner) / (outer - inner))
                           for name in anatomy.FINGERS], axis=1)
    if parts is not None:
        for digit in range(1, 6):
            own = parts == digit
            membership[np.ix_(own, [d for d in range(5) if d != digit - 1])] = 0.0
    total = membership.sum(1, keepdims=True)
    membership = membership / np.maximum(total, 1.0)
    return np.concatenate([1 - membership.sum(1, keepdims=True), membership], axis=1)


def smoothstep(x):
    """3x^2 - 2x^3 of x clamped to [0, 1], for numpy arrays and torch tensors alike."""
    x = x.clip(0.0, 1.0) if hasattr(x, "clip") else np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def smooth_ramp(x, width):
    """0 for x < -width, x for x > width, C1 quadratic blend in between."""
    return np.where(x > width, x, np.where(x < -width, 0.0, (x + width) ** 2 / (4 * width)))
