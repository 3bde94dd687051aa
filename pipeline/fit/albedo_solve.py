"""The final albedo, solved from the frames.

Adam moves a texel only by the gradients of the few pixels that show it in a batch, against a
texture regulariser that every texel feels every step: the appearance stage settles a smoothed
albedo, and a tattoo the clip shows sharply comes out a smear (sharpness ratio 0.27 on the demo
clip, evaluate/fidelity.py). Once the geometry and the light are final, the albedo that best
explains the frames is a linear least-squares problem, and it is solved directly; the
appearance stage's albedo stays where the frames say too little.

Every pixel of a fitted frame on the visible surface inside the eroded mask gives one equation
per channel: I = S * bilinear(albedo, uv), I the frame's colour, S what the renderer shows there
for an albedo of 1 (light, ambient ratio, shadows, normal map, exposure gain), bilinear() the
renderer's own texture lookup (render/texture.py) at the pixel's UV: four texels and their
weights. The normal equations couple each texel with its eight neighbours only, so they are
gathered as a 3 x 3 stencil per texel and solved by conjugate gradients, with a weak pull
(SMOOTHNESS) between neighbouring texels and a weaker one (ANCHOR) towards the current albedo
for the texels the frames barely decide. Texels with less than MIN_COVERAGE of bilinear weight
from the frames keep the value the fit gave them.

Off by default (`harp fit --solve-albedo`, FitSettings.solve_albedo): under a hard sun the solve
also fits, texel by texel, what the renderer does not model (soft shadow edges, real skin), and
blotches appear (docs/fidelity.md).
"""
from __future__ import annotations

import dataclasses

import torch

from ..render.renderer import render
from ..render.texture import bilinear_texels
from .losses import eroded_mask

MIN_COVERAGE = 1.0      # bilinear weight (about one pixel's worth) a texel needs to be solved
MIN_SHADING = 0.05      # pixels darker than this (shading of an albedo of 1) carry no colour
MASK_EROSION = 2        # pixels, as the photometric term's
SMOOTHNESS = 1e-2       # neighbour pull, against the mean data weight of a solved texel
ANCHOR = 1e-4           # pull towards the current albedo, likewise
CG_ITERATIONS = 300
# the 3 x 3 stencil: offsets (row, column) to the neighbours a texel's equations couple it with
STENCIL = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]


@torch.no_grad()
def solved_albedo(problem, shadows, batch_size=4):
    """((3, T, T) albedo in [0, 1] that explains the problem's frames best with its avatar's
    current geometry, light and exposure gains, (T, T) bool: texels the frames decide)."""
    avatar, clip = problem.avatar, problem.clip
    current = avatar.albedo.detach().clamp(0, 1)
    size = current.shape[-1]
    system = _NormalEquations(size, current.dtype, current.device)
    appearance = dataclasses.replace(avatar.appearance(), albedo=torch.ones_like(current))
    light = avatar.light(shadows)
    for batch in torch.arange(len(problem.frames), device=current.device).split(batch_size):
        vertices, _ = avatar.posed(batch)
        images = render(vertices, avatar.mesh, clip.K, clip.height, clip.width, outputs=("rgb", "uv", "alpha"),
                        appearance=appearance, light=light, antialiased=False)
        shading = images["rgb"] * avatar.exposure_gain(batch) if problem.exposure_on else images["rgb"]
        usable = (eroded_mask(clip.masks[batch], MASK_EROSION)[..., 0] > 0.5) & (images["alpha"][..., 0] > 0.5)
        if clip.valid is not None:
            usable = usable & (clip.valid[..., 0] > 0.5)
        usable = usable & (shading.min(-1).values > MIN_SHADING)
        system.add(images["uv"][usable], shading[usable], clip.images[batch][usable])
    return system.solve(current)


