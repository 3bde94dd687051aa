"""A mask grown by a disc, at a cost that does not grow with the disc.

OpenCV's dilation by an elliptical kernel visits every kernel pixel at every image pixel: growing
a hand's landmarks by most of a palm's length on a 640 px frame took 0.2-0.8 s a call, a third of
the time a mask made from the footage took (detection/hand_masks.py). A pixel lies within a disc
of radius r of the mask exactly where its Euclidean distance to the mask is at most r, and OpenCV's
exact distance transform finds that in one pass over the image, whatever r is.
"""
from __future__ import annotations

import cv2
import numpy as np


def grown(mask, radius) -> np.ndarray:
    """(H, W) uint8, 1 where a pixel lies within `radius` pixels (rounded to a whole pixel, at least
    one) of a pixel of `mask` (H, W; nonzero is in), 0 elsewhere: the mask dilated by a disc of that
    radius (cv2.dilate with a MORPH_ELLIPSE kernel of 2 radius + 1 differs from it by a pixel at
    some places along the outline: its rasterised ellipse is not quite a Euclidean disc)."""
    mask = np.asarray(mask)
    if not mask.any():
        return np.zeros(mask.shape, np.uint8)
    reach = max(1, int(round(radius)))
    distance = cv2.distanceTransform((mask == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return (distance <= reach + 0.25).astype(np.uint8)
