"""Which frames of a clip a fit uses.

Held-out frames are the frames a fit leaves out so that its avatar can be judged on frames it
never saw (HARP's appearance evaluation; evaluate/held_out.py fits only pose and light on
them, with the appearance frozen). Rule: with `every` = N, frames N-1, 2N-1, 3N-1, ... (every
N-th frame counting from one) are held out, so the first frame always stays in the fit.
Long clips are subsampled evenly over time (select_frames).
"""
from __future__ import annotations

import numpy as np


def held_out_frames(count, every=None):
    """Sorted sequence frame indices (K,) held out of a fit of `count` frames (none if `every`
    is None or 0). Raises ValueError for every < 2, which would leave nothing to fit."""
    if not every:
        return np.zeros(0, dtype=np.int64)
    if int(every) < 2:
        raise ValueError(f"hold_out_every must be at least 2, got {every}")
    frames = np.arange(count)
    return frames[(frames + 1) % int(every) == 0]


def select_frames(count, maximum, exclude=()):
    """Evenly spaced frame indices (all of them when the clip is short enough): an even spread
    over time keeps the clip's coverage of views for flipping and turning motions. Frames in
    `exclude` (held out for evaluation) are never chosen."""
    candidates = np.setdiff1d(np.arange(count), np.asarray(exclude, dtype=np.int64))
    if len(candidates) <= maximum:
        return candidates
    return candidates[np.unique(np.round(np.linspace(0, len(candidates) - 1, maximum)).astype(int))]


def validation_frames(count, wanted, per_frames=10, exclude=()):
    """Sorted sequence frame indices (V,) that a fit keeps out to score itself as it runs
    (fit/validation.py): `wanted` of them, at most one in `per_frames` of the clip's frames
    (none for a short clip), at the centres of equal parts of the frames not in `exclude`, so
    each has fitted neighbours on both sides."""
    candidates = np.setdiff1d(np.arange(count), np.asarray(exclude, dtype=np.int64))
    number = min(int(wanted or 0), count // per_frames, len(candidates) // 3)
    if number <= 0:
        return np.zeros(0, dtype=np.int64)
    return candidates[((np.arange(number) + 0.5) * len(candidates) / number).astype(int)]


def neighbours(fitted, targets):
    """(left, right, fraction) for each target frame (T,): the indices into the sorted `fitted`
    frames (F,) of its nearest fitted frames before and after it, and how far it lies between
    them (0 at left, 1 at right); beyond the ends both are the nearest end."""
    fitted, targets = np.asarray(fitted), np.asarray(targets)
    right = np.clip(np.searchsorted(fitted, targets), 0, len(fitted) - 1)
    left = np.clip(right - 1, 0, len(fitted) - 1)
    left = np.where(fitted[right] <= targets, right, left)
    span = (fitted[right] - fitted[left]).astype(np.float64)
    fraction = np.where(span > 0, (targets - fitted[left]) / np.where(span > 0, span, 1.0), 0.0)
    return left, right, np.clip(fraction, 0.0, 1.0)
