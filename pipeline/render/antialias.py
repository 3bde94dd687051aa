"""Silhouette-edge gradients: analytic antialiasing of a rendered image (in the manner of
nvdiffrast's antialias, written for pure PyTorch).

A hard rasteriser's image does not change continuously when a silhouette moves, so it gives
no gradient there. Here every silhouette edge (a mesh edge between a front- and a back-facing
face, or an open boundary) is intersected with the segments joining neighbouring pixel
centres. Where it crosses such a segment at a visible occlusion boundary, the two pixels'
values are blended by how far the edge lies past the segment's midpoint. The result is a
continuous function of the edge's position, so vertices receive gradients that move silhouette
edges outward and inward, for masks and colour images alike.
"""
from __future__ import annotations

import dataclasses

import torch

from .rasterize import NEAR, Rasterization, front_facing, project

OCCLUSION_GAP = 0.002         # relative depth by which the outside pixel must lie behind


@dataclasses.dataclass
class EdgeTopology:
    """Undirected edges of a triangle mesh and the (one or two) faces on each side."""

    edges: torch.Tensor        # (E, 2) vertex indices
    faces: torch.Tensor        # (E, 2) face indices, -1 for an open boundary
    forward: torch.Tensor      # (E, 2) bool: that face runs along the edge from edges[:, 0] to [:, 1]
    mesh_faces: torch.Tensor   # (F, 3) the faces themselves


def edge_topology(faces):
    """Build EdgeTopology for faces (F, 3) (any device)."""
    device = faces.device
    f = faces.long()
    corners = torch.stack([f, f.roll(-1, dims=1), f.roll(-2, dims=1)], dim=2).reshape(-1, 3)
    face_id = torch.arange(len(f), device=device).repeat_interleave(3)
    key_a = torch.minimum(corners[:, 0], corners[:, 1])
    key_b = torch.maximum(corners[:, 0], corners[:, 1])
    key = key_a * (int(f.max()) + 1) + key_b
    order = torch.argsort(key, stable=True)
    key, face_id, corners = key[order], face_id[order], corners[order]
    _, counts = torch.unique_consecutive(key, return_counts=True)
    first = torch.cumsum(counts, 0) - counts
    edges = torch.stack([torch.minimum(corners[first, 0], corners[first, 1]),
                         torch.maximum(corners[first, 0], corners[first, 1])], dim=1)
    has_second = counts >= 2
    second = torch.where(has_second, first + 1, first)
    edge_faces = torch.stack([face_id[first], torch.where(has_second, face_id[second], -1)], dim=1)
    runs_forward = corners[:, 0] < corners[:, 1]
    forward = torch.stack([runs_forward[first], runs_forward[second] & has_second], dim=1)
    return EdgeTopology(edges, edge_faces, forward, f)


def antialias(image, points, K, rast: Rasterization, topology: EdgeTopology):
    """Blend `image` (B, H, W, C) across the visible silhouette edges of the mesh.

    points (B, V, 3) camera-frame vertices (differentiable), K (B, 3, 3) or (3, 3), rast the
    rasterisation that produced the image (for its depth buffer)."""
    batch, height, width, channels = image.shape
    crossings = silhouette_crossings(points, K, rast, topology)
    if crossings is None:
        return image
    inside, outside, coverage = crossings
    flat = image.reshape(-1, channels)
    value_in, value_out = flat[inside], flat[outside]
    spills_out = coverage > 0.5
    target = torch.where(spills_out, outside, inside)
    delta = torch.where(spills_out.unsqueeze(1), value_in - value_out, value_out - value_in)
    weight = (coverage - 0.5).abs().unsqueeze(1)
    return flat.index_add(0, target, weight * delta).view(batch, height, width, channels)


