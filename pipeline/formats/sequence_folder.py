"""The sequence folder: one clip of one hand, its masks, camera and (synthetic only) ground truth.

This module is the single home of the format (numpy + json only at import, so `synth/` and
the Blender add-on use it too; reading pixels lazily imports OpenCV). Layout:

    sequence.json        format name + version, fps, width, height, frame_count, hand_side,
                         camera K (OpenCV, pixels) or horizontal_fov_deg, where frames/masks are
    rgb/000000.png ...   8-bit RGB frames (or one video file, "frames": {"kind": "video"})
    mask/000000.png ...  8-bit single-channel masks, 255 = hand (+ arm where visible), 0 = rest
    gt.npz               ground truth (synthetic clips only), see GroundTruth
    gt_albedo.png        ground-truth albedo, 8-bit sRGB, in the hand model's UV layout

Pixels the camera never recorded (where an import's crop reached past the video's edge) are
marked invalid: `valid_region` [x0, y0, x1, y1] in sequence.json is the rectangle of recorded
pixels (pixel edges; absent: every pixel), the same in every frame; validity_mask() gives it
as an image. Invalid pixels hold black and count in no image term or score.

Conventions (DESIGN.md): metres; the camera frame is OpenCV's (x right, y down, z forward) and
is also the world frame of the ground truth (camera at the origin, R = I, t = 0), so posing the
hand model with (betas, pose, global_orient, transl) of a frame gives the hand in camera
coordinates. Pixel coordinates have their origin at the top-left corner of the top-left pixel
(as in pipeline/formats/camera.py), so a pixel centre is at (column + 0.5, row + 0.5). The
albedo image's top row is v = 1 (UV v up).
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from .png_file import png_size, write_png  # noqa: F401  (part of this format's API)
from .pose_arrays import pose_array_problems

FORMAT_NAME = "harp-sequence"
FORMAT_VERSION = 1
SEQUENCE_FILE = "sequence.json"
GT_FILE = "gt.npz"
GT_ALBEDO_FILE = "gt_albedo.png"
MASK_PREVIEW_FILE = "mask_preview.png"   # masks over sampled frames, for a person to check (import-video)
FRAME_PATTERN = "rgb/{index:06d}.png"
MASK_PATTERN = "mask/{index:06d}.png"
GT_FORMAT_VERSION = 1
HAND_SIDES = ("right", "left")
MODEL_MODES = ("hand", "arm")
MIN_MASK_PIXELS = 16   # a mask with fewer hand pixels is empty (hand out of view, or missed)


class SequenceFolderError(ValueError):
    """A sequence folder is missing, incomplete or inconsistent (one-line message)."""


@dataclasses.dataclass
class SequenceInfo:
    """Contents of sequence.json."""

    fps: float
    width: int
    height: int
    frame_count: int
    hand_side: str
    K: np.ndarray                       # (3, 3) OpenCV intrinsics in pixels
    frames: dict = dataclasses.field(default_factory=lambda: {"kind": "images", "pattern": FRAME_PATTERN})
    masks: dict | None = dataclasses.field(default_factory=lambda: {"kind": "images", "pattern": MASK_PATTERN})
    ground_truth: str | None = None     # file name of the ground truth (gt.npz), synthetic clips
    albedo: str | None = None           # file name of the ground-truth albedo (gt_albedo.png)
    metadata: dict = dataclasses.field(default_factory=dict)  # free-form: generator, settings ...
    valid_region: list | None = None    # [x0, y0, x1, y1] recorded pixels (None: all of them)
    # (F, 2) each frame's principal point (pixels) where each frame is cut from the footage around
    # the hand (harp import-video's per-frame crops): frame f's intrinsics are K with (cx, cy)
    # replaced by row f. None: every frame has K's.
    principal_points: np.ndarray | None = None
    # (F, 3) each frame's background colour in [0, 1] as the import measured it on the whole source
    # frame, away from the hand (the fit's exposure meter; None: measured on the frames themselves)
    background_colour: np.ndarray | None = None

    def frame_K(self) -> np.ndarray:
        """(F, 3, 3) the intrinsics of every frame."""
        K = np.repeat(np.asarray(self.K, dtype=np.float64)[None], self.frame_count, axis=0)
        if self.principal_points is not None:
            K[:, :2, 2] = np.asarray(self.principal_points, dtype=np.float64)
        return K

    def to_json(self) -> dict:
        return {
            "format": FORMAT_NAME, "version": FORMAT_VERSION, "fps": float(self.fps),
            "width": int(self.width), "height": int(self.height), "frame_count": int(self.frame_count),
            "hand_side": self.hand_side, "K": np.asarray(self.K, dtype=float).tolist(),
            "frames": self.frames, "masks": self.masks, "ground_truth": self.ground_truth,
            "albedo": self.albedo, "metadata": self.metadata,
            **({"valid_region": [int(v) for v in self.valid_region]} if self.valid_region is not None else {}),
            **({"principal_points": np.asarray(self.principal_points, dtype=float).tolist()}
               if self.principal_points is not None else {}),
            **({"background_colour": np.asarray(self.background_colour, dtype=float).round(6).tolist()}
               if self.background_colour is not None else {}),
        }

    def validate(self) -> None:
        problems = []
        if not self.fps > 0:
            problems.append(f"fps must be positive, got {self.fps}")
        if self.width <= 0 or self.height <= 0:
            problems.append(f"image size must be positive, got {self.width}x{self.height}")
        if self.frame_count <= 0:
            problems.append(f"frame_count must be positive, got {self.frame_count}")
        if self.hand_side not in HAND_SIDES:
            problems.append(f"hand_side {self.hand_side!r} is not one of {HAND_SIDES}")
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            problems.append("K must be a 3x3 matrix with positive focal lengths")
        for name, entry in (("frames", self.frames), ("masks", self.masks)):
            if entry is None and name == "masks":
                continue
            kind = entry.get("kind") if isinstance(entry, dict) else None
            if kind == "images" and "{index" not in str(entry.get("pattern", "")):
                problems.append(f"{name}.pattern must contain '{{index...}}'")
            elif kind == "video" and not entry.get("path"):
                problems.append(f"{name}.path is missing")
            elif kind not in ("images", "video"):
                problems.append(f"{name}.kind must be 'images' or 'video'")
        for name, value, columns in (("principal_points", self.principal_points, "(cx, cy)"),
                                     ("background_colour", self.background_colour, "(r, g, b)")):
            if value is not None and not _finite_per_frame(value, self.frame_count, columns.count(",") + 1):
                problems.append(f"{name} must hold one finite {columns} per frame ({self.frame_count})")
        if self.valid_region is not None:
            x0, y0, x1, y1 = self.valid_region
            if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
                problems.append(f"valid_region {list(self.valid_region)} must lie inside the "
                                f"{self.width}x{self.height} image and hold pixels")
        if problems:
            raise SequenceFolderError("invalid sequence.json: " + "; ".join(problems))


def _finite_per_frame(value, frame_count, columns) -> bool:
    """Whether `value` reads as a finite (frame_count, columns) array."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return array.shape == (frame_count, columns) and bool(np.isfinite(array).all())


