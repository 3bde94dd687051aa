"""Which texels of a texture a set of frames shows: the UV atlas seen through the camera."""
from __future__ import annotations

import math

import torch

from .interpolate import fragments, interpolate
from .rasterize import rasterize
from .renderer import RenderMesh


def visible_texels(vertices, mesh: RenderMesh, K, height, width, texture_size, supersample=None, batch_size=4,
                   minimum_samples=1):
    """(T, T) bool image of the UV atlas (row 0 = v 1): texels that hold the UV of a visible
    surface point at `minimum_samples` or more pixel centres of the frames (texel_samples)."""
    return texel_samples(vertices, mesh, K, height, width, texture_size, supersample, batch_size) >= minimum_samples


def texel_samples(vertices, mesh: RenderMesh, K, height, width, texture_size, supersample=None, batch_size=4):
    """(T, T) int image of the UV atlas (row 0 = v 1): how many pixel centres of the frames show
    a visible surface point whose UV falls in each texel.

    vertices (F, V, 3) camera frame, metres; K (3, 3) or per frame (F, 3, 3) for the height x width images. The frames
    are rendered `supersample` times finer (default: at least two samples per texel width) so
    that the seen texels form a solid area, not a sampling pattern."""
    vertices = torch.as_tensor(vertices, dtype=torch.float32)
    device = vertices.device
    supersample = supersample or max(1, math.ceil(2 * texture_size / max(height, width)))
    K = torch.as_tensor(K, dtype=vertices.dtype, device=device).clone()
    K = (K if K.dim() == 3 else K[None]).expand(len(vertices), 3, 3).clone()
    K[:, :2] *= supersample
    faces, uvs, faces_uv = (t.to(device) for t in (mesh.faces, mesh.uvs, mesh.faces_uv))
    counts = torch.zeros(texture_size * texture_size, dtype=torch.long, device=device)
    for chunk, chunk_K in zip(vertices.split(batch_size), K.split(batch_size)):
        rast = rasterize(chunk, faces, chunk_K, height * supersample, width * supersample)
        uv = interpolate(uvs.to(chunk.dtype), fragments(chunk, faces, chunk_K, rast), faces_uv)
        column = (uv[:, 0] * texture_size).floor().long().clamp(0, texture_size - 1)
        row = ((1 - uv[:, 1]) * texture_size).floor().long().clamp(0, texture_size - 1)
        counts.index_add_(0, row * texture_size + column, torch.ones_like(row))
    return counts.view(texture_size, texture_size).cpu().numpy()
