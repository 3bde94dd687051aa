"""Each frame registered to the avatar before the albedo solve reads it.

The albedo solve (albedo_solve.py) reads each pixel's colour at the texel the fitted surface puts
under it. Where the fitted surface is off by a pixel or two (a finger a little thin or turned, the
sides of the hand seen at a grazing angle), the colours of one side of an edge in the skin land on
texels of the other, differently in each frame, and the solve averages them into a blurred edge:
on the phone-like clip three quarters of the albedo's error lies within 3 texels of the boundary
between the palm's light skin and the back's dark skin (docs/fidelity.md).

So each frame is warped, before the solve reads it, onto what the avatar shows there: a smooth
field of image offsets per frame, bilinear between control points GRID_SPACING pixels apart over
the frame's hand, each at most MAX_SHIFT pixels, found by Gauss-Newton on

    sum over the frame's pixels p of rho(|F(p + d(p)) - A(p)|^2) + SMOOTHNESS |grad d|^2 + STAY |d|^2

F the frame's colours (in the solve's units), A the colour the avatar predicts at p for the
current albedo, rho a Cauchy weight against the frame's median residual; then the solve reads
F(p + d(p)) in place of F(p) (Zhou and Koltun's non-rigid correction for colour maps, 2014, on a
coarse grid). Where the skin is plain the data say nothing and the field stays near zero; at an
edge in the albedo or the shading it moves the frame's edge onto the avatar's. A pixel whose
shifted place leaves the frame's mask is dropped (it would read the background). The solve then
alternates: albedo from the registered frames, frames registered again to that albedo (ROUNDS).
"""
from __future__ import annotations

import dataclasses

import torch

from ..formats.colour_model import srgb_to_linear

GRID_SPACING = 16 / 448   # control points' spacing, as a fraction of the frame's long side (16 px at 448)
MAX_SHIFT = 2.0           # pixels at the solve's resolution (scaled with it from 448)
SMOOTHNESS = 1.0          # the field's pull between neighbouring control points, against the mean data weight
STAY = 0.05               # its pull towards no shift, likewise
OUTLIER_SCALE = 3.0       # residuals beyond this many of the frame's typical ones lose weight (Cauchy)
GAUSS_NEWTON_STEPS = 3
ROUNDS = 2                # registrations, each followed by a solve, before the solve's reweighting


@dataclasses.dataclass
class FrameFields:
    """The registration's offsets: per frame (index into the observations' frames), the control
    grid's origin (y, x) and spacing in pixels and its (Gy, Gx, 2) offsets (dy, dx)."""
    origins: dict
    spacing: float
    offsets: dict

    def largest_shift(self) -> float:
        return max((float(field.norm(dim=-1).max()) for field in self.offsets.values()), default=0.0)


def frame_colours(problem, frame, gain=None):
    """(H, W, 3) the frame's colours in the solve's units: as recorded, or in the linear colour model
    decoded from sRGB over the exposure gain `gain` (3,) (albedo_solve._observations)."""
    image = problem.clip.images[frame]
    if problem.avatar.linear_light:
        image = srgb_to_linear(image / (1.0 if gain is None else gain))
    return image


def _bilinear(image, points):
    """(N, C) the image (H, W, C) read at `points` (N, 2) (y, x) pixel coordinates (pixel centres at
    integers), held at the border."""
    height, width = image.shape[:2]
    grid = torch.stack([points[:, 1] / max(width - 1, 1), points[:, 0] / max(height - 1, 1)], -1) * 2 - 1
    sampled = torch.nn.functional.grid_sample(image.permute(2, 0, 1)[None], grid[None, None].to(image.dtype),
                                              mode="bilinear", padding_mode="border", align_corners=True)
    return sampled[0, :, 0].t()


