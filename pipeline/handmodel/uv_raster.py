"""Texel sampling of the model's UV layout (numpy): which face and barycentric weights cover
each texel centre, and per-vertex attributes interpolated into texture space.

Texel (row r, column c) of an H x W texture has its centre at u = (c + 0.5) / W and
v = 1 - (r + 0.5) / H (image rows top to bottom, UV v up).
"""
from __future__ import annotations

import numpy as np


def rasterize_uv(uvs, faces_uv, size):
    """face (size, size) int index of the UV triangle covering each texel centre (-1: none) and
    bary (size, size, 3) its barycentric weights. uvs (U, 2) in [0, 1]; faces_uv (F, 3)."""
    face = np.full((size, size), -1, dtype=np.int64)
    bary = np.zeros((size, size, 3))
    corners = np.asarray(uvs, dtype=np.float64)[faces_uv] * size  # (F, 3, 2) in texel units
    corners[..., 1] = size - corners[..., 1]                      # v up -> rows down
    lo = np.clip(np.floor(corners.min(1) - 0.5).astype(int), 0, size - 1)
    hi = np.clip(np.ceil(corners.max(1) - 0.5).astype(int), 0, size - 1)
    for f in range(len(corners)):
        cols = np.arange(lo[f, 0], hi[f, 0] + 1) + 0.5
        rows = np.arange(lo[f, 1], hi[f, 1] + 1) + 0.5
        px, py = np.meshgrid(cols, rows)
        (x0, y0), (x1, y1), (x2, y2) = corners[f]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        w1 = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / area
        w2 = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / area
        w0 = 1 - w1 - w2
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
        r = (py[inside] - 0.5).astype(int)
        c = (px[inside] - 0.5).astype(int)
        face[r, c] = f
        bary[r, c] = np.stack([w0[inside], w1[inside], w2[inside]], -1)
    return face, bary


def interpolate(face, bary, faces, values):
    """Per-vertex values (V, C) -> per-texel (H, W, C) over the mesh faces (F, 3); zero where
    no face covers the texel."""
    values = np.asarray(values, dtype=np.float64)
    out = np.zeros(face.shape + values.shape[1:])
    covered = face >= 0
    corner_values = values[faces[face[covered]]]          # (N, 3, C)
    out[covered] = np.einsum("nk,nk...->n...", bary[covered], corner_values)
    return out


def dilate(image, valid, iterations=4):
    """Grow `image` (H, W, C) from the `valid` texels (H, W) by `iterations` texels (mean of the
    valid 4-neighbours), so texture filtering at chart borders picks up no background."""
    image = image.copy()
    valid = valid.copy()
    for _ in range(iterations):
        total = np.zeros_like(image)
        count = np.zeros(valid.shape)
        for axis, step in ((0, 1), (0, -1), (1, 1), (1, -1)):
            shifted_valid = np.roll(valid, step, axis)
            shifted = np.roll(image, step, axis)
            edge = [slice(None)] * 2
            edge[axis] = 0 if step == 1 else -1
            shifted_valid[tuple(edge)] = False  # no wrap-around
            total += shifted * shifted_valid[..., None]
            count += shifted_valid
        grow = ~valid & (count > 0)
        image[grow] = total[grow] / count[grow][:, None]
        valid = valid | grow
    return image, valid
