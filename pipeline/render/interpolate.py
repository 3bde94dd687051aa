"""Differentiable attributes at covered pixels: barycentrics recomputed from vertex positions.

The rasteriser decides visibility without gradients; here, for each covered pixel, the
perspective-correct barycentric coordinates of its pixel centre are recomputed with torch ops
from the (differentiable) camera-frame vertex positions, so interpolated attributes carry
gradients to both the attributes and the geometry. Work is done only on covered pixels
("fragments"); `to_image` scatters fragment values into a dense image.
"""
from __future__ import annotations

import dataclasses

import torch

from .rasterize import Rasterization


@dataclasses.dataclass
class Fragments:
    """The covered pixels of a batch: where they are and their differentiable barycentrics."""

    pixel: torch.Tensor        # (N,) flat index into (B * H * W)
    frame: torch.Tensor        # (N,) frame of each fragment
    face: torch.Tensor         # (N,) face index
    bary: torch.Tensor         # (N, 3) perspective-correct barycentrics (differentiable)
    batch: int
    height: int
    width: int


def fragments(points, faces, K, rast: Rasterization):
    """Differentiable barycentrics of every covered pixel centre.

    points (B, V, 3) camera-frame vertices (the same that were rasterised), faces (F, 3),
    K (B, 3, 3) or (3, 3)."""
    batch = points.shape[0]
    pixel, face = rast.pixel_index()
    hw = rast.height * rast.width
    frame = pixel // hw
    local = pixel % hw
    centre = torch.stack([local % rast.width, local // rast.width], dim=-1).to(points.dtype) + 0.5
    corners = points[frame[:, None], faces[face]]                       # (N, 3, 3)
    K = K if K.dim() == 3 else K.unsqueeze(0).expand(batch, -1, -1)
    screen = _project_per_fragment(corners, K[frame])
    a, b, c = screen[:, 0], screen[:, 1], screen[:, 2]
    area = _cross(b - a, c - a)
    area = torch.where(area.abs() > 1e-20, area, torch.full_like(area, 1e-20))
    w0 = _cross(b - centre, c - centre) / area
    w1 = _cross(c - centre, a - centre) / area
    w2 = 1.0 - w0 - w1
    screen_bary = torch.stack([w0, w1, w2], dim=-1)
    inverse_z = 1.0 / corners[..., 2]
    weighted = screen_bary * inverse_z
    bary = weighted / weighted.sum(-1, keepdim=True)
    return Fragments(pixel, frame, face, bary, batch, rast.height, rast.width)


def _project_per_fragment(corners, K):
    """(N, 3, 3) camera points with per-fragment K (N, 3, 3) -> (N, 3, 2) pixels."""
    xy = corners[..., :2] / corners[..., 2:3]
    f = torch.stack([K[:, 0, 0], K[:, 1, 1]], dim=-1)[:, None]
    c = torch.stack([K[:, 0, 2], K[:, 1, 2]], dim=-1)[:, None]
    return xy * f + c


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def interpolate(attributes, frags: Fragments, faces):
    """Attributes at the fragments: (N, C).

    attributes: (B, V, C) per frame or (V, C) shared; faces: (F, 3) indices into them (pass the
    UV faces for UV attributes, whose vertices differ from the position vertices at seams)."""
    corner_index = faces[frags.face]                                      # (N, 3)
    if attributes.dim() == 3:
        values = attributes[frags.frame[:, None], corner_index]           # (N, 3, C)
    else:
        values = attributes[corner_index]
    return (frags.bary.unsqueeze(-1) * values).sum(1)


def to_image(values, frags: Fragments, background=0.0):
    """Scatter fragment values (N, C) into an image (B, H, W, C) filled with `background`."""
    channels = values.shape[-1]
    image = values.new_empty((frags.batch * frags.height * frags.width, channels))
    image[:] = torch.as_tensor(background, dtype=values.dtype, device=values.device)
    image = image.index_put((frags.pixel,), values)
    return image.view(frags.batch, frags.height, frags.width, channels)
