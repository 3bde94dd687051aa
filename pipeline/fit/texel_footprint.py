"""How much of the texture one pixel of the frames covers, the texture size whose texels the frames
measure, and the avatar's texture grown to it before the finer albedo solve.

A pixel on face f of the mesh covers uv_area(f) / screen_area(f) of the UV square (the same
triangle's area in the texture's unit square, and projected into the frame, in pixels), so at a
texture of T x T texels it covers T^2 times that many texels. Above 1 a pixel spans several
texels, and the albedo solve has more unknowns there than the frames measure (its texels come out
blurred or left to the fill); below 1 the frames hold detail the texture cannot keep. The median
over the pixels the albedo solve reads, in its frames at the size it reads them, is the clip's
footprint; `fitting_texture_size` is the largest power of two whose texels are TEXEL_PIXELS pixels
across at that pixel. A texel one pixel across (the issue's "no smaller than a pixel") was too fine
in practice: on the phone-like clip's frames at 873 px that rule gives 1024 texels, whose albedo came
out noisy (sharpness 1.01 of the truth's, new poses below the 512 texture's), while 512, two pixels
across, was the best of 256 / 512 / 1024 (docs/fidelity.md, "Texture detail at the footage's
resolution"). A pixel's footprint reaches the solve blurred by the frames' registration and the
bilinear lookup, and the solve pools each texel from the few frames that see it, not from one.
"""
from __future__ import annotations

import math

import torch

from ..render.rasterize import rasterize

FRAMES = 12        # frames measured at most (spread over the clip)
BATCH = 4
TEXEL_PIXELS = 2.0     # pixels across a texel, at the median pixel the solve reads
MOST_TEXELS = 2048     # the largest texture grown to
# texels per pixel of the finer solve's frames that the rule gave on the phone-like clip imported with the hand's
# window (512 from 873 px frames); the import holds every hand with the same margin, so the time estimate takes it
# for any imported clip before the fit has measured its own
IMPORTED_TEXELS_PER_PIXEL = 0.59


def _triangle_areas(a, b, c):
    """(...) unsigned areas of 2-D triangles with corners (..., 2)."""
    u, v = b - a, c - a
    return 0.5 * (u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]).abs()


def pixel_shares(vertices, mesh, K, height, width):
    """((B, H, W) the share of the UV square each pixel's surface covers, (B, H, W) bool: the pixels
    a face covers) for vertices (B, V, 3) in the camera frame, a RenderMesh with UVs and K (B, 3, 3)."""
    uv_area = _triangle_areas(*(mesh.uvs[mesh.faces_uv[:, k]].double() for k in range(3)))        # (F,)
    projected = vertices.double() @ K.double().transpose(1, 2)
    pixels = projected[..., :2] / projected[..., 2:].clamp(min=1e-9)
    screen_area = _triangle_areas(*(pixels[:, mesh.faces[:, k]] for k in range(3)))             # (B, F)
    face = rasterize(vertices.detach(), mesh.faces, K, height, width).face
    drawn = face.clamp(min=0)
    share = uv_area[drawn] / torch.gather(screen_area, 1, drawn.flatten(1)).view_as(drawn).clamp(min=1e-12)
    return share, face >= 0


@torch.no_grad()
def pixel_footprint(problem, frames=None) -> float:
    """The median share of the UV square (texels of a 1 x 1 texture) that one pixel the albedo solve
    reads covers, over up to FRAMES of `problem`'s frames (indices; default all), spread evenly over
    them, at the size its clip holds them; nan where no frame shows a pixel."""
    avatar, clip = problem.avatar, problem.clip
    frames = torch.arange(len(problem.frames)) if frames is None else torch.as_tensor(frames, dtype=torch.long)
    if len(frames) > FRAMES:
        frames = frames[torch.linspace(0, len(frames) - 1, FRAMES).round().long().unique()]
    shares = []
    for batch in torch.as_tensor(frames, dtype=torch.long).split(BATCH):
        batch = batch.to(avatar.albedo.device)
        vertices, _ = avatar.posed(batch)
        share, drawn = pixel_shares(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width)
        shares.append(share[drawn & problem.compared_pixels(batch, albedo_solve=True)])
    shares = torch.cat(shares)
    return float(shares.median()) if len(shares) else float("nan")


def fitting_texture_size(footprint, least=64, most=MOST_TEXELS, texel_pixels=TEXEL_PIXELS) -> int:
    """The largest power of two T (within [least, most]) whose texels are `texel_pixels` pixels of
    `footprint` (the share of the UV square one covers) across, or more: footprint * T^2 <=
    1 / texel_pixels^2."""
    if not math.isfinite(footprint) or footprint <= 0:
        return least
    size = 2 ** math.floor(math.log2(1.0 / (texel_pixels * math.sqrt(footprint))))
    return int(min(most, max(least, size)))


def likely_texture_size(texture_size, solve_px) -> int:
    """The texture a fit whose stages use `texture_size` will likely write when its finer solve reads
    frames of `solve_px` (long side; None: no finer solve) and grows the texture: for the time
    estimate, before the footprint is measured."""
    if not solve_px:
        return texture_size
    return max(texture_size, 2 ** math.floor(math.log2(IMPORTED_TEXELS_PER_PIXEL * solve_px)))


def grow_texture(problem) -> dict:
    """The avatar's albedo and normal map resampled to fitting_texture_size of `problem`'s frames
    (the finer solve's view, FitProblem.at_resolution) where that is larger than their size; never
    shrunk. Returns {"pixel_footprint", "texture_size" (as it is now), "grown_from" (the size before,
    or None where it stayed)}."""
    footprint = pixel_footprint(problem)
    size, fitting = int(problem.avatar.albedo.shape[-1]), fitting_texture_size(footprint)
    if fitting > size:
        problem.avatar.resize_textures(fitting)
    return {"pixel_footprint": footprint, "texture_size": max(size, fitting), "grown_from": size if fitting > size
            else None}