def silhouette_crossings(points, K, rast: Rasterization, topology: EdgeTopology):
    """Visible silhouette crossings of pixel-centre segments.

    Returns (inside pixel (M,), outside pixel (M,), coverage (M,)) with flat pixel indices and
    coverage = distance from the inside pixel's centre to the edge along the segment (0..1,
    differentiable in `points`), or None when there is none."""
    batch, height, width = rast.face.shape
    faces_of_edge = topology.faces
    with torch.no_grad():
        front = front_facing(points, topology.mesh_faces)
        f0, f1 = faces_of_edge[:, 0], faces_of_edge[:, 1]
        front0 = front[:, f0]
        front1 = torch.where(f1 >= 0, front[:, f1.clamp(min=0)], torch.zeros_like(front0))
        silhouette = front0 != front1
        z = points[..., 2]
        e0, e1 = topology.edges[:, 0], topology.edges[:, 1]
        silhouette &= (z[:, e0] > NEAR) & (z[:, e1] > NEAR)
        frame, edge = torch.nonzero(silhouette, as_tuple=True)
        if len(edge) == 0:
            return None
        # orient each edge a -> b as its front-facing face runs along it: a front-facing face has
        # a negative signed area in the image (y down), so its inside is where cross(b - a, x - a) < 0
        use_second = ~front0[frame, edge]
        forward = torch.where(use_second, topology.forward[edge, 1], topology.forward[edge, 0])
        start = torch.where(forward, topology.edges[edge, 0], topology.edges[edge, 1])
        end = torch.where(forward, topology.edges[edge, 1], topology.edges[edge, 0])
    pixels = project(points, K)
    a, b = pixels[frame, start], pixels[frame, end]
    with torch.no_grad():
        za, zb = z[frame, start], z[frame, end]
    results = [_crossings_along(axis, a, b, za, zb, frame, rast) for axis in (0, 1)]
    results = [r for r in results if r is not None]
    if not results:
        return None
    inside = torch.cat([r[0] for r in results])
    outside = torch.cat([r[1] for r in results])
    coverage = torch.cat([r[2] for r in results])
    return inside, outside, coverage


def _crossings_along(axis, a, b, za, zb, frame, rast):
    """Crossings of silhouette segments a-b with pixel-centre segments along `axis`
    (0: horizontal neighbours, crossing rows; 1: vertical neighbours, crossing columns)."""
    height, width = rast.height, rast.width
    across = 1 - axis                    # coordinate that indexes the rows (or columns) crossed
    lines = height if axis == 0 else width
    along_size = width if axis == 0 else height
    with torch.no_grad():
        lo = torch.minimum(a[:, across], b[:, across])
        hi = torch.maximum(a[:, across], b[:, across])
        first = torch.ceil(lo - 0.5).clamp(min=0)
        last = torch.floor(hi - 0.5).clamp(max=lines - 1)
        # a crossing needs the line strictly inside the segment's span; each edge is handled
        # by the neighbour pairs across its major axis only (rows for steep edges, columns for
        # flat ones), so moving it changes the covered area once, not twice
        count = (last - first + 1).clamp(min=0).long()
        extent = (a - b).abs()
        major = extent[:, across] >= extent[:, axis] if axis == 0 else extent[:, across] > extent[:, axis]
        count = torch.where((hi - lo > 1e-9) & major, count, torch.zeros_like(count))
        total = int(count.sum())
        if total == 0:
            return None
        owner = torch.repeat_interleave(torch.arange(len(count), device=a.device), count)
        start = torch.cumsum(count, 0) - count
        line = first[owner] + (torch.arange(total, device=a.device) - start[owner])
    line_centre = line + 0.5
    pa, pb = a[owner], b[owner]
    t = (line_centre - pa[:, across]) / (pb[:, across] - pa[:, across])
    position = pa[:, axis] + t * (pb[:, axis] - pa[:, axis])          # differentiable
    with torch.no_grad():
        keep = (t >= 0) & (t <= 1)
        lower = torch.floor(position - 0.5)                             # pixel before the crossing
        keep &= (lower >= 0) & (lower + 1 <= along_size - 1)
        lower = lower.clamp(0, along_size - 2).long()
        line_i = line.long()
        if axis == 0:
            pixel_lower = (frame[owner] * height + line_i) * width + lower
            pixel_upper = pixel_lower + 1
            upper_centre = torch.stack([lower + 1.5, line_centre], dim=1)
        else:
            pixel_lower = (frame[owner] * height + lower) * width + line_i
            pixel_upper = pixel_lower + width
            upper_centre = torch.stack([line_centre, lower + 1.5], dim=1)
        upper_inside = _cross(pb - pa, upper_centre.to(pa.dtype) - pa) < 0
        inside = torch.where(upper_inside, pixel_upper, pixel_lower)
        outside = torch.where(upper_inside, pixel_lower, pixel_upper)
        inverse_z = (1 - t) / za[owner] + t / zb[owner]
        edge_depth = 1.0 / inverse_z
        depth = rast.depth.reshape(-1)
        # visible occlusion boundary: the inside pixel sees a surface and the outside pixel sees
        # the background or something behind the edge. (An edge hidden behind an occluder is
        # rejected here too, because the occluder then also covers the outside pixel, except
        # where the occluder's own outline falls in the same pixel pair.)
        keep &= rast.face.reshape(-1)[inside] >= 0
        keep &= depth[outside] > edge_depth * (1 + OCCLUSION_GAP)
    offset = position - 0.5 - lower.to(position.dtype)                 # lower centre -> crossing
    coverage = torch.where(upper_inside, 1 - offset, offset)
    return inside[keep], outside[keep], coverage[keep]


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
