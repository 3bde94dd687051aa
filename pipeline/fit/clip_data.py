"""A sequence folder loaded for fitting: frames, masks and intrinsics at the working resolution."""
from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np
import scipy.sparse
import scipy.sparse.linalg
import torch

from ..background_meter import frame_background_colour
from ..formats import sequence_folder as seq


LUMINANCE = np.array([0.2126, 0.7152, 0.0722])   # Rec. 709 weights of linear-ish RGB
# a frame's value at or above this (8-bit 254 of 255) was clipped by the camera: it says only "at least this"
SATURATED = 254 / 255


def saturated(images):
    """Bool of the same shape as `images` (values in [0, 1]): the channels the camera clipped at white."""
    return images >= SATURATED


@dataclasses.dataclass
class ClipData:
    images: torch.Tensor      # (F, H, W, 3) in [0, 1]
    masks: torch.Tensor       # (F, H, W, 1) in {0, 1}
    K: torch.Tensor           # (F, 3, 3) each frame's intrinsics at the working resolution
    info: seq.SequenceInfo
    frames: np.ndarray        # (F,) indices into the sequence
    valid: torch.Tensor | None = None   # (H, W, 1) pixels the camera recorded (None: all)

    @property
    def height(self):
        return self.images.shape[1]

    @property
    def width(self):
        return self.images.shape[2]

    @functools.cached_property
    def backgrounds(self):
        """(F, H, W, 3) background plates (background_plates): what renders are composited over
        when they are compared with the frames."""
        return background_plates(self.images, self.masks)

    @functools.cached_property
    def background_colour(self):
        """(F, 3) colour of each frame's background (recorded pixels away from the hand; as the
        import measured it on the whole source frame where it did): it changes over a clip when
        the camera's exposure or white balance does."""
        if self.info.background_colour is not None:
            return np.asarray(self.info.background_colour, dtype=np.float64)[self.frames]
        return background_colour(self.images, self.masks, self.valid)

    @property
    def background_brightness(self):
        """(F,) luminance of background_colour."""
        return self.background_colour @ LUMINANCE


def load_clip(folder, resolution=None, frames=None, device=None, dtype=torch.float32):
    """Frames and masks of a sequence folder, shrunk so the long side is at most `resolution`
    (never enlarged: a small source is fitted at its own scale), with its validity mask; an
    empty or all-foreground mask stops with one SequenceFolderError line."""
    info = seq.validate_sequence_folder(folder)
    frames = np.arange(info.frame_count) if frames is None else np.asarray(frames)
    scale = 1.0 if resolution is None else min(1.0, resolution / max(info.width, info.height))
    size = (int(round(info.width * scale)), int(round(info.height * scale)))
    images, masks = [], []
    for index in frames:
        rgb = seq.read_rgb(seq.frame_path(folder, info, int(index)))
        hand = seq.read_mask(seq.mask_path(folder, info, int(index)))
        seq.check_mask(hand, int(index))
        if scale != 1.0:
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        images.append(rgb.astype(np.float32) / 255)
        masks.append(mask_at_size(hand, size))
    K = info.frame_K()[frames]
    K[:, :2] *= np.array([[size[0] / info.width], [size[1] / info.height]])
    valid = None
    if info.valid_region is not None:   # a pixel counts only if it is wholly recorded
        recorded = cv2.resize(seq.validity_mask(info).astype(np.float32), size, interpolation=cv2.INTER_AREA)
        valid = torch.as_tensor((recorded > 0.999)[..., None], dtype=dtype, device=device)
    return ClipData(torch.as_tensor(np.stack(images), dtype=dtype, device=device),
                    torch.as_tensor(np.stack(masks)[..., None], dtype=dtype, device=device),
                    torch.as_tensor(K, dtype=dtype, device=device), info, frames, valid)


def mask_at_size(hand, size) -> np.ndarray:
    """(H', W') float32 0/1: the (H, W) bool mask `hand` at `size` (width, height) as the clip
    holds its masks (area-averaged, then at least half hand)."""
    mask = hand.astype(np.float32)
    if (mask.shape[1], mask.shape[0]) != tuple(size):
        mask = cv2.resize(mask, tuple(size), interpolation=cv2.INTER_AREA)
    return (mask >= 0.5).astype(np.float32)


def background_colour(images, masks, valid=None, margin=8):
    """(F, 3) colour of each frame's pixels farther than `margin` px from the hand (and recorded;
    NaN where there are none; background_meter.py); images (F, H, W, 3), masks (F, H, W, 1)."""
    recorded = None if valid is None else valid.cpu().numpy()[..., 0] > 0.5
    return np.array([frame_background_colour(image, mask[..., 0] > 0.5, margin, recorded)
                     for image, mask in zip(images.cpu().numpy(), masks.cpu().numpy())], dtype=np.float64)


def background_plates(images, masks, margin=2):
    """Each frame with the hand filled in from its surroundings: an estimate of what the camera
    saw behind the hand. Rendered over it, an antialiased silhouette edge blends into the same
    colours as in the photograph, and a hand pixel the render misses shows background there.
    The mask is grown by `margin` px so the blended ring just outside it is filled too.
    images (F, H, W, 3) in [0, 1], masks (F, H, W, 1) in {0, 1}; returns a tensor like images."""
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    plates = []
    for image, mask in zip(images.cpu().numpy().astype(np.float64), masks.cpu().numpy()):
        hole = cv2.dilate((mask[..., 0] > 0.5).astype(np.uint8), kernel).astype(bool)
        plates.append(harmonic_fill(image, hole))
    return torch.as_tensor(np.stack(plates), dtype=images.dtype, device=images.device)


def harmonic_fill(image, hole):
    """image (H, W, C) with the pixels of `hole` (H, W) bool replaced by the solution of
    Laplace's equation whose boundary values are the known pixels around them: the smoothest
    fill, exact for flat and linearly shaded backgrounds. Sides of the hole on the image's
    border are free (zero normal derivative). A frame with no known pixel is filled grey."""
    if not hole.any():
        return image.copy()
    if hole.all():
        return np.full_like(image, 0.5)
    height, width = hole.shape
    ys, xs = np.nonzero(hole)
    count = len(ys)
    index = np.full(hole.shape, -1, np.int64)
    index[ys, xs] = np.arange(count)
    neighbours = np.zeros(count)
    rows, cols = [], []
    rhs = np.zeros((count, image.shape[-1]))
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ny, nx = ys + dy, xs + dx
        k = np.nonzero((ny >= 0) & (ny < height) & (nx >= 0) & (nx < width))[0]
        neighbours[k] += 1
        unknown = hole[ny[k], nx[k]]
        rows.append(k[unknown])
        cols.append(index[ny[k[unknown]], nx[k[unknown]]])
        known = k[~unknown]
        rhs[known] += image[ny[known], nx[known]]
    rows, cols = np.concatenate([np.arange(count), *rows]), np.concatenate([np.arange(count), *cols])
    values = np.concatenate([neighbours, -np.ones(len(rows) - count)])
    laplacian = scipy.sparse.csc_matrix((values, (rows, cols)), shape=(count, count))
    filled = image.copy()
    # the matrix is symmetric positive definite: SuperLU's symmetric mode (an ordering of A + A^T, pivots on the
    # diagonal) takes a fifth off the fill (68 -> 54 ms a frame for a hand of 17,000 px; the same fill to 1e-13)
    factors = scipy.sparse.linalg.splu(laplacian, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                       options={"SymmetricMode": True})
    filled[ys, xs] = factors.solve(rhs)
    return filled