def validity_mask(info: SequenceInfo) -> np.ndarray:
    """(H, W) bool: the pixels the camera recorded (info.valid_region; all when absent)."""
    valid = np.zeros((info.height, info.width), bool)
    x0, y0, x1, y1 = info.valid_region if info.valid_region is not None else (0, 0, info.width, info.height)
    valid[y0:y1, x0:x1] = True
    return valid


def intrinsics_from_json(entry: dict) -> np.ndarray:
    """K from a sequence.json dict: "K", or "horizontal_fov_deg" (centred pinhole)."""
    if entry.get("K") is not None:
        return np.asarray(entry["K"], dtype=np.float64)
    if entry.get("horizontal_fov_deg") is not None:
        fx = 0.5 * entry["width"] / np.tan(0.5 * np.radians(float(entry["horizontal_fov_deg"])))
        return np.array([[fx, 0, entry["width"] / 2], [0, fx, entry["height"] / 2], [0, 0, 1.0]])
    raise SequenceFolderError("sequence.json gives neither K nor horizontal_fov_deg")


def write_sequence_info(folder, info: SequenceInfo) -> Path:
    """Validate `info` and write folder/sequence.json."""
    info.validate()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / SEQUENCE_FILE
    path.write_text(json.dumps(info.to_json(), indent=2) + "\n")
    return path


