"""A sequence folder loaded for fitting: frames, masks and intrinsics at the working resolution."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import torch

from ..formats import sequence_folder as seq


@dataclasses.dataclass
class ClipData:
    images: torch.Tensor      # (F, H, W, 3) in [0, 1]
    masks: torch.Tensor       # (F, H, W, 1) in {0, 1}
    K: torch.Tensor           # (3, 3) intrinsics at the working resolution
    info: seq.SequenceInfo
    frames: np.ndarray        # (F,) indices into the sequence

    @property
    def height(self):
        return self.images.shape[1]

    @property
    def width(self):
        return self.images.shape[2]


def load_clip(folder, resolution=None, frames=None, device=None, dtype=torch.float32):
    """Frames and masks of a sequence folder, resized so the long side is `resolution`; an empty
    or all-foreground mask stops with one SequenceFolderError line."""
    info = seq.validate_sequence_folder(folder)
    frames = np.arange(info.frame_count) if frames is None else np.asarray(frames)
    scale = 1.0 if resolution is None else resolution / max(info.width, info.height)
    size = (int(round(info.width * scale)), int(round(info.height * scale)))
    images, masks = [], []
    for index in frames:
        rgb = seq.read_rgb(seq.frame_path(folder, info, int(index)))
        hand = seq.read_mask(seq.mask_path(folder, info, int(index)))
        seq.check_mask(hand, int(index))
        mask = hand.astype(np.float32)
        if scale != 1.0:
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
            mask = cv2.resize(mask, size, interpolation=cv2.INTER_AREA)
        images.append(rgb.astype(np.float32) / 255)
        masks.append((mask >= 0.5).astype(np.float32))
    K = np.asarray(info.K, dtype=np.float64).copy()
    K[:2] *= np.array([[size[0] / info.width], [size[1] / info.height]])
    return ClipData(torch.as_tensor(np.stack(images), dtype=dtype, device=device),
                    torch.as_tensor(np.stack(masks)[..., None], dtype=dtype, device=device),
                    torch.as_tensor(K, dtype=dtype, device=device), info, frames)