def _gradients(image):
    """(H, W, C, 2) central differences of the image (H, W, C) along y and x (one-sided at the border)."""
    dy = torch.zeros_like(image)
    dx = torch.zeros_like(image)
    dy[1:-1] = (image[2:] - image[:-2]) / 2
    dy[0], dy[-1] = image[1] - image[0], image[-1] - image[-2]
    dx[:, 1:-1] = (image[:, 2:] - image[:, :-2]) / 2
    dx[:, 0], dx[:, -1] = image[:, 1] - image[:, 0], image[:, -1] - image[:, -2]
    return torch.stack([dy, dx], -1)


def _control_weights(pixels, origin, spacing, shape):
    """((N, 4) flat control-point indices, (N, 4) bilinear weights) of `pixels` (N, 2) on a grid of
    `shape` (Gy, Gx) control points `spacing` pixels apart from `origin` (2,)."""
    position = (pixels - origin) / spacing
    rows = position[:, 0].floor().clamp(0, shape[0] - 2)
    columns = position[:, 1].floor().clamp(0, shape[1] - 2)
    fy = (position[:, 0] - rows).clamp(0, 1)
    fx = (position[:, 1] - columns).clamp(0, 1)
    rows, columns = rows.long(), columns.long()
    top_left = rows * shape[1] + columns
    indices = torch.stack([top_left, top_left + 1, top_left + shape[1], top_left + shape[1] + 1], 1)
    weights = torch.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx], 1)
    return indices, weights


def _grid_laplacian_matrix(shape, dtype, device):
    """(K, K) the graph Laplacian of a (Gy, Gx) grid's 4-neighbours (the Hessian of half the sum of
    squared differences between neighbours)."""
    count = shape[0] * shape[1]
    index = torch.arange(count, device=device).view(shape)
    pairs = torch.cat([torch.stack([index[:, :-1].flatten(), index[:, 1:].flatten()], 1),
                       torch.stack([index[:-1].flatten(), index[1:].flatten()], 1)])
    matrix = torch.zeros(count, count, dtype=dtype, device=device)
    matrix.index_put_((pairs[:, 0], pairs[:, 1]), torch.tensor(-1.0, dtype=dtype, device=device), accumulate=True)
    matrix.index_put_((pairs[:, 1], pairs[:, 0]), torch.tensor(-1.0, dtype=dtype, device=device), accumulate=True)
    degree = -matrix.sum(1)
    return matrix + torch.diag(degree)


def frame_field(colours, pixels, predicted, spacing, max_shift, steps=GAUSS_NEWTON_STEPS):
    """(origin (2,), (Gy, Gx, 2) offsets) registering one frame: `colours` (H, W, 3) its colours in the
    solve's units, `pixels` (N, 2) the (y, x) of its observed pixels, `predicted` (N, 3) what the avatar
    shows there (as the frame's colours would read after the solve's own corrections). The module's
    docstring has the energy."""
    dtype, device = colours.dtype, colours.device
    low, high = pixels.min(0).values - spacing, pixels.max(0).values + spacing
    shape = tuple(int(n) for n in ((high - low) / spacing).ceil().long() + 1)
    count = shape[0] * shape[1]
    indices, weights = _control_weights(pixels, low, spacing, shape)
    gradients = _gradients(colours)
    laplacian = _grid_laplacian_matrix(shape, dtype, device)
    offsets = torch.zeros(count, 2, dtype=dtype, device=device)
    for _ in range(steps):
        shift = (weights[:, :, None] * offsets[indices]).sum(1)
        places = pixels + shift
        residual = _bilinear(colours, places) - predicted                      # (N, 3)
        slope = _bilinear(gradients.flatten(2), places).view(-1, 3, 2)           # (N, 3, 2): d colour / d (y, x)
        squared = residual.square().sum(1)
        robust = 1 / (1 + squared / (OUTLIER_SCALE ** 2 * squared.median().clamp(min=1e-8)))
        # normal equations over the control points' (dy, dx): J = w_k slope per pixel and channel
        pixel_hessian = torch.einsum("nca,ncb->nab", slope, slope) * robust[:, None, None]   # (N, 2, 2)
        pixel_gradient = torch.einsum("nca,nc->na", slope, residual) * robust[:, None]                      # (N, 2)
        hessian = torch.zeros(count, count, 2, 2, dtype=dtype, device=device)
        pair_weights = weights[:, :, None] * weights[:, None, :]                                        # (N, 4, 4)
        rows = indices[:, :, None].expand(-1, 4, 4).flatten()
        columns = indices[:, None, :].expand(-1, 4, 4).flatten()
        hessian.index_put_((rows, columns), (pair_weights.flatten()[:, None, None]
                                             * pixel_hessian.repeat_interleave(16, 0)), accumulate=True)
        gradient = torch.zeros(count, 2, dtype=dtype, device=device)
        gradient.index_add_(0, indices.flatten(), (weights[:, :, None] * pixel_gradient[:, None, :]).reshape(-1, 2))
        hessian = hessian.permute(0, 2, 1, 3).reshape(2 * count, 2 * count)      # unknowns ordered (k, axis)
        data_weight = hessian.diagonal().mean().clamp(min=1e-12)
        regulariser = torch.kron(SMOOTHNESS * laplacian + STAY * torch.eye(count, dtype=dtype, device=device),
                                 torch.eye(2, dtype=dtype, device=device)) * data_weight
        total = hessian + regulariser
        rhs = -(gradient.flatten() + regulariser @ offsets.flatten())
        step = torch.linalg.solve(total, rhs).view(count, 2)
        offsets = offsets + step
        length = offsets.norm(dim=1, keepdim=True)
        offsets = offsets * (max_shift / length.clamp(min=max_shift))                # at most max_shift pixels
    return low, offsets.view(*shape, 2)