def read_sequence_info(folder) -> SequenceInfo:
    """Read and validate folder/sequence.json (format name and version included)."""
    path = Path(folder) / SEQUENCE_FILE
    if not path.is_file():
        raise SequenceFolderError(f"no {SEQUENCE_FILE} in {folder}")
    try:
        entry = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise SequenceFolderError(f"cannot read {path}: {error}") from None
    if not isinstance(entry, dict) or entry.get("format") != FORMAT_NAME:
        raise SequenceFolderError(f"{path} is not a {FORMAT_NAME} file")
    if entry.get("version") != FORMAT_VERSION:
        raise SequenceFolderError(f"{path} has format version {entry.get('version')}, "
                                  f"this program reads version {FORMAT_VERSION}")
    missing = [key for key in ("fps", "width", "height", "frame_count", "hand_side", "frames") if key not in entry]
    if missing:
        raise SequenceFolderError(f"{path} lacks {', '.join(missing)}")
    info = SequenceInfo(
        fps=float(entry["fps"]), width=int(entry["width"]), height=int(entry["height"]),
        frame_count=int(entry["frame_count"]), hand_side=entry["hand_side"], K=intrinsics_from_json(entry),
        frames=entry["frames"], masks=entry.get("masks"), ground_truth=entry.get("ground_truth"),
        albedo=entry.get("albedo"), metadata=entry.get("metadata", {}), valid_region=entry.get("valid_region"),
        principal_points=entry.get("principal_points"), background_colour=entry.get("background_colour"))
    info.validate()
    return info


def frame_path(folder, info: SequenceInfo, index: int) -> Path:
    """Path of RGB frame `index` (image sequences only)."""
    return _indexed_path(folder, info.frames, index, "frames")


def mask_path(folder, info: SequenceInfo, index: int) -> Path:
    """Path of mask `index`."""
    if info.masks is None:
        raise SequenceFolderError(f"the sequence in {folder} has no masks")
    return _indexed_path(folder, info.masks, index, "masks")


def _indexed_path(folder, entry, index, name):
    if entry["kind"] != "images":
        raise SequenceFolderError(f"{name} of the sequence in {folder} are a video, not images")
    return Path(folder) / entry["pattern"].format(index=index)


@dataclasses.dataclass
class GroundTruth:
    """gt.npz: exact parameters of a synthetic clip. F frames, V model vertices, S betas.

    Posing HandModel.load(mode, side)(betas, pose, global_orient, transl) reproduces the hand
    in the camera frame (metres) before the personal displacements; `vertices` are the rendered
    surface (with them); `personal_offsets` are those displacements in rest model space."""

    mode: str                       # "hand" or "arm"
    side: str                       # "right" or "left" (poses are in that side's model frames)
    betas: np.ndarray               # (S,)
    global_orient: np.ndarray       # (F, 3) axis-angle, model -> camera frame, about the wrist
    transl: np.ndarray              # (F, 3) wrist position in the camera frame, metres
    pose: np.ndarray                # (F, 16, 3) local axis-angle per joint, radians
    keypoints3d: np.ndarray         # (F, 21, 3) camera frame, metres (MediaPipe order)
    keypoints2d: np.ndarray         # (F, 21, 2) pixels, projection of keypoints3d with K
    vertices: np.ndarray | None = None          # (F, V, 3) rendered surface, camera frame, metres
    personal_offsets: np.ndarray | None = None  # (V, 3) rest-space personal displacements, metres
    light: dict = dataclasses.field(default_factory=dict)  # preset, lights (camera frame), ambient

    @property
    def frame_count(self) -> int:
        return int(self.pose.shape[0])

    def validate(self) -> None:
        F = self.pose.shape[0] if self.pose.ndim == 3 else -1
        problems = []
        if self.mode not in MODEL_MODES:
            problems.append(f"mode {self.mode!r} is not one of {MODEL_MODES}")
        if self.side not in HAND_SIDES:
            problems.append(f"side {self.side!r} is not one of {HAND_SIDES}")
        problems += pose_array_problems(self, {"keypoints2d": (21, 2)}, finite=("keypoints2d",))
        if self.vertices is not None and (self.vertices.ndim != 3 or self.vertices.shape[0] != F
                                          or self.vertices.shape[2] != 3):
            problems.append(f"vertices has shape {self.vertices.shape}, expected ({F}, V, 3)")
        if self.personal_offsets is not None and self.personal_offsets.ndim != 2:
            problems.append(f"personal_offsets has shape {self.personal_offsets.shape}, expected (V, 3)")
        if problems:
            raise SequenceFolderError("invalid ground truth: " + "; ".join(problems))


_GT_ARRAYS = ("betas", "global_orient", "transl", "pose", "keypoints3d", "keypoints2d")
_GT_OPTIONAL = ("vertices", "personal_offsets")


def write_ground_truth(path, gt: GroundTruth) -> Path:
    """Validate and write gt.npz (float32 for vertices, float64 for parameters)."""
    gt.validate()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {name: np.asarray(getattr(gt, name), dtype=np.float64) for name in _GT_ARRAYS}
    for name in _GT_OPTIONAL:
        if getattr(gt, name) is not None:
            arrays[name] = np.asarray(getattr(gt, name), dtype=np.float32)
    with open(path, "wb") as handle:
        np.savez_compressed(handle, format_version=np.array(GT_FORMAT_VERSION), mode=np.array(gt.mode),
                            side=np.array(gt.side), light=np.array(json.dumps(gt.light, sort_keys=True)),
                            **arrays)
    return path


