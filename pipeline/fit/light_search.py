"""The point light's direction and the ambient ratio searched over the whole sphere before the
light is fitted.

Gradient steps move the light from where it starts (in front of the hand, above the camera) to
the nearest light that explains the frames, which need not be the best: on the phone-like clip
(a window's light from the camera's left, in front of the hand) one fit seed in three found it, two
settled on a light above and behind the hand (held-out PSNR 27.6-27.7 dB against 28.4, the
albedo's mean error 0.110 against 0.077). So before the first stage that fits the light (the
joint stage: the poses and shape are settled by then), every candidate light is scored by how
well one colour per texel explains what the frames show of it: a texel seen under different
normals in different frames must change in brightness as the light's shading says, whatever its
albedo. Per candidate, each texel's colour is solved in least squares (TEXELS x TEXELS texels,
so that each pools a few pixels of each frame), and the score is the residual's share of the
frames' energy. The candidates: CANDIDATES directions at the current light's distance from the
hand's centre (at least MIN_DISTANCE: a light nearer than a few hand lengths shines from a
different direction on each finger, which the fit then has to keep), each with every ambient
ratio of AMBIENTS, and the current light itself; the best replaces the current one only where it
scores at least MIN_GAIN lower. Where it does, the texels' colours it solved become the starting
albedo (upsampled to the texture, texels no frame showed at the albedo's mean): left at its flat
start, the albedo's light palm and dark back pulled the light away again in the joint stage
(the phone-like clip's seed 0: searched to the window, fitted to above the hand).

Pixels the camera clipped at white are left out, as in the albedo solve (FitProblem.colour_pixels).
In the linear colour model the frames are decoded first (the shading multiplies linear light);
the exposure gains (1 at this point unless resumed) are divided out. The environment light, the
specular lobe and shadows are left out: the search is for the light's direction, which they do
not explain.
"""
from __future__ import annotations

import torch

from ..formats.colour_model import linear_to_srgb, srgb_to_linear
from ..formats.environment_light import sphere_directions
from ..render.rasterize import pixel_rays
from ..render.renderer import render
from ..render.vector_ops import dot3, normalized

CANDIDATES = 64                      # directions (a Fibonacci lattice over the sphere)
AMBIENTS = (0.15, 0.3, 0.5, 0.7)     # ambient ratios tried with each
TEXELS = 64                          # the texel grid's side the colours are pooled on
FRAMES = 24                          # fitted frames used at most (spread over the clip)
BATCH = 6
MIN_DISTANCE = 0.5                   # metres from the hand's centre, at least
MIN_GAIN = 0.1                       # the share by which the best candidate must beat the current light


@torch.no_grad()
def search_light(problem) -> dict:
    """Search the light (module docstring) and move the avatar's point light and ambient ratio to
    the best candidate, in place. Returns {"before": {"position", "ambient", "residual"}, "after":
    the same of the light kept, "moved": bool, "candidates": count}; {} where no frame shows a
    usable pixel."""
    avatar = problem.avatar
    pixels = _pixels(problem)
    if pixels is None:
        return {}
    positions, normals, colours, texels = pixels
    dtype, device = positions.dtype, positions.device
    current = avatar.light_position.detach().to(dtype)
    ambient = float(avatar.ambient.item())
    centre = positions.mean(0)
    distance = (current - centre).norm().clamp(min=MIN_DISTANCE)
    directions = torch.as_tensor(sphere_directions(CANDIDATES), dtype=dtype, device=device)
    before = _residual(positions, normals, colours, texels, current, ambient)
    best = (before, current, ambient)
    for direction in directions:
        light = centre + distance * direction
        for candidate_ambient in AMBIENTS:
            residual = _residual(positions, normals, colours, texels, light, candidate_ambient)
            if residual < best[0]:
                best = (residual, light, candidate_ambient)
    moved = best[0] < (1 - MIN_GAIN) * before
    if moved:
        avatar.light_position.copy_(best[1].to(avatar.light_position.dtype))
        avatar.ambient_logit.copy_(torch.logit(torch.tensor(best[2], dtype=avatar.ambient_logit.dtype)))
        avatar.albedo.copy_(_starting_albedo(avatar, *_texel_colours(positions, normals, colours, texels,
                                                                       best[1], best[2])))
    kept = best if moved else (before, current, ambient)
    return {"before": _figures(before, current, ambient), "after": _figures(*kept), "moved": bool(moved),
            "candidates": CANDIDATES * len(AMBIENTS) + 1}


