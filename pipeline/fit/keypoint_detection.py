"""2D hand keypoints per frame: MediaPipe Hands (offline) or a keypoint file.

Keypoints are 21 points in MediaPipe order (0 wrist, 1-4 thumb, 5-8 index, 9-12 middle,
13-16 ring, 17-20 pinky) in pixels of the sequence's frames, with the origin at the top-left
corner of the image (a pixel centre is at column + 0.5; pipeline/formats/camera.py).

MediaPipe Hands (`mediapipe==0.10.21`, `mediapipe.solutions.hands`) runs on the CPU with the
models inside the wheel; nothing is downloaded. Each frame is detected on its own (static image
mode), on the frame padded by half its size on every side with replicated edges: a hand that
fills the image (as our crops do) is found more often that way (measured in
docs/initialisation.md). Frames without a detection are linearly interpolated in time (held
constant before the first and after the last detection) and flagged `detected = False`.

Handedness: MediaPipe's label assumes a mirrored (selfie) image, so on an ordinary, unmirrored
image a right hand is labelled "Left" (measured on synthetic clips: a right hand gets "Left" in
22 of 23 detected frames, a left hand "Right" in 23 of 24).
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from ..quiet_stderr import native_stderr_silenced

KEYPOINT_COUNT = 21
MEDIAPIPE_LABEL = {"right": "Left", "left": "Right"}   # MediaPipe's label for an unmirrored image
PAD_FRACTION = 0.5          # padding around each frame before detection, fraction of its size
MIN_DETECTION_CONFIDENCE = 0.3
KEYPOINT_FILE_FORMAT = "harp-keypoints"


class KeypointError(ValueError):
    """Keypoints could not be detected or read (one-line message)."""


@dataclasses.dataclass
class Keypoints2D:
    """Per-frame 2D keypoints of one hand in a clip of F frames."""

    points: np.ndarray                  # (F, 21, 2) pixels, corner origin; interpolated where not detected
    detected: np.ndarray                # (F,) bool: the frame had its own detection
    score: np.ndarray                   # (F,) confidence in [0, 1] (0 where not detected)
    world: np.ndarray | None = None     # (F, 21, 3) MediaPipe's metric world landmarks, metres
    handedness_ok: np.ndarray | None = None  # (F,) bool: the detector's label matched the side
    source: str = "mediapipe"

    @property
    def frame_count(self) -> int:
        return int(self.points.shape[0])

    def summary(self) -> dict:
        """Detection rate and handedness agreement, for logs and init.npz metadata."""
        entry = {"source": self.source, "frames": self.frame_count,
                 "detected": int(self.detected.sum()), "detection_rate": float(self.detected.mean())}
        if self.handedness_ok is not None and self.detected.any():
            entry["handedness_agreement"] = float(self.handedness_ok[self.detected].mean())
        return entry


def interpolate_missing(values, detected):
    """Linear interpolation over time of (F, ...) values at frames where `detected` is False;
    held constant before the first and after the last detected frame."""
    values = np.array(values, dtype=np.float64)
    known = np.flatnonzero(detected)
    if len(known) == 0:
        raise KeypointError("no frame has keypoints to interpolate from")
    flat = values.reshape(len(values), -1)
    frames = np.arange(len(values))
    for column in range(flat.shape[1]):
        flat[:, column] = np.interp(frames, known, flat[known, column])
    return flat.reshape(values.shape)


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


def detect_keypoints(frames, side, detector=None):
    """Keypoints2D from an iterable of (H, W, 3) uint8 RGB frames of one `side` ("right"/"left").

    Where MediaPipe finds two hands, the one labelled as `side` (see MEDIAPIPE_LABEL) is taken,
    otherwise the most confident. Raises KeypointError when no frame has a detection."""
    own = detector is None
    detector = detector or MediaPipeHands()
    points, world, detected, score, handedness_ok = [], [], [], [], []
    try:
        for rgb in frames:
            hands = detector.detect(rgb)
            if not hands:
                points.append(np.zeros((KEYPOINT_COUNT, 2)))
                world.append(np.zeros((KEYPOINT_COUNT, 3)))
                detected.append(False)
                score.append(0.0)
                handedness_ok.append(False)
                continue
            hands.sort(key=lambda hand: (hand[2] == MEDIAPIPE_LABEL[side], hand[3]), reverse=True)
            best = hands[0]
            points.append(best[0])
            world.append(best[1])
            detected.append(True)
            score.append(best[3])
            handedness_ok.append(best[2] == MEDIAPIPE_LABEL[side])
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
                       handedness_ok=np.array(handedness_ok, dtype=bool), source="mediapipe")


def detect_sequence_keypoints(folder, info=None, detector=None):
    """Keypoints2D of the frames of a sequence folder (image frames)."""
    from ..formats import sequence_folder as seq

    info = info or seq.read_sequence_info(folder)
    frames = (seq.read_rgb(seq.frame_path(folder, info, index)) for index in range(info.frame_count))
    return detect_keypoints(frames, info.hand_side, detector)


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


# --- keypoint files -------------------------------------------------------------------------
def read_keypoint_file(path, frame_count, width, height):
    """Keypoints2D from a keypoint file of F = frame_count frames (docs/initialisation.md):

    - `.npy`: array (F, 21, 2) pixels, or (F, 21, 3) with a per-keypoint confidence last;
    - `.npz`: `keypoints` (F, 21, 2) pixels, optional `score` (F,);
    - `.json`: {"format": "harp-keypoints", "version": 1, "keypoints": F lists of 21 [x, y]
      (or null for a frame without keypoints), optional "score": F numbers}, or the bare list.
    A frame whose keypoints are all NaN (or null) has none and is interpolated."""
    path = Path(path)
    if not path.is_file():
        raise KeypointError(f"keypoint file not found: {path}")
    score = None
    try:
        if path.suffix.lower() == ".npy":
            array = np.load(path, allow_pickle=False)
        elif path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                if "keypoints" not in archive.files:
                    raise KeypointError(f"{path} has no array named 'keypoints' (has {', '.join(archive.files)})")
                array = archive["keypoints"]
                score = archive["score"] if "score" in archive.files else None
        elif path.suffix.lower() == ".json":
            entry = json.loads(path.read_text())
            if isinstance(entry, dict):
                if entry.get("format", KEYPOINT_FILE_FORMAT) != KEYPOINT_FILE_FORMAT or "keypoints" not in entry:
                    raise KeypointError(f"{path} is not a {KEYPOINT_FILE_FORMAT} file (needs a 'keypoints' list)")
                score = entry.get("score")
                entry = entry["keypoints"]
            nan_frame = [[np.nan, np.nan]] * KEYPOINT_COUNT
            array = np.array([nan_frame if frame is None else frame for frame in entry], dtype=np.float64)
        else:
            raise KeypointError(f"keypoint file {path} must be .npy, .npz or .json")
    except KeypointError:
        raise
    except Exception as error:  # unreadable, ragged lists, non-numbers ...
        raise KeypointError(f"cannot read keypoint file {path}: {error}") from None
    array = np.asarray(array, dtype=np.float64)
    if array.ndim != 3 or array.shape[1] != KEYPOINT_COUNT or array.shape[2] not in (2, 3):
        raise KeypointError(f"keypoints in {path} have shape {array.shape}, expected ({frame_count}, 21, 2)")
    if array.shape[0] != frame_count:
        raise KeypointError(f"{path} has keypoints for {array.shape[0]} frames, the sequence has {frame_count}")
    if array.shape[2] == 3:
        score = np.nan_to_num(array[..., 2]).mean(axis=1) if score is None else score
        array = array[..., :2]
    detected = np.isfinite(array).all(axis=(1, 2))
    if not detected.any():
        raise KeypointError(f"{path} has no frame with 21 finite keypoints")
    known = array[detected]
    if known.min() >= -1e-9 and known.max() <= 1 + 1e-9 and max(width, height) > 2:
        raise KeypointError(f"keypoints in {path} all lie in [0, 1]: they look normalised; "
                            f"give pixels (multiply x by {width} and y by {height})")
    centres = known.mean(axis=1)
    outside = (centres[:, 0] < 0) | (centres[:, 0] > width) | (centres[:, 1] < 0) | (centres[:, 1] > height)
    if outside.all():
        raise KeypointError(f"keypoints in {path} lie outside the {width}x{height} image in every frame")
    score = np.where(detected, 1.0, 0.0) if score is None else np.asarray(score, dtype=np.float64).reshape(-1)
    if score.shape != (frame_count,):
        raise KeypointError(f"score in {path} has {score.size} values, expected {frame_count}")
    return Keypoints2D(points=interpolate_missing(np.where(np.isfinite(array), array, 0.0), detected),
                       detected=detected, score=np.where(detected, score, 0.0), source="keypoints")


def write_keypoint_file(path, keypoints: Keypoints2D) -> Path:
    """Write Keypoints2D as a .json keypoint file (frames without detection as null)."""
    frames = [points.round(3).tolist() if found else None
              for points, found in zip(keypoints.points, keypoints.detected)]
    path = Path(path)
    path.write_text(json.dumps({"format": KEYPOINT_FILE_FORMAT, "version": 1, "keypoints": frames,
                                "score": np.round(keypoints.score, 4).tolist()}) + "\n")
    return path
