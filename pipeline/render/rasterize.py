"""Visibility: which face covers each pixel centre, and at what depth (no gradients).

Pure PyTorch, batched over frames, on any device. Every face enumerates the pixel centres in
its screen bounding box; an inside test with edge functions and a depth-keyed scatter-min
keep the nearest face per pixel. The edge functions and the inverse depth are affine in the
image, so each face's are evaluated once at the first pixel centre of its box and stepped from
there by whole pixels (as hardware rasterisers do), a few operations per candidate pixel.
Faces with a vertex at or behind the near plane are culled (never clipped), so geometry behind
or crossing the camera never produces garbage.

Pixel convention (OpenCV): pixel (i, j) has its centre at (i + 0.5, j + 0.5) in the image
coordinates that K maps to, i.e. x to the right, y down.
"""
from __future__ import annotations

import dataclasses

import torch

NEAR = 1e-3          # metres
_FACE_BITS = 31      # face index in the low bits of the depth-sorted key


@dataclasses.dataclass
class Rasterization:
    """Per-pixel visibility of a batch of frames (B, H, W)."""

    face: torch.Tensor    # (B, H, W) long, index into faces, -1 where no face covers the centre
    depth: torch.Tensor   # (B, H, W) camera-space z of the visible surface, +inf for background
    height: int
    width: int

    @property
    def covered(self):
        return self.face >= 0

    def pixel_index(self):
        """Flat indices (N,) of covered pixels in (B * H * W) order, and their faces (N,)."""
        flat = self.face.reshape(-1)
        index = torch.nonzero(flat >= 0).squeeze(1)
        return index, flat[index]


def project(points, K):
    """Camera-frame points (B, N, 3) -> pixel coordinates (B, N, 2) under K (B, 3, 3) or (3, 3)."""
    K = K if K.dim() == 3 else K.unsqueeze(0)
    z = points[..., 2:3]
    safe = torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))
    xy = points[..., :2] / safe
    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]
    cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
    return torch.stack([fx * xy[..., 0] + cx, fy * xy[..., 1] + cy], dim=-1)


def pixel_rays(K, batch, height, width, dtype, device):
    """(B, H, W, 3) the camera-frame direction (x, y, 1) through each pixel's centre under K
    ((B, 3, 3) or (3, 3)): a point at depth z on it is z times it; project()'s inverse."""
    K = (K if K.dim() == 3 else K.unsqueeze(0)).to(dtype).expand(batch, 3, 3)
    rows, columns = torch.meshgrid(torch.arange(height, dtype=dtype, device=device) + 0.5,
                                   torch.arange(width, dtype=dtype, device=device) + 0.5, indexing="ij")
    x = (columns - K[:, 0, 2, None, None]) / K[:, 0, 0, None, None]
    y = (rows - K[:, 1, 2, None, None]) / K[:, 1, 1, None, None]
    return torch.stack([x, y, torch.ones_like(x)], dim=-1)


def front_facing(points, faces):
    """(B, F) bool: the face's outward normal points towards the camera at the origin."""
    v0, v1, v2 = (points.index_select(1, faces[:, k]) for k in range(3))
    normal = torch.cross(v1 - v0, v2 - v0, dim=-1)
    return (normal * v0).sum(-1) < 0


@torch.no_grad()
def face_boxes(points, faces, K, height, width, cull_backfaces=True, near=NEAR):
    """Per face and frame: screen corners p0, p1, p2 (B, F, 2), depths z0, z1, z2 (B, F), twice
    the signed area, the first pixel x0, y0 and width of its box of pixel centres, and the
    number of pixels in that box, flat (B * F,) (0 for a culled or invalid face)."""
    pixels = project(points, K)
    z = points[..., 2]
    p0, p1, p2 = (pixels.index_select(1, faces[:, k]) for k in range(3))
    z0, z1, z2 = (z.index_select(1, faces[:, k]) for k in range(3))
    area = _edge(p0, p1, p2)                                          # twice the signed area
    valid = (z0 > near) & (z1 > near) & (z2 > near) & (area.abs() > 1e-12)
    valid &= torch.isfinite(area)
    if cull_backfaces:
        valid &= front_facing(points, faces)
    lo = torch.minimum(torch.minimum(p0, p1), p2)
    hi = torch.maximum(torch.maximum(p0, p1), p2)
    # pixel indices whose centres (i + 0.5) lie inside the bounding box, clamped to the image
    x0 = torch.ceil(lo[..., 0] - 0.5).clamp(min=0)
    x1 = torch.floor(hi[..., 0] - 0.5).clamp(max=width - 1)
    y0 = torch.ceil(lo[..., 1] - 0.5).clamp(min=0)
    y1 = torch.floor(hi[..., 1] - 0.5).clamp(max=height - 1)
    box_w = (x1 - x0 + 1).clamp(min=0)
    box_h = (y1 - y0 + 1).clamp(min=0)
    box_w = torch.where(valid, box_w, torch.zeros_like(box_w))
    count = (box_w * box_h).long().reshape(-1)
    return p0, p1, p2, z0, z1, z2, area, x0, y0, box_w, count