def shifted_places(pixels, origin, spacing, field):
    """(N, 2) where the pixels (N, 2) read their colour under the frame's field."""
    indices, weights = _control_weights(pixels, origin, spacing, field.shape[:2])
    return pixels + (weights[:, :, None] * field.view(-1, 2)[indices]).sum(1)


def still_inside(inside, places):
    """(N,) bool: the shifted places whose four nearest pixels are all inside the mask (H, W)."""
    return _bilinear(inside[..., None].to(places.dtype), places)[:, 0] > 0.999


@torch.no_grad()
def registered_observations(problem, seen, albedo):
    """(the albedo solve's observations `seen` with each frame's colours read through its field
    registering it to what the avatar shows for `albedo` (3, T, T) in the solve's units, a pixel
    whose shifted place leaves the solve's mask dropped; the FrameFields). `seen` must come from
    these frames unregistered (albedo_solve._observations): each call registers afresh."""
    avatar, clip = problem.avatar, problem.clip
    long_side = max(clip.height, clip.width)
    spacing, max_shift = GRID_SPACING * long_side, MAX_SHIFT * long_side / 448
    predicted = seen.predicted(albedo)
    colour = seen.colour.clone()
    keep = torch.ones(len(colour), dtype=torch.bool, device=colour.device)
    fields = FrameFields({}, spacing, {})
    for frame in seen.frame.unique().tolist():
        rows = (seen.frame == frame).nonzero()[:, 0]
        gain = avatar.exposure_gain(torch.tensor([frame], device=colour.device))[0, 0, 0] \
            if problem.exposure_on else None
        colours = frame_colours(problem, frame, gain)
        pixels = seen.place[rows]
        # what the frame reads at the pixel itself less what the solve reads there: the lobe's sheen
        # (albedo_solve._observations takes it off), held at the pixel
        sheen = _bilinear(colours, pixels) - seen.colour[rows]
        origin, field = frame_field(colours, pixels, predicted[rows] + sheen, spacing, max_shift)
        places = shifted_places(pixels, origin, spacing, field)
        colour[rows] = _bilinear(colours, places) - sheen
        keep[rows] = still_inside(clip.masks[frame, ..., 0] > 0.5, places)
        fields.origins[frame], fields.offsets[frame] = origin, field
    return dataclasses.replace(seen, colour=colour).subset(keep), fields
