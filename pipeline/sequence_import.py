"""`harp import-video`: a sequence folder from a video (or image folder) and, optionally, its
masks.

Frames and masks are each a video file (anything OpenCV's VideoCapture decodes) or a folder of
images (.png, .jpg, .jpeg, .bmp, .tif, .tiff, .webp; taken in natural name order, so 2.png
comes before 10.png). They are paired by order. Masks are binarised at half intensity (the
brightest channel >= 128 is hand), so lossy mask videos work. Without masks the import makes
its own (detection/hand_masks.py: MediaPipe's landmarks seed OpenCV's GrabCut), at a working
scale of at most AUTO_MASK_SIZE pixels, a process per core at once (`workers`,
detection/mask_workers.py); masks a user gives always win.

What the window holds (`window`): the hand ("hand", default: the mask's box cut to MediaPipe's
landmarks, grown by HAND_BOX_GROWTH, so that a forearm reaching to the frame's edge does not
make the hand small: on a 1080 x 1920 phone clip of a hand with its forearm the whole mask's
window was 1659 px, the hand a third of it; the forearm then leaves the crop as it would leave
the frame), or the whole mask ("mask"; also where MediaPipe finds no hand in the clip, or a
frame's landmarks miss its mask).
The crop (`crop`): a square window that follows the hand ("frame"), or one window for the whole
clip ("clip"); "auto" follows the hand where that shows it at least PER_FRAME_GAIN times larger
and every window fits inside the frame. A following window has one size for the clip (the
largest mask box, grown by `margin` of its longer side on every side) and moves with the hand:
each frame's window holds that frame's mask box, centred on the box's centre smoothed over time
(a Gaussian of FOLLOW_SECONDS), inside the frame; each frame then has its own principal point
(sequence.json `principal_points`), the focal length stays the clip's. The clip's window is the
union of the masks' bounding boxes, grown by `margin` (a fraction of the box's longer side) on
every side, made square about its centre and shifted to stay inside the frame where it fits.
Where it still reaches past the frame (a hand near the edge of a narrow video), the import
invents nothing: those pixels are black and sequence.json marks them invalid (`valid_region`),
so no image term or score counts them. The window is resized to `size` x `size`, but never
enlarged: a small source keeps its own scale. The import also measures each source frame's
background colour, away from the hand (sequence.json `background_colour`: the fit's exposure
meter; the whole frame, as a following crop moves over the scene).
The intrinsics follow exactly (pixel-corner convention of pipeline/formats/camera.py):
cropping at (x0, y0) moves the principal point by (-x0, -y0); resizing by s scales fx, fy,
cx, cy by s.

Intrinsics of the original frames: `K` (fx, fy, cx, cy in pixels), or a horizontal field of
view, or by default DEFAULT_FOV_DEG across the frame's longer side: phone main cameras have
a 24 - 26 mm (35 mm equivalent) lens, and 26 mm over the 34.6 mm long side of a 4:3 frame
(diagonal 43.3 mm) gives 2 atan(17.3 / 26) = 67 degrees; 16:9 video keeps the sensor's width.

Frames whose mask is empty (fewer than MIN_MASK_PIXELS hand pixels: the hand left the view or
the segmenter missed it) are left out, reported in one warning line and recorded in
sequence.json (`metadata.source_frames`, `metadata.dropped_frames`). Masks made from the footage
are screened first (detection/footage_screen.py): frames with no hand found near them in time and
frames whose mask disagrees with the landmarks are left out, and frames showing both hands are
named, one line each; every other problem stops
the import with one ImportVideoError line. The sequence is written into a hidden folder next
to `out` and renamed into place at the end, so a failed import leaves nothing behind.
FFmpeg's and the image libraries' own complaints (written straight to file descriptor 2) are
kept off the terminal, so a damaged file gives that one line and nothing else.
"""
from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np

