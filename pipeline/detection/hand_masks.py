"""Hand (and forearm) masks made from the frames alone, for footage that comes without masks.

MediaPipe Hands (offline, mediapipe_hands.py) finds the 21 landmarks in a frame; from them,
in units of the palm's length L (wrist to middle knuckle):

    sure hand        the bones of the fingers and the palm drawn thin (well inside the skin)
    probably hand    the landmarks' hull grown by HULL_GROWTH L, and the forearm corridor: from
                     the wrist away from the fingers, FOREARM_WIDTH L wide
    probably not     a ring around those, and the forearm corridor's pixels beyond the wrist whose
                     colour is far from the skin's (a sleeve, a watch strap: chroma
                     farther than NOT_SKIN standard deviations from the sure-hand pixels')
    sure not         everything farther away

OpenCV's GrabCut then separates hand from background with colour models learned from those
seeds, in a window around the hand; the result is the connected part that holds the palm,
with its holes closed. GrabCut takes a defocused or motion-blurred edge whole into the hand (on
the MediaPipe sample video its masks ran 1-2 px wide all round against masks drawn by hand), so
the outline is then moved to half-way across the colour step between the skin just inside and
the background just outside (`refine_outline`), the rule the drawn masks follow (IoU with them
0.904 -> 0.930 on their 10 frames; docs/real_footage.md). Where the other hand is in the frame
too, its bones are sure background.
Frames where MediaPipe finds no hand take the landmarks of the nearest frames in time
(interpolated) when a detection lies close enough on both sides, and are otherwise left out
(footage_screen.py); a clip where it finds none fails with one line.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import label as ndimage_label

from .footage_screen import MIN_LANDMARKS_IN_MASK, FootageScreen, frames_without_hand, landmarks_in_mask
from .mask_growth import grown

FINGERS = ((0, 1, 2, 3, 4), (0, 5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (0, 17, 18, 19, 20))
PALM = (0, 1, 5, 9, 13, 17)
BONE_WIDTH = 0.07        # sure-hand bone lines, in palm lengths
HULL_GROWTH = 0.22       # probable hand: the landmarks' hull grown by this
FOREARM_WIDTH = 0.95     # probable forearm corridor width
FOREARM_LENGTH = 2.6     # and length beyond the wrist
RING = 0.6               # probable background ring beyond the probable hand
NOT_SKIN = 3.5           # chroma distance (Mahalanobis, YCrCb) beyond which the forearm is not skin
SLEEVE_START = 0.3       # ... tested from this far beyond the wrist (palm lengths)
GRABCUT_ITERATIONS = 4
GRABCUT_SEED = 0
OUTLINE_BAND = 3         # refine_outline: pixels either side of the outline it may move
OUTLINE_REACH = 12       # ... and the radius (pixels) of the neighbourhood whose skin and background it compares
MIN_COLOUR_STEP = 15.0   # ... where skin and background differ by less (RGB levels), the outline stays


def frame_mask(rgb, points, other_hand=None, refine=True):
    """(H, W) bool hand mask of an RGB frame (H, W, 3) uint8 given its 21 landmarks (21, 2) in
    pixels (corner origin); `other_hand` (21, 2), when finite: the other hand's landmarks, kept
    out of the mask. `refine`: the outline moved to half-way across the edge (refine_outline);
    False: GrabCut's own (for comparison)."""
    height, width = rgb.shape[:2]
    points = np.asarray(points, dtype=np.float64)
    palm = float(np.linalg.norm(points[9] - points[0]))
    if not np.isfinite(palm) or palm < 2:
        return np.zeros((height, width), bool)
    seeds = np.full((height, width), cv2.GC_BGD, np.uint8)
    probable = np.zeros((height, width), np.uint8)
    hull = cv2.convexHull(np.round(points).astype(np.int32))
    cv2.fillConvexPoly(probable, hull, 1)
    probable = grown(probable, HULL_GROWTH * palm)
    axis = points[0] - points[9]
    axis /= max(np.linalg.norm(axis), 1e-9)
    across = np.array([-axis[1], axis[0]]) * FOREARM_WIDTH * palm / 2
    end = points[0] + axis * FOREARM_LENGTH * palm
    corridor = np.round([points[0] + across, points[0] - across, end - across, end + across]).astype(np.int32)
    cv2.fillConvexPoly(probable, corridor, 1)
    ring = grown(probable, RING * palm)
    seeds[ring > 0] = cv2.GC_PR_BGD
    seeds[probable > 0] = cv2.GC_PR_FGD
    thickness = max(1, int(round(BONE_WIDTH * palm)))
    if other_hand is not None and np.isfinite(other_hand).all():
        seeds[_bones(other_hand, (height, width), thickness) > 0] = cv2.GC_BGD
    sure = _bones(points, (height, width), thickness)
    centre = points[list(PALM)].mean(0)
    shrunk = np.round(centre + 0.6 * (points[list(PALM)] - centre)).astype(np.int32)
    cv2.fillConvexPoly(sure, cv2.convexHull(shrunk), 1)
    seeds[sure > 0] = cv2.GC_FGD
    rows, cols = np.mgrid[0:height, 0:width]
    beyond_wrist = ((cols + 0.5 - points[0, 0]) * axis[0] + (rows + 0.5 - points[0, 1]) * axis[1]) > SLEEVE_START * palm
    seeds[(seeds == cv2.GC_PR_FGD) & beyond_wrist & _not_skin(rgb, sure > 0)] = cv2.GC_BGD
    x0, y0, w, h = cv2.boundingRect((ring > 0).astype(np.uint8))
    if w < 4 or h < 4:
        return np.zeros((height, width), bool)
    window = (slice(y0, y0 + h), slice(x0, x0 + w))
    labels = seeds[window].copy()
    if not ((labels == cv2.GC_BGD) | (labels == cv2.GC_PR_BGD)).any():
        labels[0, :] = labels[-1, :] = labels[:, 0] = labels[:, -1] = cv2.GC_PR_BGD
    background, foreground = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(GRABCUT_SEED)   # its colour models start from k-means: the same frame, the same mask
    cv2.grabCut(np.ascontiguousarray(rgb[window]), labels, None, background, foreground, GRABCUT_ITERATIONS,
                cv2.GC_INIT_WITH_MASK)
    hand = np.zeros((height, width), bool)
    hand[window] = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    hand = _clean(hand, centre)
    if not refine:
        return hand
    hand[window] = refine_outline(rgb[window], hand[window])
    return _clean(hand, centre)