class _NormalEquations:
    """sum over pixels of (S * sum_i w_i a_(k_i) - I)^2, per channel, as a 9-point stencil per
    texel (matrix) and a right-hand side, plus each texel's bilinear weight (coverage)."""

    def __init__(self, size, dtype, device):
        self.size = size
        self.matrix = torch.zeros(3, size * size * len(STENCIL), dtype=dtype, device=device)
        self.rhs = torch.zeros(3, size * size, dtype=dtype, device=device)
        self.coverage = torch.zeros(size * size, dtype=dtype, device=device)

    def add(self, uv, shading, colour):
        """Pixels' UVs (N, 2), shading (N, 3) and colours (N, 3)."""
        rows, columns, weights = bilinear_texels(uv, self.size)
        for i in range(4):
            texel = rows[:, i] * self.size + columns[:, i]
            self.rhs.index_add_(1, texel, (shading * colour * weights[:, i, None]).t())
            self.coverage.index_add_(0, texel, weights[:, i])
            for j in range(4):
                place = (rows[:, j] - rows[:, i] + 1) * 3 + (columns[:, j] - columns[:, i] + 1)
                self.matrix.index_add_(1, texel * len(STENCIL) + place,
                                       (shading * shading * (weights[:, i] * weights[:, j])[:, None]).t())

    def solve(self, start):
        """(albedo (3, T, T), solved (T, T) bool): conjugate gradients from `start`."""
        size = self.size
        matrix = self.matrix.view(3, size, size, len(STENCIL))
        solved = self.coverage.view(size, size) >= MIN_COVERAGE
        if not solved.any():
            return start.clone(), solved
        data_weight = matrix[..., STENCIL.index((0, 0))].mean(0)[solved].mean()
        smoothness, anchor = SMOOTHNESS * data_weight, ANCHOR * data_weight

        def apply(albedo):
            padded = torch.nn.functional.pad(albedo, (1, 1, 1, 1))
            result = anchor * albedo
            for index, (dy, dx) in enumerate(STENCIL):
                result = result + matrix[..., index] * padded[:, 1 + dy:1 + dy + size, 1 + dx:1 + dx + size]
            return result + smoothness * _grid_laplacian(albedo)

        rhs = self.rhs.view(3, size, size) + anchor * start
        diagonal = matrix[..., STENCIL.index((0, 0))] + anchor + 4 * smoothness
        albedo = _conjugate_gradients(apply, rhs, start.clone(), 1 / diagonal, CG_ITERATIONS)
        return albedo.clamp(0, 1), solved


def _grid_laplacian(images):
    """Sum over the 4-neighbours inside the grid of (value - neighbour): the gradient of half
    the squared differences between neighbouring texels. images (C, T, T)."""
    result = torch.zeros_like(images)
    for axis in (1, 2):
        difference = images.diff(dim=axis)
        result.narrow(axis, 0, images.shape[axis] - 1).sub_(difference)
        result.narrow(axis, 1, images.shape[axis] - 1).add_(difference)
    return result


def _conjugate_gradients(apply, rhs, x, inverse_diagonal, iterations, tolerance=1e-6):
    """Jacobi-preconditioned conjugate gradients on each channel's symmetric positive system."""
    residual = rhs - apply(x)
    z = residual * inverse_diagonal
    direction = z.clone()
    rz = (residual * z).flatten(1).sum(1)
    scale = rhs.flatten(1).norm(dim=1).clamp(min=1e-12)
    for _ in range(iterations):
        product = apply(direction)
        step = rz / (direction * product).flatten(1).sum(1).clamp(min=1e-30)
        x = x + step[:, None, None] * direction
        residual = residual - step[:, None, None] * product
        if (residual.flatten(1).norm(dim=1) / scale).max() < tolerance:
            break
        z = residual * inverse_diagonal
        rz_next = (residual * z).flatten(1).sum(1)
        direction = z + (rz_next / rz.clamp(min=1e-30))[:, None, None] * direction
        rz = rz_next
    return x


def solve_avatar_albedo(problem, shadows) -> dict:
    """Replace the avatar's albedo by the solved one where the frames decide it (in place);
    returns the share of the UV charts solved and the mean change there."""
    albedo, solved = solved_albedo(problem, shadows)
    solved = solved & (problem.uv_mask.to(solved.device) > 0)
    with torch.no_grad():
        change = (albedo - problem.avatar.albedo.clamp(0, 1)).abs().mean(0)[solved]
        problem.avatar.albedo.copy_(torch.where(solved[None], albedo, problem.avatar.albedo))
    return {"solved_fraction": float(solved.sum() / (problem.uv_mask > 0).sum().clamp(min=1)),
            "mean_change": float(change.mean()) if change.numel() else 0.0}
