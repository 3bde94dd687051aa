"""Poses of frames a fit did not fit, from the fitted poses of their temporal neighbours:
rotations along the shortest arc between the neighbours' (formats/rotations.slerp_axis_angle),
translations linearly; beyond the first or last fitted frame, the nearest one's. Used to start
the frames a fit keeps out (validation.py) and the held-out frames (evaluate/held_out.py)."""
from __future__ import annotations

import numpy as np
import torch

from ..formats.rotations import slerp_axis_angle
from .frames import neighbours

ROTATIONS = ("global_orient", "pose")


def interpolated_poses(fitted: dict, fitted_frames, frames) -> dict:
    """{"global_orient": (T, 3), "transl": (T, 3), "pose": (T, J, 3)} at the sequence frames
    `frames` (T,), from `fitted` (the same names, over the sorted sequence frames `fitted_frames`)."""
    left, right, fraction = neighbours(np.asarray(fitted_frames), np.asarray(frames))
    result = {}
    for name in ROTATIONS:
        values = fitted[name].detach()
        array = values.cpu().double().numpy()
        shape = (-1,) + (1,) * (array.ndim - 2)
        blended = slerp_axis_angle(array[left], array[right], fraction.reshape(shape))
        result[name] = torch.as_tensor(blended, dtype=values.dtype, device=values.device)
    transl = fitted["transl"].detach()
    weight = torch.as_tensor(fraction, dtype=transl.dtype, device=transl.device)[:, None]
    result["transl"] = transl[left] * (1 - weight) + transl[right] * weight
    return result


@torch.no_grad()
def start_from_neighbours(avatar, fitted: dict, fitted_frames, frames):
    """Set `avatar`'s per-frame pose (over the sequence frames `frames`) to interpolated_poses."""
    for name, value in interpolated_poses(fitted, fitted_frames, frames).items():
        getattr(avatar, name).copy_(value)