def face_planes(p0, p1, p2, z0, z1, z2, area, x0, y0):
    """Per face (B, F): the barycentric weights w0, w1 of the corners p0, p1 and the inverse
    depth 1/z at the first pixel centre (x0 + 0.5, y0 + 0.5) of the face's box, each with its
    steps per pixel in x and y: nine tensors (w0, w0_x, w0_y, w1, w1_x, w1_y, d, d_x, d_y).

    Under a perspective camera 1/z is affine in the image: 1/z2 + w0 (1/z0 - 1/z2) + w1 (1/z1 - 1/z2)."""
    first = torch.stack([x0 + 0.5, y0 + 0.5], dim=-1)
    w0 = _edge(p1, p2, first) / area
    w1 = _edge(p2, p0, first) / area
    w0_x, w0_y = (p1[..., 1] - p2[..., 1]) / area, (p2[..., 0] - p1[..., 0]) / area
    w1_x, w1_y = (p2[..., 1] - p0[..., 1]) / area, (p0[..., 0] - p2[..., 0]) / area
    u0, u1 = 1.0 / z0 - 1.0 / z2, 1.0 / z1 - 1.0 / z2
    d = 1.0 / z2 + w0 * u0 + w1 * u1
    return w0, w0_x, w0_y, w1, w1_x, w1_y, d, w0_x * u0 + w1_x * u1, w0_y * u0 + w1_y * u1


def candidate_test(planes, dx, dy):
    """For candidates at whole-pixel offsets dx, dy (float) from their face's first pixel centre,
    each with its face's nine `planes` rows: (inside the face and in front of the camera, bool;
    the inverse depth there)."""
    w0, w0_x, w0_y, w1, w1_x, w1_y, d, d_x, d_y = planes
    w0 = w0 + dx * w0_x + dy * w0_y
    w1 = w1 + dx * w1_x + dy * w1_y
    inverse_depth = d + dx * d_x + dy * d_y
    return (w0 >= 0) & (w1 >= 0) & (w0 + w1 <= 1) & (inverse_depth > 0), inverse_depth


@torch.no_grad()
def rasterize(points, faces, K, height, width, cull_backfaces=True, near=NEAR):
    """Nearest face and depth at every pixel centre.

    points: (B, V, 3) vertex positions in the camera frame (metres, OpenCV axes);
    faces: (F, 3) long; K: (B, 3, 3) or (3, 3) intrinsics in pixels.
    cull_backfaces drops faces turned away from the camera (exact for closed meshes).
    """
    device = points.device
    batch, num_faces = points.shape[0], faces.shape[0]
    p0, p1, p2, z0, z1, z2, area, x0, y0, box_w, count = face_boxes(points, faces, K, height, width,
                                                                    cull_backfaces, near)
    depth = torch.full((batch * height * width,), float("inf"), dtype=points.dtype, device=device)
    face_map = torch.full((batch * height * width,), -1, dtype=torch.long, device=device)
    total = int(count.sum())
    if total == 0:
        return Rasterization(face_map.view(batch, height, width), depth.view(batch, height, width), height, width)
    planes = face_planes(p0, p1, p2, z0, z1, z2, area, x0, y0)
    # one candidate per (face, pixel in its box)
    owner = torch.repeat_interleave(torch.arange(batch * num_faces, device=device), count)
    start = torch.cumsum(count, 0) - count
    offset = torch.arange(total, device=device) - start[owner]
    bw = box_w.reshape(-1).long()[owner]
    dx, dy = offset % bw, offset // bw
    inside, inverse_depth = candidate_test([plane.reshape(-1)[owner] for plane in planes],
                                           dx.to(points.dtype), dy.to(points.dtype))
    cand_depth = 1.0 / inverse_depth[inside]
    frame = owner[inside] // num_faces
    face_index = owner[inside] % num_faces
    px = x0.reshape(-1).long()[owner][inside] + dx[inside]
    py = y0.reshape(-1).long()[owner][inside] + dy[inside]
    pixel = (frame * height + py) * width + px
    # sort key: depth bits (positive floats order like integers) then face index
    depth_bits = cand_depth.float().view(torch.int32).long()
    key = (depth_bits << _FACE_BITS) | face_index
    best = torch.full((batch * height * width,), torch.iinfo(torch.long).max, dtype=torch.long, device=device)
    best.scatter_reduce_(0, pixel, key, reduce="amin")
    hit = best != torch.iinfo(torch.long).max
    winner_face = best[hit] & ((1 << _FACE_BITS) - 1)
    face_map[hit] = winner_face
    # exact depth of the winning candidates (the key held a float32 copy)
    is_winner = key == best[pixel]
    depth[pixel[is_winner]] = cand_depth[is_winner]
    return Rasterization(face_map.view(batch, height, width), depth.view(batch, height, width), height, width)


def _edge(a, b, c):
    """Edge function: twice the signed area of triangle (a, b, c) in 2D."""
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
