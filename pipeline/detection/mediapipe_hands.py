"""MediaPipe Hands (offline): 2D hand keypoints per frame and the hand side of a clip; the
detection layer under `harp import-video` and `harp init`.

MediaPipe Hands (`mediapipe==0.10.21`, `mediapipe.solutions.hands`) runs on the CPU with the
models inside the wheel; nothing is downloaded. Each frame is detected on its own (static image
mode), on the frame padded by half its size on every side with replicated edges: a hand that
fills the image (as our crops do) is found more often that way (measured in
docs/initialisation.md). Frames without a detection are interpolated (formats/keypoint_file.py).

Handedness: MediaPipe's label assumes a mirrored (selfie) image, so on an ordinary, unmirrored
image a right hand is labelled "Left" (measured on synthetic clips: a right hand gets "Left" in
22 of 23 detected frames, a left hand "Right" in 23 of 24).
"""
from __future__ import annotations

import contextlib
import dataclasses
import os

import numpy as np

from ..formats.keypoint_file import KEYPOINT_COUNT, KeypointError, Keypoints2D, interpolate_missing
from ..quiet_stderr import native_stderr_silenced

MEDIAPIPE_LABEL = {"right": "Left", "left": "Right"}   # MediaPipe's label for an unmirrored image
PAD_FRACTION = 0.5          # padding around each frame before detection, fraction of its size
MIN_DETECTION_CONFIDENCE = 0.3
# a sequence's frames are shrunk to this long side before `harp init` detects them: the size the import wrote
# until it kept the hand's window at up to 1024 px, at which the landmark offsets were calibrated and the
# initialisation measured (docs/initialisation.md); MediaPipe's landmark model reads the hand at 224 px whatever
# the frame's size, but its result moved with it (the phone-like clip's 873 px frames: a hand 1.6% smaller than
# from the same frames at 448, and one frame's detection elsewhere)
SEQUENCE_DETECTION_SIZE = 448


@contextlib.contextmanager
def _quiet_native_logs():
    """Silence MediaPipe's C++ log lines on stderr (file descriptor 2) for a block."""
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    with native_stderr_silenced():
        yield


