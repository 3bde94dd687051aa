"""What the footage shows, frame by frame, before masks are made from it: the frames the fit
cannot serve are named and left out, instead of fitted to a mask of something else.

    no hand found     MediaPipe found no hand in the frame, and none within MAX_GAP_SECONDS of
                      it on both sides: before the hand enters, after it leaves, or in a long
                      gap whose two ends disagree (the hand moved on: the wrist more than
                      STILL_HAND palm lengths, or the palm's size by more than STILL_SCALE).
                      Landmarks there would be held or interpolated over a hand that is not
                      there, and GrabCut would cut a mask from whatever lies under them (a chin,
                      a blob on the floor). Short gaps, and long ones where the hand held still
                      (a blurred thumbs-up MediaPipe misses for seconds), are interpolated.
    both hands        MediaPipe found two hands: the one of the clip's side is taken, and the
                      other's bones are seeded as background, so its pixels stay out of the mask
                      (hand_masks.frame_mask).
    mask disagrees    fewer than MIN_LANDMARKS_IN_MASK of the taken hand's landmarks (those
                      inside the frame) lie in its mask, grown by LANDMARK_REACH palm lengths:
                      the cut went to something else.

A hand hidden behind an object is not told apart from a hand that is not there: where
MediaPipe still finds it, the frame is kept and the occluder goes wherever GrabCut puts it.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .mask_growth import grown

MAX_GAP_SECONDS = 0.2          # missing detections interpolated across at most this long a gap ...
STILL_HAND = 0.3               # ... or across any gap whose ends put the wrist this close (palm lengths)
STILL_SCALE = 0.2              # ... and the palm's length within this share
MIN_LANDMARKS_IN_MASK = 0.6    # share of the landmarks a mask must hold
LANDMARK_REACH = 0.15          # palm lengths: a landmark this close to the mask counts as in it


@dataclasses.dataclass
class FootageScreen:
    """Frames named by the screen (indices into the clip's frames)."""

    no_hand: list
    both_hands: list
    mask_disagrees: list = dataclasses.field(default_factory=list)

    def lines(self, frame_ranges, side, total):
        """One line each for what was seen, in a user's words (empty when nothing was)."""
        lines = []
        if self.no_hand:
            lines.append(f"no hand found in {len(self.no_hand)} of {total} frames (none detected within "
                         f"{MAX_GAP_SECONDS:g} s, nor the hand held still across the gap): left out: "
                         f"{frame_ranges(self.no_hand)}")
        if self.both_hands:
            lines.append(f"both hands in {len(self.both_hands)} frames: the {side} one taken, the other kept out "
                         f"of its masks: {frame_ranges(self.both_hands)}")
        if self.mask_disagrees:
            lines.append(f"the mask disagrees with the landmarks in {len(self.mask_disagrees)} frames (fewer than "
                         f"{MIN_LANDMARKS_IN_MASK:.0%} of them inside it): left out: "
                         f"{frame_ranges(self.mask_disagrees)}")
        return lines

    def dropped(self) -> dict:
        """{reason: frames} of the frames left out, as sequence.json records them."""
        return {"no_hand_found": list(self.no_hand), "mask_disagrees": list(self.mask_disagrees)}


def frames_without_hand(detected, fps, points=None, max_gap_seconds=MAX_GAP_SECONDS):
    """(F,) bool: frames with no detection of their own that cannot borrow one, those before the
    first and after the last detection and those in a run of misses longer than the gap allows
    (max_gap_seconds * fps frames, at least 1) unless, with landmarks `points` (F, 21, 2), the
    hand is in the same place at both ends (module docstring)."""
    detected = np.asarray(detected, dtype=bool)
    longest = max(1, int(round(max_gap_seconds * fps)))
    unserved = np.zeros(len(detected), dtype=bool)
    found = np.flatnonzero(detected)
    if not len(found):
        unserved[:] = True
        return unserved
    unserved[:found[0]] = True
    unserved[found[-1] + 1:] = True
    for before, after in zip(found[:-1], found[1:]):
        if after - before - 1 > longest and not (points is not None and _held_still(points[before], points[after])):
            unserved[before + 1:after] = True
    return unserved


def _held_still(first, last):
    """Whether two frames' landmarks (21, 2) show the hand in the same place at the same size."""
    palm = [float(np.linalg.norm(points[9] - points[0])) for points in (first, last)]
    if min(palm) < 1e-6:
        return False
    moved = float(np.linalg.norm(first[0] - last[0])) / max(palm)
    return moved < STILL_HAND and abs(palm[0] - palm[1]) < STILL_SCALE * max(palm)


def landmarks_in_mask(mask, points):
    """Share of the landmarks (21, 2) px inside the frame that lie in the mask (H, W) bool, grown
    by LANDMARK_REACH palm lengths; 1 when none lies inside the frame."""
    height, width = mask.shape
    points = np.asarray(points, dtype=np.float64)
    palm = float(np.linalg.norm(points[9] - points[0]))
    cols, rows = np.floor(points[:, 0]).astype(int), np.floor(points[:, 1]).astype(int)
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    if not inside.any():
        return 1.0
    near = grown(mask, LANDMARK_REACH * palm)
    return float(near[rows[inside], cols[inside]].astype(bool).mean())