from .formats import sequence_folder as seq
from .formats.camera import intrinsics_from_fov
from .quiet_stderr import native_stderr_silenced

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
DEFAULT_FOV_DEG = 67.0          # across the longer side of the original frame (phone main camera)
DEFAULT_FPS = 30.0              # for image folders
MIN_MASK_PIXELS = seq.MIN_MASK_PIXELS  # fewer hand pixels than this: an empty mask frame
MIN_FRAMES = 2                  # the fit needs more than one view
MASK_THRESHOLD = 128
AUTO_MASK_SIZE = 640            # long side of the frames masks are made at (then scaled back)
# the window's side is kept up to this many pixels (never enlarged): the hand at its own pixel size in the
# source, which the finer albedo solve reads (FitSettings.solve_resolution, grow_texture); a 1080p phone clip
# shows the hand at 400-900 px. At 448 (until then) the phone-like clip's 873 px window lost the detail that a
# 512 texture solved from its own frames keeps (docs/fidelity.md, "Texture detail at the footage's resolution")
DEFAULT_SIZE = 1024
CROPS = ("auto", "frame", "clip")
WINDOWS = ("hand", "mask")
SIDE_VOTES = 10                 # frames MediaPipe's handedness is asked about for --side auto
HAND_BOX_GROWTH = 0.1           # the landmarks' box grown by this share of its longer side on each side: the
#                                 joints MediaPipe marks lie inside the palm's edges and the fingertips
PER_FRAME_GAIN = 1.1            # crop=auto follows the hand where it is then this much larger (at 1.25 the MediaPipe
#                                 sample video's hand-held window, 385 px for the clip against 346 following, stayed still)
FOLLOW_SECONDS = 0.1            # how much the following window's centre is smoothed over time
METER_SIZE = 320                # long side at which each source frame's background colour is measured
METER_MARGIN = 0.03             # ... away from the hand by this share of that side


class ImportVideoError(ValueError):
    """The video, images or masks cannot be imported (one-line message)."""


# --- sources ----------------------------------------------------------------------------------
def _natural_key(path):
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