def _figures(residual, position, ambient):
    return {"position": [round(float(value), 4) for value in position], "ambient": round(float(ambient), 4),
            "residual": round(float(residual), 5)}


def _pixels(problem):
    """(positions (N, 3) camera frame, unit normals (N, 3), colours (N, 3) in the shading's space,
    texel indices (N,)) of the usable pixels of up to FRAMES fitted frames, float64; None if none."""
    avatar, clip = problem.avatar, problem.clip
    count = len(problem.frames)
    chosen = torch.linspace(0, count - 1, min(FRAMES, count), device=avatar.albedo.device).round().long().unique()
    gathered = []
    for batch in chosen.split(BATCH):
        vertices, _ = avatar.posed(batch)
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                        outputs=("alpha", "uv", "normal", "depth"), antialiased=False)
        usable = problem.colour_pixels(batch) & (images["alpha"][..., 0] > 0.5)
        colour = clip.images[batch].double()
        if problem.exposure_on:
            colour = colour / avatar.exposure_gain(batch).double().expand_as(colour)
        if avatar.linear_light:
            colour = srgb_to_linear(colour.clamp(0, 1))
        points = _camera_points(images["depth"][..., 0].double(), clip.K[batch].double())
        uv = images["uv"].double()
        column = (uv[..., 0] * TEXELS).long().clamp(0, TEXELS - 1)
        row = ((1 - uv[..., 1]) * TEXELS).long().clamp(0, TEXELS - 1)        # uv's v points up
        gathered.append((points[usable], images["normal"].double()[usable], colour[usable],
                         (row * TEXELS + column)[usable]))
    positions, normals, colours, texels = (torch.cat(part) for part in zip(*gathered))
    if len(positions) == 0:
        return None
    return positions, torch.nn.functional.normalize(normals, dim=-1), colours, texels


def _camera_points(depth, K):
    """(B, H, W, 3) the camera-frame points at each pixel centre's depth (B, H, W) for K (B, 3, 3)
    (zeros where nothing is drawn)."""
    finite = torch.where(torch.isfinite(depth), depth, torch.zeros_like(depth))
    return pixel_rays(K, *depth.shape, depth.dtype, depth.device) * finite[..., None]


def _texel_colours(positions, normals, colours, texels, light, ambient):
    """((TEXELS * TEXELS, 3) each texel's colour in least squares under the shading
    a + (1 - a) max(0, n . l) of a point light at `light` and ambient ratio a, (N, 1) that shading,
    (TEXELS * TEXELS,) bool: the texels some pixel shows)."""
    to_light = normalized(light - positions)
    shading = ambient + (1 - ambient) * dot3(normals, to_light).clamp(min=0)
    size = TEXELS * TEXELS
    numerator = torch.zeros(size, 3, dtype=colours.dtype, device=colours.device).index_add_(0, texels, colours * shading)
    denominator = torch.zeros(size, 1, dtype=colours.dtype, device=colours.device).index_add_(0, texels,
                                                                                              shading * shading)
    return numerator / denominator.clamp(min=1e-12), shading, denominator[:, 0] > 0


def _residual(positions, normals, colours, texels, light, ambient) -> torch.Tensor:
    """The share of the colours' energy that one colour per texel (_texel_colours) leaves unexplained."""
    colour_of_texel, shading, _ = _texel_colours(positions, normals, colours, texels, light, ambient)
    unexplained = colours - colour_of_texel[texels] * shading
    return unexplained.square().sum() / colours.square().sum().clamp(min=1e-12)


def _starting_albedo(avatar, colour_of_texel, _, seen):
    """(3, T, T) the avatar's starting albedo from the texels' colours (TEXELS * TEXELS, 3) where
    `seen`, their mean elsewhere, upsampled to the avatar's texture and, in the linear colour
    model, encoded to sRGB as the avatar keeps its albedo."""
    colour_of_texel = colour_of_texel.clamp(0, 1)
    mean = colour_of_texel[seen].mean(0) if bool(seen.any()) else colour_of_texel.mean(0)
    grid = torch.where(seen[:, None], colour_of_texel, mean).t().reshape(3, TEXELS, TEXELS)
    size = avatar.albedo.shape[-1]
    albedo = torch.nn.functional.interpolate(grid[None], size=(size, size), mode="bilinear", align_corners=False)[0]
    if avatar.linear_light:
        albedo = linear_to_srgb(albedo)
    return albedo.clamp(0, 1).to(avatar.albedo.dtype)
