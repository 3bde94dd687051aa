"""Bilinear texture lookup in UV space, differentiable in the texture and in the UVs."""
from __future__ import annotations

import torch
import torch.nn.functional as F


def sample_texture(texture, uv):
    """Sample `texture` (C, H, W) at `uv` (N, 2) -> (N, C).

    UVs follow the OpenGL/Blender convention (v up: v = 1 is the texture's row 0); texel
    centres sit at ((i + 0.5) / W, 1 - (j + 0.5) / H); lookups outside [0, 1] clamp to the border.
    """
    grid = torch.stack([2 * uv[:, 0] - 1, 1 - 2 * uv[:, 1]], dim=-1).view(1, 1, -1, 2)
    sampled = F.grid_sample(texture.unsqueeze(0), grid.to(texture.dtype), mode="bilinear",
                            padding_mode="border", align_corners=False)
    return sampled[0, :, 0].transpose(0, 1)