def read_ground_truth(path) -> GroundTruth:
    """Read and validate gt.npz."""
    path = Path(path)
    if not path.is_file():
        raise SequenceFolderError(f"ground truth file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as archive:
            version = int(archive["format_version"])
            if version != GT_FORMAT_VERSION:
                raise SequenceFolderError(f"{path} has ground-truth version {version}, "
                                          f"this program reads version {GT_FORMAT_VERSION}")
            gt = GroundTruth(mode=str(archive["mode"]), side=str(archive["side"]),
                             light=json.loads(str(archive["light"])),
                             **{name: archive[name] for name in _GT_ARRAYS},
                             **{name: archive[name] if name in archive.files else None for name in _GT_OPTIONAL})
    except SequenceFolderError:
        raise
    except Exception as error:  # corrupt zip, missing member ...
        raise SequenceFolderError(f"cannot read ground truth {path}: {error}") from None
    gt.validate()
    return gt


def validate_sequence_folder(folder) -> SequenceInfo:
    """Check that a sequence folder is complete and consistent; returns its SequenceInfo.

    Checks sequence.json, that every frame and mask exists with the stated size, and that the
    ground truth (if named) matches the frame count. Raises SequenceFolderError (one line)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SequenceFolderError(f"sequence folder not found: {folder}")
    info = read_sequence_info(folder)
    kinds = [("frame", info.frames)] + ([("mask", info.masks)] if info.masks is not None else [])
    for label, entry in kinds:
        if entry["kind"] == "video":
            if not (folder / entry["path"]).is_file():
                raise SequenceFolderError(f"{label} video not found: {folder / entry['path']}")
            continue
        for index in range(info.frame_count):
            path = folder / entry["pattern"].format(index=index)
            if not path.is_file():
                raise SequenceFolderError(f"{label} {index} of {info.frame_count} is missing: {path}")
            if path.suffix.lower() == ".png" and png_size(path) != (info.width, info.height):
                raise SequenceFolderError(f"{path} is {png_size(path)[0]}x{png_size(path)[1]}, "
                                          f"sequence.json says {info.width}x{info.height}")
        extra = folder / entry["pattern"].format(index=info.frame_count)
        if extra.is_file():
            raise SequenceFolderError(f"more {label}s than frame_count = {info.frame_count}: {extra} exists")
    if info.ground_truth:
        gt = read_ground_truth(folder / info.ground_truth)
        if gt.frame_count != info.frame_count:
            raise SequenceFolderError(f"ground truth has {gt.frame_count} frames, sequence.json says {info.frame_count}")
        if gt.side != info.hand_side:
            raise SequenceFolderError(f"ground truth is a {gt.side} hand, sequence.json says {info.hand_side}")
    if info.albedo and not (folder / info.albedo).is_file():
        raise SequenceFolderError(f"ground-truth albedo not found: {folder / info.albedo}")
    return info


def read_rgb(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB image (needs OpenCV)."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SequenceFolderError(f"cannot read image {path}")
    return image[..., ::-1].copy()


def check_mask(mask, index) -> None:
    """Raise SequenceFolderError (one line) unless the (H, W) bool mask of frame `index` shows a
    hand: an empty mask (fewer than MIN_MASK_PIXELS hand pixels) or one that is hand everywhere
    (inverted?) cannot guide a fit."""
    pixels = int(mask.sum())
    if pixels < MIN_MASK_PIXELS:
        raise SequenceFolderError(f"mask {index} is empty (fewer than {MIN_MASK_PIXELS} hand pixels): leave the "
                                  "frame out of the sequence (harp import-video does) or mend the mask")
    if pixels == mask.size:
        raise SequenceFolderError(f"mask {index} is all foreground (every pixel is hand); masks must be white "
                                  "(>= 128) on the hand and black elsewhere - inverted?")


def read_mask(path) -> np.ndarray:
    """(H, W) bool mask: True where the stored value is >= 128 (needs OpenCV)."""
    import cv2

    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise SequenceFolderError(f"cannot read mask {path}")
    return mask >= 128


def frame_ranges(indices):
    """"1-3, 7" for [1, 2, 3, 7]."""
    parts, start = [], None
    for i, value in enumerate(indices):
        if start is None:
            start = value
        if i + 1 == len(indices) or indices[i + 1] != value + 1:
            parts.append(str(start) if start == value else f"{start}-{value}")
            start = None
    return ", ".join(parts)