def refine_outline(rgb, hand, band=OUTLINE_BAND, reach=OUTLINE_REACH):
    """(H, W) bool: the mask `hand` (H, W) bool of an RGB image (H, W, 3) with its outline moved
    to half-way across the colour step from background to skin.

    For each pixel within `band` px of the outline: the local skin and background colours (the
    means within `reach` px of the pixels more than `band` px inside / outside the mask), and
    where the pixel's colour lies on the line between them, once in RGB and once in the colour
    with its grey (luminance) part taken out. The pixel is hand where it lies more than half-way
    to the skin. Its label changes only where both say so: a blurred edge mixes both alike, while
    skin darkened by its own shading towards the outline (a rim lit at a grazing angle) keeps its
    hue and stays hand. Where the two colours differ by less than MIN_COLOUR_STEP in either, or
    either is not seen nearby, the pixel keeps its label."""
    image = rgb.astype(np.float64)
    disc = _disc(band)
    hand_bytes = hand.astype(np.uint8)
    inside = cv2.erode(hand_bytes, disc).astype(bool)
    outside = ~cv2.dilate(hand_bytes, disc).astype(bool)
    near = ~inside & ~outside
    if not near.any():
        return hand
    kernel = (2 * reach + 1, 2 * reach + 1)

    def local_mean(where):
        share = cv2.blur(where.astype(np.float64), kernel, borderType=cv2.BORDER_REFLECT)
        total = cv2.blur(image * where[..., None], kernel, borderType=cv2.BORDER_REFLECT)
        return total / np.maximum(share, 1e-9)[..., None], share

    skin, skin_share = local_mean(inside)
    background, background_share = local_mean(outside)
    changeable = near & (skin_share > 0.02) & (background_share > 0.02)
    grey = np.full(3, 1 / np.sqrt(3))
    verdicts = []
    for without_grey in (False, True):
        colours = [image, skin, background]
        if without_grey:
            colours = [colour - (colour @ grey)[..., None] * grey for colour in colours]
        pixel, inner, outer = colours
        step = inner - outer
        step_squared = (step * step).sum(-1)
        verdicts.append(((pixel - outer) * step).sum(-1) / np.maximum(step_squared, 1e-9) > 0.5)
        changeable &= step_squared > MIN_COLOUR_STEP ** 2
    in_rgb, in_hue = verdicts
    changeable &= in_rgb == in_hue
    refined = hand.copy()
    refined[changeable] = in_rgb[changeable]
    return refined