class FrameSource:
    """Frames of a video file or an image folder, in order: `for index, image in source`.

    Images are (H, W, 3) uint8 RGB (`grey=False`) or (H, W) uint8 (`grey=True`, the brightest
    channel of a colour image)."""

    def __init__(self, path, label, grey=False, limit=None):
        self.path, self.label, self.grey, self.limit = Path(path), label, grey, limit
        if not self.path.exists():
            raise ImportVideoError(f"{label} not found: {self.path}")
        if self.path.is_dir():
            self.files = sorted((p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                                key=_natural_key)
            if not self.files:
                raise ImportVideoError(f"{label} folder {self.path} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        else:
            self.files = None
            self._open_video().release()

    @property
    def fps(self):
        """Frame rate stored in a video file (None for image folders or when unknown)."""
        if self.files is not None:
            return None
        import cv2

        capture = self._open_video()
        fps = capture.get(cv2.CAP_PROP_FPS)
        capture.release()
        return float(fps) if fps and math.isfinite(fps) and 0 < fps < 1000 else None

    @property
    def stored_frames(self):
        """Frame count a video file's header states (None for image folders or when unknown);
        more than can be decoded when the file is damaged or truncated."""
        if self.files is not None:
            return None
        import cv2

        capture = self._open_video()
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        capture.release()
        return int(count) if count and math.isfinite(count) and count > 0 else None

    def _open_video(self):
        import cv2

        with native_stderr_silenced():
            capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            raise ImportVideoError(f"cannot read {self.label} {self.path}: not a video OpenCV can decode "
                                   "(or a folder of images)")
        return capture

    def __iter__(self):
        import cv2

        if self.files is not None:
            for index, file in enumerate(self.files[:self.limit]):
                with native_stderr_silenced():
                    image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
                if image is None:
                    raise ImportVideoError(f"cannot read {self.label} image {file}")
                yield index, self._convert(image)
            return
        capture = self._open_video()
        index = 0
        try:
            while self.limit is None or index < self.limit:
                with native_stderr_silenced():
                    ok, image = capture.read()
                if not ok:
                    break
                yield index, self._convert(image)
                index += 1
        finally:
            capture.release()
        if index == 0:
            raise ImportVideoError(f"cannot read {self.label} {self.path}: no frame could be decoded")

    def _convert(self, image):
        import cv2

        if image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        if image.ndim == 3 and image.shape[2] == 4:
            image = image[..., :3]
        if self.grey:
            return image.max(axis=2) if image.ndim == 3 else image
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        return np.ascontiguousarray(image[..., ::-1])


# --- crop and intrinsics ----------------------------------------------------------------------
def parse_intrinsics(text):
    """"fx,fy,cx,cy" -> K (3, 3)."""
    try:
        fx, fy, cx, cy = (float(value) for value in str(text).split(","))
    except ValueError:
        raise ImportVideoError(f"--K needs four numbers fx,fy,cx,cy in pixels, got {text!r}") from None
    if not (fx > 0 and fy > 0 and all(math.isfinite(v) for v in (cx, cy))):
        raise ImportVideoError(f"--K needs positive focal lengths, got {text!r}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def source_intrinsics(width, height, K=None, fov_deg=None):
    """K (3, 3) of the original frames: given, from a horizontal field of view, or the default
    phone camera (DEFAULT_FOV_DEG across the longer side). Returns (K, description)."""
    if K is not None and fov_deg is not None:
        raise ImportVideoError("give either --K or --fov, not both")
    if K is not None:
        return np.asarray(K, dtype=np.float64), "given K"
    if fov_deg is not None:
        if not 1.0 <= fov_deg <= 170.0:
            raise ImportVideoError(f"--fov must be between 1 and 170 degrees, got {fov_deg}")
        return intrinsics_from_fov(width, height, fov_deg), f"horizontal field of view {fov_deg:g} degrees"
    K = intrinsics_from_fov(max(width, height), max(width, height), DEFAULT_FOV_DEG)
    K[0, 2], K[1, 2] = width / 2.0, height / 2.0
    return K, f"default phone camera: {DEFAULT_FOV_DEG:g} degrees across the longer side"


def crop_window(box, width, height, margin):
    """Square window (x0, y0, side) in pixels around box (x_min, y_min, x_max, y_max) (pixel
    edges), grown by `margin` times the box's longer side on each side, inside the image
    where it fits (it may extend past the image when it is larger than the image)."""
    x_min, y_min, x_max, y_max = box
    side = int(math.ceil(max(x_max - x_min, y_max - y_min) * (1 + 2 * margin)))
    side = max(side, 1)
    x0 = int(round((x_min + x_max - side) / 2))
    y0 = int(round((y_min + y_max - side) / 2))
    if side <= width:
        x0 = min(max(x0, 0), width - side)
    if side <= height:
        y0 = min(max(y0, 0), height - side)
    return x0, y0, side


def following_windows(boxes, width, height, margin, fps):
    """(side, (N, 2) int x0, y0 per box) of square windows of one side that follow the hand:
    boxes (N, 4) (x_min, y_min, x_max, y_max), in frame order. Each window holds its box and
    lies inside the width x height frame (side None where the largest box, grown, does not fit);
    between those bounds its centre is the boxes' centres smoothed over time (FOLLOW_SECONDS)."""
    from scipy.ndimage import gaussian_filter1d

    boxes = np.asarray(boxes, dtype=np.float64)
    side = int(math.ceil(max((boxes[:, 2:] - boxes[:, :2]).max(), 1) * (1 + 2 * margin)))
    if side > min(width, height):
        return None, None
    half = side / 2.0
    centres = (boxes[:, :2] + boxes[:, 2:]) / 2
    smoothed = gaussian_filter1d(centres, sigma=max(FOLLOW_SECONDS * fps, 1e-3), axis=0, mode="nearest")
    low = np.maximum(boxes[:, 2:] - half, half)                        # holds the box, inside the frame
    high = np.minimum(boxes[:, :2] + half, np.array([width, height]) - half)
    corners = np.round(np.clip(smoothed, low, high) - half).astype(int)
    corners = np.clip(corners, 0, np.array([width, height]) - side)
    return side, corners


def valid_region(x0, y0, side, size, width, height):
    """[x0, y0, x1, y1] of the output pixels that hold recorded pixels of the width x height
    frame, after cropping the window (x0, y0, side) and resizing it to size; None when all do.
    Edge pixels only partly inside the frame count as invalid."""
    scale = size / side
    region = [math.ceil(max(0, -x0) * scale - 1e-9), math.ceil(max(0, -y0) * scale - 1e-9),
              math.floor(min(side, width - x0) * scale + 1e-9), math.floor(min(side, height - y0) * scale + 1e-9)]
    return None if region == [0, 0, size, size] else region


def crop_intrinsics(K, x0, y0, side, size):
    """K after cropping the square window (x0, y0, side) and resizing it to size x size."""
    scale = size / side
    K = np.array(K, dtype=np.float64)
    K[0, 2] -= x0
    K[1, 2] -= y0
    K[:2] *= scale
    return K


def crop_and_resize(image, x0, y0, side, size, mask=False):
    """Cut the square window out of an image (black past its edges: nothing is invented) and
    resize to size x size (area averaging; masks re-binarised)."""
    import cv2

    height, width = image.shape[:2]
    pad = max(0, -x0, -y0, x0 + side - width, y0 + side - height)
    if pad:
        image = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
        x0, y0 = x0 + pad, y0 + pad
    window = image[y0:y0 + side, x0:x0 + side]
    interpolation = cv2.INTER_AREA if side >= size else cv2.INTER_LINEAR
    resized = cv2.resize(window, (size, size), interpolation=interpolation)
    if mask:
        return np.where(resized >= MASK_THRESHOLD, 255, 0).astype(np.uint8)
    return resized


# --- the import -------------------------------------------------------------------------------
def _scan(frames, masks, max_frames):
    """Check frames against masks (count, size, content); return (size, boxes, empty) where boxes
    maps a kept frame index to its mask's bounding box."""
    frame_iter, mask_iter = iter(frames), iter(masks)
    size, boxes, empty, count = None, {}, [], 0
    while max_frames is None or count < max_frames:
        frame = next(frame_iter, None)
        mask = next(mask_iter, None)
        if frame is None and mask is None:
            break
        if frame is None or mask is None:
            frame_count = count + (frame is not None) + sum(1 for _ in frame_iter)
            mask_count = count + (mask is not None) + sum(1 for _ in mask_iter)
            raise ImportVideoError(f"frame/mask count mismatch: {frame_count} frames, {mask_count} masks"
                                   + _damage_hint(frames, frame_count) + _damage_hint(masks, mask_count))
        index, image = frame
        _, mask_image = mask
        frame_size = (image.shape[1], image.shape[0])
        size = size or frame_size
        if frame_size != size:
            raise ImportVideoError(f"frame {index} is {frame_size[0]}x{frame_size[1]}, frame 0 is {size[0]}x{size[1]}")
        if (mask_image.shape[1], mask_image.shape[0]) != size:
            raise ImportVideoError(f"mask {index} is {mask_image.shape[1]}x{mask_image.shape[0]}, "
                                   f"frame {index} is {size[0]}x{size[1]}")
        hand = mask_image >= MASK_THRESHOLD
        pixels = int(hand.sum())
        if pixels == hand.size:
            raise ImportVideoError(f"mask {index} is all foreground (every pixel is hand); masks must be "
                                   "white (>= 128) on the hand and black elsewhere - inverted?")
        if pixels < MIN_MASK_PIXELS:
            empty.append(index)
        else:
            rows, cols = np.nonzero(hand)
            boxes[index] = (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1)
        count += 1
    return size, boxes, empty, count


def _damage_hint(source, decoded):
    """"; the video ... states N frames ..." when a video file decoded fewer frames than its
    header states (a damaged or truncated file), else ""."""
    if source.limit is not None:
        return ""
    stored = source.stored_frames
    if stored is None or decoded >= stored:
        return ""
    return (f"; the {source.label} {source.path.name} states {stored} frames but only {decoded} could be "
            "decoded (damaged or truncated file?)")


class AutoMasks:
    """Masks made from the frames themselves (detection/hand_masks.py), iterated like a
    FrameSource of masks: (index, (H, W) uint8) at the frames' own size."""

    label, limit, stored_frames = "masks (made from the footage)", None, None

    def __init__(self, frames, side, log=print, workers=None):
        from .detection.hand_masks import screened_masks
        from .detection.mediapipe_hands import detect_keypoints

        self.path = frames.path
        small, self.scale, self.size = mask_size_frames(frames)
        self.side = side = _side_of(small, side, log)
        log(f"making masks from the footage: MediaPipe landmarks in {len(small)} frames")
        self.keypoints = keypoints = detect_keypoints(small, side)

        def progress(number):
            if (number + 1) % max(1, len(small) // 10) == 0 or number + 1 == len(small):
                log(f"masks: {number + 1}/{len(small)} frames")

        masks, self.screen = screened_masks(small, keypoints, frames.fps or DEFAULT_FPS, progress, workers=workers)
        for line in self.screen.lines(seq.frame_ranges, side, len(small)):
            log(line)
        self.masks = [np.packbits(mask) for mask in masks]
        self.small_shape = small[0].shape[:2]
        self.detected = keypoints.detected

    def __iter__(self):
        import cv2

        count = self.small_shape[0] * self.small_shape[1]
        for index, packed in enumerate(self.masks):
            mask = np.unpackbits(packed, count=count).reshape(self.small_shape).astype(np.float32)
            if self.small_shape[::-1] != self.size:
                mask = cv2.resize(mask, self.size, interpolation=cv2.INTER_LINEAR)
            yield index, np.where(mask >= 0.5, 255, 0).astype(np.uint8)


def hand_boxes(mask_boxes, landmarks, detected=None, growth=HAND_BOX_GROWTH):
    """(N, 4) boxes the crop holds: each mask box (N, 4) (x_min, y_min, x_max, y_max) cut to the
    hand, the box of its frame's landmarks (N, 21, 2) grown by `growth` of its longer side on
    each side, where MediaPipe saw the hand in that frame (`detected` (N,) bool, default all).
    A mask box stays whole where the landmarks are only interpolated (a guess could cut the
    hand), where the grown landmarks' box misses it (a wrong detection), and everywhere when
    `landmarks` is None."""
    mask_boxes = np.asarray(mask_boxes, dtype=np.float64)
    if landmarks is None:
        return mask_boxes
    landmarks = np.asarray(landmarks, dtype=np.float64)
    low, high = landmarks.min(axis=1), landmarks.max(axis=1)
    grow = growth * (high - low).max(axis=1, keepdims=True)
    hand = np.concatenate([low - grow, high + grow], axis=1)
    cut = np.concatenate([np.floor(np.maximum(mask_boxes[:, :2], hand[:, :2])),
                          np.ceil(np.minimum(mask_boxes[:, 2:], hand[:, 2:]))], axis=1)
    use = (cut[:, 2:] > cut[:, :2]).all(axis=1) & np.isfinite(cut).all(axis=1)
    if detected is not None:
        use &= np.asarray(detected, dtype=bool)
    return np.where(use[:, None], cut, mask_boxes)


def _landmarks(frames, mask_source, kept, side, log):
    """((len(kept), 21, 2) MediaPipe's landmarks of the kept frames (indices) in source pixels,
    gaps interpolated; (len(kept),) whether each was seen; the side used), or (None, None, side)
    where MediaPipe finds no hand in the clip."""
    from .detection.mediapipe_hands import detect_keypoints
    from .formats.keypoint_file import KeypointError

    if isinstance(mask_source, AutoMasks):     # the masks were made from these very landmarks
        keypoints, scale, side = mask_source.keypoints, mask_source.scale, mask_source.side
    else:
        small, scale, _ = mask_size_frames(frames)
        side = _side_of(small, side, log)
        try:
            keypoints = detect_keypoints(small, side)
        except KeypointError:
            log("crop: MediaPipe finds no hand in the frames, so the window holds the whole masks")
            return None, None, side
    return np.asarray(keypoints.points)[kept] / scale, np.asarray(keypoints.detected)[kept], side


def mask_size_frames(frames):
    """(the frames, an iterable of (index, RGB image), at most AUTO_MASK_SIZE pixels on their long
    side: the size masks are made at; that scale; (width, height) of the frames)."""
    import cv2

    small, scale, size = [], 1.0, None
    for _, image in frames:
        size = (image.shape[1], image.shape[0])
        scale = min(1.0, AUTO_MASK_SIZE / max(size))
        small.append(image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale,
                                                            interpolation=cv2.INTER_AREA))
    return small, scale, size


def _side_of(small, side, log):
    """`side`, or for "auto" MediaPipe's vote over up to SIDE_VOTES frames spread over `small`."""
    if side != "auto":
        return side
    from .detection.mediapipe_hands import guess_hand_side

    sample = np.unique(np.linspace(0, len(small) - 1, min(len(small), SIDE_VOTES)).round().astype(int))
    side, votes = guess_hand_side(small[i] for i in sample)
    log(f"hand side: {side} (MediaPipe votes right {votes['right']}, left {votes['left']} in {len(sample)} frames; "
        "--side overrides)")
    return side


def import_video(video, masks, out, size=DEFAULT_SIZE, K=None, fov_deg=None, side="auto", fps=None, margin=0.15,
                 max_frames=None, overwrite=False, log=print, warn=None, crop="auto", window="hand", workers=None):
    """Write the sequence folder `out` from `video` and `masks` (files or image folders; None:
    made from the frames); returns its SequenceInfo. See the module docstring."""
    warn = warn or log
    if size < 32:
        raise ImportVideoError(f"--size must be at least 32 pixels, got {size}")
    if not 0 <= margin <= 2:
        raise ImportVideoError(f"--margin must be between 0 and 2, got {margin}")
    if max_frames is not None and max_frames < MIN_FRAMES:
        raise ImportVideoError(f"--max-frames must be at least {MIN_FRAMES}, got {max_frames}")
    if fps is not None and not fps > 0:
        raise ImportVideoError(f"--fps must be positive, got {fps}")
    if side not in ("right", "left", "auto"):
        raise ImportVideoError(f"--side must be right, left or auto, got {side!r}")
    if crop not in CROPS:
        raise ImportVideoError(f"--crop must be one of {', '.join(CROPS)}, got {crop!r}")
    if window not in WINDOWS:
        raise ImportVideoError(f"--window must be one of {', '.join(WINDOWS)}, got {window!r}")
    if workers is not None and workers < 1:
        raise ImportVideoError(f"the mask workers must be at least 1, got {workers}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ImportVideoError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise ImportVideoError(f"output folder {out} is not empty (use --overwrite to replace its sequence)")
    frames = FrameSource(video, "video", limit=max_frames)
    if masks is None:
        try:
            mask_source = AutoMasks(frames, side, log, workers)
        except ValueError as error:   # no hand in the footage
            raise ImportVideoError(f"no masks given, and none could be made: {error}") from None
    else:
        mask_source = FrameSource(masks, "masks", grey=True, limit=max_frames)
    (width, height), boxes, empty, count = _scan(frames, mask_source, max_frames)
    if not boxes:
        raise ImportVideoError(f"every mask is empty (fewer than {MIN_MASK_PIXELS} hand pixels in each of {count} frames)")
    if len(boxes) < MIN_FRAMES:
        raise ImportVideoError(f"not enough frames: {len(boxes)} with a hand in the mask, need at least {MIN_FRAMES}")
    named = mask_source.screen.dropped() if isinstance(mask_source, AutoMasks) else {}
    named_frames = {index for frames_of_reason in named.values() for index in frames_of_reason}
    empty = [index for index in empty if index not in named_frames]
    if empty:
        warn(f"warning: left out {len(empty)} frame(s) with an empty mask: {seq.frame_ranges(empty)}")
    K_source, camera_note = source_intrinsics(width, height, K, fov_deg)
    kept = sorted(boxes)
    stacked = np.array([boxes[index] for index in kept])
    landmarks = detected = None
    if window == "hand":
        landmarks, detected, side = _landmarks(frames, mask_source, kept, side, log)
    whole = stacked
    stacked = hand_boxes(stacked, landmarks, detected)
    holds = "hand" if landmarks is not None else "mask"
    beyond = float(np.max(np.maximum(whole[:, 2:] - whole[:, :2], 0).max(axis=1)
                          - np.maximum(stacked[:, 2:] - stacked[:, :2], 0).max(axis=1)))
    union = (stacked[:, 0].min(), stacked[:, 1].min(), stacked[:, 2].max(), stacked[:, 3].max())
    clip_fps = fps or frames.fps or DEFAULT_FPS
    x0, y0, side_px = crop_window(union, width, height, margin)
    follow_side, corners = following_windows(stacked, width, height, margin, clip_fps)
    if crop == "frame" and follow_side is None:
        raise ImportVideoError("--crop frame: the hand's window does not fit inside the frame; use --crop clip")
    follows = crop == "frame" or (crop == "auto" and follow_side is not None
                                  and side_px >= PER_FRAME_GAIN * follow_side)
    clip_side = side_px
    if follows:
        side_px = follow_side
    else:
        corners = np.tile([x0, y0], (len(kept), 1))
    size = min(size, side_px)        # a small source keeps its own scale
    frame_K = [crop_intrinsics(K_source, cx, cy, side_px, size) for cx, cy in corners]
    info = seq.SequenceInfo(fps=clip_fps, width=size, height=size, frame_count=len(boxes),
                            hand_side="right", K=frame_K[0],
                            valid_region=None if follows else valid_region(x0, y0, side_px, size, width, height),
                            principal_points=np.array([K_f[:2, 2] for K_f in frame_K]) if follows else None)
    window_of = {index: (int(cx), int(cy)) for index, (cx, cy) in zip(kept, corners)}
    partial = out.parent / f".{out.name}.partial"
    shutil.rmtree(partial, ignore_errors=True)
    try:
        written, colours = 0, []
        for (index, image), (_, mask_image) in zip(frames, mask_source):
            if index not in boxes:
                continue
            cx, cy = window_of[index]
            colours.append(_background_colour(image, mask_image))
            seq.write_png(seq.frame_path(partial, info, written), crop_and_resize(image, cx, cy, side_px, size))
            seq.write_png(seq.mask_path(partial, info, written),
                          crop_and_resize(mask_image, cx, cy, side_px, size, mask=True))
            written += 1
        if written != len(kept):
            raise ImportVideoError(f"the {frames.label} gave {written} frames on the second read, {len(kept)} on the "
                                   "first")
        if side == "auto":
            sample = np.unique(np.linspace(0, written - 1, min(written, SIDE_VOTES)).round().astype(int))
            side = _side_of([seq.read_rgb(seq.frame_path(partial, info, i)) for i in sample], side, log)
        info.hand_side = side
        if np.isfinite(colours).all():
            info.background_colour = np.array(colours)
        info.metadata = {
            "generator": "harp import-video", "video": str(video),
            "masks": str(masks) if masks is not None else "made from the footage (MediaPipe + GrabCut)",
            "source_size": [width, height], "source_K": K_source.tolist(), "camera": camera_note,
            "crop": ({"follows_the_hand": True, "x0": corners[:, 0].tolist(), "y0": corners[:, 1].tolist(),
                      "side": side_px, "margin": margin, "clip_window_side": clip_side}
                     if follows else {"x0": x0, "y0": y0, "side": side_px, "margin": margin}) | {"holds": holds},
            "source_frames": kept, "dropped_frames": {"empty_mask": empty, **named},
        }
        seq.write_sequence_info(partial, info)
        write_mask_preview(partial, info, partial / seq.MASK_PREVIEW_FILE)
        if out.exists():
            shutil.rmtree(out)
        partial.rename(out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    scale_note = "" if side_px > size else f", kept at the source's {side_px} px (not enlarged)"
    valid_note = "" if info.valid_region is None else \
        f"; pixels outside {info.valid_region} lie past the video's edge and are marked invalid"
    where = (f"following the hand (one window for the clip would be {info.metadata['crop']['clip_window_side']} px)"
             if follows else f"at ({x0}, {y0})")
    if holds == "hand" and beyond >= 0.25 * side_px:
        where += f"; around the hand: the masks reach up to {beyond:.0f} px further (a forearm), cut by the crop"
    log(f"wrote {written} frames ({size}x{size}, crop {side_px} px {where} of {width}x{height}"
        f"{scale_note}; {camera_note}{valid_note}) to {out}; the masks over sampled frames: "
        f"{out / seq.MASK_PREVIEW_FILE}")
    return info


def _background_colour(image, mask_image):
    """(3,) the source frame's background colour in [0, 1] (background_meter.py), measured at
    up to METER_SIZE pixels: the whole frame is the camera's exposure meter, not the crop, which
    moves over the scene when it follows the hand."""
    import cv2

    from .background_meter import frame_background_colour

    scale = min(1.0, METER_SIZE / max(image.shape[:2]))
    if scale < 1.0:
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        mask_image = cv2.resize(mask_image, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_AREA)
    hand = mask_image >= MASK_THRESHOLD
    margin = max(2, int(round(METER_MARGIN * max(image.shape[:2]))))
    return frame_background_colour(image.astype(np.float64) / 255, hand, margin)


def write_mask_preview(folder, info, path, count=8, tile=224):
    """A PNG of `count` frames sampled over the sequence, each with its mask tinted green and
    outlined, and what lies past the video's edge (invalid) hatched dark."""
    import cv2

    picks = np.unique(np.linspace(0, info.frame_count - 1, min(count, info.frame_count)).round().astype(int))
    valid = seq.validity_mask(info) if info.valid_region is not None else None
    tiles = []
    for index in picks:
        image = seq.read_rgb(seq.frame_path(folder, info, index)).astype(np.float32)
        mask = seq.read_mask(seq.mask_path(folder, info, index))
        image[mask] = 0.6 * image[mask] + 0.4 * np.array([60, 220, 90])
        if valid is not None:
            hatch = (np.add.outer(np.arange(info.height), np.arange(info.width)) // 6) % 2 == 0
            image[~valid & hatch] = 40
        outline = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        image[outline] = (255, 255, 255)
        tiles.append(cv2.resize(image.clip(0, 255).astype(np.uint8), (tile, tile), interpolation=cv2.INTER_AREA))
    while len(tiles) % 4:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.concatenate(tiles[i:i + 4], axis=1) for i in range(0, len(tiles), 4)]
    seq.write_png(path, np.concatenate(rows, axis=0))
