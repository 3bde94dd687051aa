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


def bilinear_texels(uv, size):
    """The four texels (rows, columns (N, 4)) and weights (N, 4) that sample_texture's bilinear
    lookup (grid_sample, align_corners False, border padding) reads at each UV (N, 2)."""
    x = (uv[:, 0] * size - 0.5).clamp(0, size - 1)
    y = ((1 - uv[:, 1]) * size - 0.5).clamp(0, size - 1)
    x0, y0 = x.floor(), y.floor()
    fx, fy = x - x0, y - y0
    x0, y0 = x0.long(), y0.long()
    x1, y1 = (x0 + 1).clamp(max=size - 1), (y0 + 1).clamp(max=size - 1)
    rows = torch.stack([y0, y0, y1, y1], dim=1)
    columns = torch.stack([x0, x1, x0, x1], dim=1)
    weights = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
    return rows, columns, weights