def _bones(points, shape, thickness):
    """(H, W) uint8: the fingers' and the palm's bones of the landmarks (21, 2) drawn as lines."""
    bones = np.zeros(shape, np.uint8)
    for chain in FINGERS:
        cv2.polylines(bones, [np.round(points[list(chain)]).astype(np.int32)], False, 1, thickness)
    return bones


def _not_skin(rgb, skin):
    """(H, W) bool: pixels whose chroma (Cr, Cb) lies more than NOT_SKIN standard deviations
    (Mahalanobis) from that of the `skin` pixels (H, W) bool."""
    chroma = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YCrCb)[..., 1:].astype(np.float64)
    samples = chroma[skin]
    if len(samples) < 10:
        return np.zeros(skin.shape, bool)
    offset = chroma - samples.mean(0)
    inverse = np.linalg.inv(np.cov(samples.T) + 4.0 * np.eye(2))     # at least 2 levels of spread
    distance = np.einsum("...i,ij,...j->...", offset, inverse, offset)
    return distance > NOT_SKIN ** 2


def _disc(radius):
    size = 2 * max(1, int(round(radius))) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _clean(hand, centre):
    """The connected part of the mask nearest the palm's centre, its holes closed."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(hand.astype(np.uint8), connectivity=4)
    if count <= 1:
        return hand
    x, y = np.clip(np.round(centre).astype(int), 0, [hand.shape[1] - 1, hand.shape[0] - 1])
    keep = labels[y, x] or 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    part = labels == keep
    background, _ = ndimage_label(~part)
    outer = set(np.unique(np.concatenate([background[0], background[-1], background[:, 0], background[:, -1]])))
    return part | (~np.isin(background, list(outer)) & ~part)


def screened_masks(frames, keypoints, fps, on_frame=None, refine=True, workers=1):
    """([(H, W) bool mask per frame], FootageScreen) of RGB frames (a list) and their Keypoints2D:
    frames the screen names (footage_screen.py) get an empty mask; `on_frame(number)` after each
    (in the frames' order); `refine`: frame_mask's. `workers` > 1: the frames' masks are made by
    that many processes at once (mask_workers.py; each frame's mask is the same either way)."""
    from .mask_workers import each_frame

    without_hand = frames_without_hand(keypoints.detected, fps, keypoints.points)
    other = keypoints.other_hand
    both = [] if other is None else [int(i) for i in np.flatnonzero(np.isfinite(other).all(axis=(1, 2)))]
    screen = FootageScreen(no_hand=[int(i) for i in np.flatnonzero(without_hand)], both_hands=both)
    jobs = [(rgb, points, None if other is None else other[number], refine)
            for number, (rgb, points) in enumerate(zip(frames, keypoints.points)) if not without_hand[number]]
    made = each_frame(_screened_frame_mask, jobs, workers)
    masks = []
    for number, rgb in enumerate(frames):
        mask = np.zeros(rgb.shape[:2], bool)
        if not without_hand[number]:
            mask, agrees = next(made)
            if not agrees:
                screen.mask_disagrees.append(number)
        masks.append(mask)
        if on_frame is not None:
            on_frame(number)
    return masks, screen


def _screened_frame_mask(job):
    """(frame_mask of one frame's job (rgb, points, other hand, refine), or an empty mask where
    fewer than MIN_LANDMARKS_IN_MASK of the landmarks lie in it; whether they did)."""
    rgb, points, other_hand, refine = job
    mask = frame_mask(rgb, points, other_hand, refine)
    if landmarks_in_mask(mask, points) < MIN_LANDMARKS_IN_MASK:
        return np.zeros(rgb.shape[:2], bool), False
    return mask, True


def clip_masks(frames, side, detector=None, fps=30.0, refine=True):
    """(F, H, W) bool masks of an iterable of RGB frames of one hand `side` (frames the screen
    names are empty; `refine`: frame_mask's). Returns (masks, detected (F,) bool, FootageScreen)."""
    from .mediapipe_hands import detect_keypoints

    frames = list(frames)
    keypoints = detect_keypoints(frames, side, detector)          # raises KeypointError without any hand
    masks, screen = screened_masks(frames, keypoints, fps, refine=refine)
    return np.stack(masks), keypoints.detected, screen
