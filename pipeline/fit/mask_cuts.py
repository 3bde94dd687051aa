"""Where a mask's outline is a cut, not the hand's edge: a sleeve (or anything else) ending the
visible forearm. Beyond such a line the mask says nothing about the arm, so the silhouette term
must not pull the model's forearm back to it.

Per frame, from the wrist and elbow of the initial estimate projected into the image: the
forearm runs from the wrist towards the elbow; the mask's pixels in a band around that line
(BAND times the projected forearm length on either side) reach to some distance along it. If
they stop short of the elbow by more than SLACK of the forearm's length, and not at the image's
edge, the mask is cut there, and the band beyond that distance (less any pixel the mask does
show as hand) is left out of the silhouette term and of the silhouette scores. A mask that
reaches the elbow or the image's edge, and a hand-only model, have no cut.
"""
from __future__ import annotations

import numpy as np

BAND = 0.35     # half-width of the forearm band, in projected forearm lengths
SLACK = 0.12    # a mask this much (in forearm lengths) short of the elbow is cut
BORDER_PX = 2   # a mask this close to the image's edge runs out of the picture, not into a sleeve


def cut_region(mask, wrist, elbow):
    """(H, W) bool: the part of the forearm band beyond the mask's cut (all False without a
    cut), for a mask (H, W) bool and the wrist and elbow (2,) in pixels."""
    height, width = mask.shape
    axis = np.asarray(elbow, np.float64) - np.asarray(wrist, np.float64)
    length = float(np.linalg.norm(axis))
    region = np.zeros_like(mask, dtype=bool)
    if length < 4:                                  # the forearm points at the camera: nothing to cut
        return region
    axis /= length
    rows, cols = np.mgrid[0:height, 0:width]
    offset = np.stack([cols + 0.5 - wrist[0], rows + 0.5 - wrist[1]], -1)
    along = offset @ axis
    across = np.abs(offset @ np.array([-axis[1], axis[0]]))
    band = (along > 0) & (across < BAND * length)
    reach = along[band & mask]
    if not len(reach):
        return region
    end = float(np.percentile(reach, 99.5))
    if end > (1 - SLACK) * length:
        return region
    tip = band & mask & (along > end - 2)
    tip_rows, tip_cols = np.nonzero(tip)
    if len(tip_rows) and (tip_rows.min() < BORDER_PX or tip_cols.min() < BORDER_PX
                          or tip_rows.max() >= height - BORDER_PX or tip_cols.max() >= width - BORDER_PX):
        return region
    return band & (along > end) & ~mask


def cut_regions(masks, wrists, elbows):
    """(F, H, W) bool cut regions of masks (F, H, W) with per-frame wrists and elbows (F, 2)."""
    return np.stack([cut_region(mask, wrist, elbow) for mask, wrist, elbow in zip(masks, wrists, elbows)])
