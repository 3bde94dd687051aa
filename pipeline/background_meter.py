"""The camera's exposure meter: the colour of a frame's background, away from the hand. A
camera's automatic exposure and white balance change the whole picture alike, so the
background's colour over a clip tells them apart from the skin's (fit/problem.py)."""
from __future__ import annotations

import cv2
import numpy as np


def interquartile_mean(values):
    """(C,) per column of values (N, C): the mean of the values between its quartiles (robust
    as a median, but not stuck to 8-bit levels where the values are few levels apart)."""
    values = np.sort(np.asarray(values, dtype=np.float64), axis=0)
    count = len(values)
    low, high = count // 4, max(count // 4 + 1, count - count // 4)
    return values[low:high].mean(0)


def frame_background_colour(image, hand, margin, recorded=None):
    """(3,) colour of the pixels of image (H, W, 3) farther than `margin` px from the hand (H, W)
    bool (and `recorded`, (H, W) bool, where given); NaN where there are none."""
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    away = cv2.dilate(np.asarray(hand, dtype=np.uint8), kernel) == 0
    if recorded is not None:
        away &= recorded
    return interquartile_mean(image[away]) if away.any() else np.full(3, np.nan)