class MediaPipeHands:
    """MediaPipe Hands in static-image mode; `detect(rgb)` returns all hands in one frame."""

    def __init__(self, min_confidence=MIN_DETECTION_CONFIDENCE, max_hands=2):
        with _quiet_native_logs():
            try:
                from mediapipe.python.solutions import hands  # = mediapipe.solutions.hands
            except ImportError as error:
                raise KeypointError(f"MediaPipe is not installed ({error}); "
                                    "pip install mediapipe==0.10.21 or use --init keypoints FILE") from None
            self._hands = hands.Hands(static_image_mode=True, max_num_hands=max_hands, model_complexity=1,
                                      min_detection_confidence=min_confidence)
            self._hands.process(np.zeros((64, 64, 3), np.uint8))  # warm up: its log lines go here

    def close(self):
        self._hands.close()

    def detect(self, rgb):
        """(H, W, 3) uint8 RGB -> list of (points (21, 2) px, world (21, 3) m, label, score)."""
        import cv2

        height, width = rgb.shape[:2]
        pad = int(round(PAD_FRACTION * max(width, height)))
        padded = cv2.copyMakeBorder(np.ascontiguousarray(rgb), pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        with _quiet_native_logs():
            result = self._hands.process(padded)
        if not result.multi_hand_landmarks:
            return []
        hands = []
        for landmarks, world, handedness in zip(result.multi_hand_landmarks, result.multi_hand_world_landmarks,
                                                result.multi_handedness):
            # normalised coordinates: 0 and 1 are the padded image's outer edges (corner origin)
            points = np.array([[p.x * padded.shape[1] - pad, p.y * padded.shape[0] - pad]
                               for p in landmarks.landmark])
            metric = np.array([[p.x, p.y, p.z] for p in world.landmark])
            label = handedness.classification[0]
            hands.append((points, metric, label.label, float(label.score)))
        return hands


def detect_keypoints(frames, side, detector=None, on_frame=None):
    """Keypoints2D from an iterable of (H, W, 3) uint8 RGB frames of one `side` ("right"/"left");
    `on_frame()` is called after each frame (progress).

    Where MediaPipe finds two hands, the one labelled as `side` (see MEDIAPIPE_LABEL) is taken,
    otherwise the most confident; the other's landmarks are kept in `other_hand`. Raises
    KeypointError when no frame has a detection."""
    own = detector is None
    detector = detector or MediaPipeHands()
    points, world, detected, score, handedness_ok, other = [], [], [], [], [], []
    try:
        for rgb in frames:
            hands = detector.detect(rgb)
            if on_frame is not None:
                on_frame()
            if not hands:
                points.append(np.zeros((KEYPOINT_COUNT, 2)))
                world.append(np.zeros((KEYPOINT_COUNT, 3)))
                detected.append(False)
                score.append(0.0)
                handedness_ok.append(False)
                other.append(np.full((KEYPOINT_COUNT, 2), np.nan))
                continue
            hands.sort(key=lambda hand: (hand[2] == MEDIAPIPE_LABEL[side], hand[3]), reverse=True)
            best = hands[0]
            points.append(best[0])
            world.append(best[1])
            detected.append(True)
            score.append(best[3])
            handedness_ok.append(best[2] == MEDIAPIPE_LABEL[side])
            other.append(hands[1][0] if len(hands) > 1 else np.full((KEYPOINT_COUNT, 2), np.nan))
    finally:
        if own:
            detector.close()
    detected = np.array(detected, dtype=bool)
    if len(detected) == 0:
        raise KeypointError("no frames to detect keypoints in")
    if not detected.any():
        raise KeypointError(f"MediaPipe found no hand in any of the {len(detected)} frames; "
                            "check the frames, or give keypoints with --init keypoints FILE")
    return Keypoints2D(points=interpolate_missing(np.array(points), detected), detected=detected,
                       score=np.array(score), world=interpolate_missing(np.array(world), detected),
                       handedness_ok=np.array(handedness_ok, dtype=bool), other_hand=np.array(other),
                       source="mediapipe")


def detect_sequence_keypoints(folder, info=None, detector=None, on_frame=None, size=SEQUENCE_DETECTION_SIZE):
    """Keypoints2D of the frames of a sequence folder (image frames), detected on the frames shrunk
    to `size` pixels on their long side where they are larger, in the frames' own pixels."""
    import cv2

    from ..formats import sequence_folder as seq

    info = info or seq.read_sequence_info(folder)
    scale = min(1.0, size / max(info.width, info.height))
    shrunk = (max(1, int(round(info.width * scale))), max(1, int(round(info.height * scale))))

    def frames():
        for index in range(info.frame_count):
            rgb = seq.read_rgb(seq.frame_path(folder, info, index))
            yield rgb if scale == 1.0 else cv2.resize(rgb, shrunk, interpolation=cv2.INTER_AREA)

    keypoints = detect_keypoints(frames(), info.hand_side, detector, on_frame)
    if scale == 1.0:
        return keypoints
    to_frame = np.array([info.width / shrunk[0], info.height / shrunk[1]])   # corner origin: a plain scale
    return dataclasses.replace(keypoints, points=keypoints.points * to_frame,
                               other_hand=None if keypoints.other_hand is None else keypoints.other_hand * to_frame)


def guess_hand_side(frames, detector=None):
    """("right" | "left", votes) from MediaPipe's handedness on the given frames (majority of the
    labels of the most confident hand per frame). Raises KeypointError without any detection."""
    own = detector is None
    detector = detector or MediaPipeHands(max_hands=1)
    votes = {"right": 0, "left": 0}
    try:
        for rgb in frames:
            hands = detector.detect(rgb)
            if hands:
                label = max(hands, key=lambda hand: hand[3])[2]
                votes["right" if label == MEDIAPIPE_LABEL["right"] else "left"] += 1
    finally:
        if own:
            detector.close()
    if votes["right"] + votes["left"] == 0:
        raise KeypointError("cannot tell the hand side: MediaPipe found no hand; pass --side right or --side left")
    return ("right" if votes["right"] >= votes["left"] else "left"), votes
