"""The final albedo, solved from the frames.

Adam moves a texel only by the gradients of the few pixels that show it in a batch, against a
texture regulariser that every texel feels every step: the appearance stage settles a smoothed
albedo, and a tattoo the clip shows sharply comes out a smear (sharpness ratio 0.27 on the demo
clip, evaluate/fidelity.py). Once the geometry and the light are final, the albedo that best
explains the frames is a linear least-squares problem, and it is solved directly; the
appearance stage's albedo stays where the frames say too little.

Every pixel of a fitted frame on the visible surface inside the eroded mask (eroded by
losses.ALBEDO_SOLVE_EROSION, a pixel less than the photometric term) gives one equation
per channel: I = S * bilinear(albedo, uv), I the frame's colour, S what the renderer shows there
for an albedo of 1 (light, ambient ratio, shadows, normal map, exposure gain), bilinear() the
renderer's own texture lookup (render/texture.py) at the pixel's UV: four texels and their
weights. The normal equations couple each texel with its eight neighbours only, so they are
gathered as a 3 x 3 stencil per texel and solved by conjugate gradients, with a pull between
neighbouring texels as strong as the frames' noise asks (neighbour_pull). Texels with less than
MIN_COVERAGE of bilinear weight from the frames keep the value the fit gave them.

The frames also show what the renderer does not model (under a hard sun: shadow edges in other
places, real skin's highlights). Solved pixel by pixel alike, that is baked into the albedo as
blotches (sharpness 3.6 times the truth's on a sun clip). So the solve is reweighted
(solved_albedo): outlier pixels, texels the frames disagree on and texels few pixels show lean
on the appearance stage's albedo, clean and well-seen texels follow the frames.

With an environment light (formats/environment_light.py) the shading is S = S0 + g Y(n) c: the
point light's part S0, the exposure gain g, the harmonics Y at each pixel's shading normal and
the coefficients c. For a fixed albedo, c is a linear least-squares problem of 8 unknowns per
colour over every pixel; the solve alternates the two (ENVIRONMENT_ROUNDS), so that a texel's
albedo cannot take up the light's change across the frames that show it, as it can under Adam
(the appearance stage moves both by small steps).

With `FitSettings.albedo_facing` "on", each pixel's equations weigh by how squarely it sees the
surface, the cosine between the surface normal and the ray to the camera (`_facing`): a texel seen
head-on in one frame and at a grazing angle in another takes its colour from the first, where the
pixel covers the least skin and the rim's light (Fresnel sheen, subsurface glow, the mask's edge)
counts least; a texel only ever seen at grazing angles still takes theirs.

With `FitSettings.albedo_openness` "on" (the default), each pixel's equations also weigh by how much
of the room its surface sees (`openness`): fully where the hand hides less than OPEN_UP_TO of the
room's cosine-weighted light from it (O_0 of render/occlusion.py), not at all from ENCLOSED_FROM
on, linearly between. Inside a closing fist or between pressed fingers most of a point's light is
what the skin around it sends back, which the renderer models as one constant bounce at best; a
real clip that opens on a fist put the fist's hollows into the fingers' palm side as dark purple
patches (docs/fidelity.md). Texels only such pixels show are left to the fill (decided_texels
weighs the same way).

The specular lobe (formats/specular_lobe.py) adds a white sheen that does not scale with the
albedo: I = S * albedo + g P, P the lobe's share at the pixel. Its part g P, fixed by the fitted
geometry, light and lobe, is taken off each pixel's colour before the solve.
docs/fidelity.md has the figures.
"""
from __future__ import annotations

import dataclasses

import torch

from ..formats.colour_model import linear_to_srgb, srgb_to_linear
from ..formats.environment_light import relative_strength
from ..handmodel.digit_coordinates import smoothstep
from ..render.rasterize import pixel_rays
from ..render.renderer import falloff_reach, lobe_colour, render
from ..render.shading import environment_basis_values, sphere_radiance_basis
from ..render.texture import bilinear_texels

MIN_COVERAGE = 1.0      # bilinear weight (about one pixel's worth) a texel needs to be solved
# texel_trust: a pixel sees its skin edge-on at a facing (_facing) below FACING_GRAZING, squarely from
# FACING_SQUARE on; a texel is kept as solved where squarely seen pixels give at least SQUARE_SHARE of its weight
FACING_GRAZING, FACING_SQUARE = 0.15, 0.5
SQUARE_SHARE = 0.5
MIN_SHADING = 0.05      # pixels darker than this (shading of an albedo of 1) carry no colour
OPEN_UP_TO = 0.15       # FitSettings.albedo_openness: a pixel whose surface the hand hides this share of the
ENCLOSED_FROM = 0.35    # room from weighs fully; from this share on, not at all (openness)
# the pull between neighbouring texels, against the mean data weight of a solved texel: the first solve's (and the
# environment rounds'), then the frames' noise over ALBEDO_STEP_VARIANCE (neighbour_pull), within PULL_RANGE
FIRST_PULL = 1e-2
ALBEDO_STEP_VARIANCE = 2.7e-3   # the least expected squared albedo step between neighbouring texels (skin's): the demo
#                                 clip's noise over it gives the demo its best pull, 1e-2
PULL_RANGE = (1e-4, 1e-1)
ANCHOR = 1e-4           # the first solve's pull towards the current albedo, likewise
WELL_SEEN = 8.0         # coverage of the texels that measure how far off the current albedo is
PRIOR_COUNT = 4.0       # a texel's noise variance: the clip's, worth this many pixels, and its own
OUTLIER_SCALE = 3.0     # residuals beyond this many of the clip's noise standard deviations lose weight
REWEIGHTINGS = 3        # weighted solves after the first
NOISE_FLOOR = 0.02      # the least noise (standard deviation) a pixel's colour is taken to have
CG_ITERATIONS = 300
SOLVE_BATCH = 4         # frames rendered at once to gather the observations
PIXEL_CHUNK = 1 << 18   # pixels gathered into the normal equations at once (about 50 MB of temporaries)
ENVIRONMENT_ROUNDS = 4  # alternations of the environment light's solve and the albedo's before the reweighting
ENVIRONMENT_RIDGE = 1e-3   # the environment solve's pull towards a uniform room, against its mean diagonal
ENVIRONMENT_STIFFNESS = 1e4   # its hold on the world's radiance at or above 0, likewise (least_squares_above)
# the 3 x 3 stencil: offsets (row, column) to the neighbours a texel's equations couple it with
STENCIL = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
# a bilinear cell's distinct pairs (i, j), i <= j, of its four texels, and for each ordered pair in row-major order
# of (i, j) the index of its distinct pair
PAIRS = [(i, j) for i in range(4) for j in range(i, 4)]
PAIR_OF_ORDERED = [PAIRS.index((min(i, j), max(i, j))) for i in range(4) for j in range(4)]


@dataclasses.dataclass
class _Observations:
    """Every usable pixel of the fitted frames: its four texels (flat int32 indices (N, 4)) and
    bilinear weights (N, 4), its shading (N, 3) and colour (N, 3); with an environment light,
    also the shading without it (N, 3, exposure gain included), the gain (N, 3) and the
    harmonics at the pixel's shading normal (N, 8); with FitSettings.albedo_facing on, how
    squarely each pixel sees the surface (N,) in [0, 1] (_facing); where the solve weighs openness
    (solve_avatar_albedo with FitSettings.albedo_openness on), how much of the room it sees (N,) in
    (0, 1] (openness)."""
    texels: torch.Tensor
    weights: torch.Tensor
    shading: torch.Tensor
    colour: torch.Tensor
    base: torch.Tensor | None = None
    gain: torch.Tensor | None = None
    basis: torch.Tensor | None = None
    facing: torch.Tensor | None = None
    openness: torch.Tensor | None = None

    def pixel_weights(self, weights=None):
        """(N,) the solve's weight of each pixel: `weights` (default 1) times its facing and its
        openness, where they are on."""
        weights = torch.ones_like(self.shading[:, 0]) if weights is None else weights
        for factor in (self.facing, self.openness):
            weights = weights if factor is None else weights * factor
        return weights

    def albedo_at(self, albedo):
        """(N, 3) the albedo each pixel sees (bilinear, as the renderer) for a (3, T, T) albedo."""
        return (albedo.flatten(1)[:, self.texels] * self.weights).sum(-1).t()

    def predicted(self, albedo):
        """(N, 3) the colour each pixel shows for a (3, T, T) albedo."""
        return self.shading * self.albedo_at(albedo)

    def under_environment(self, coefficients):
        """These observations with the shading of the environment light `coefficients` (8, 3)."""
        return dataclasses.replace(self, shading=self.base + self.gain * (self.basis @ coefficients))


@torch.no_grad()
def solved_albedo(problem, shadows, batch_size=SOLVE_BATCH, supersample=1, frames=None, solve_environment=True,
                  weigh_openness=False):
    """((3, T, T) albedo in [0, 1] that explains the problem's frames best with its avatar's
    current geometry, light and exposure gains, (T, T) bool: texels the frames decide).

    Iteratively reweighted least squares, with the current albedo as the prior: a first solve
    with every pixel alike and a weak pull (ANCHOR); then REWEIGHTINGS times, from the last
    solve's residuals: each pixel loses weight where it is an outlier against the clip's noise
    (Cauchy, OUTLIER_SCALE) and is weighted by the inverse noise variance of its texels (each
    texel's from its pixels' residuals, pooled with the clip's, PRIOR_COUNT pixels' worth); the
    current albedo is weighted by the clip's noise over its own error where the first solve is
    well decided (WELL_SEEN); and the albedo is solved again. Texels whose frames
    disagree (what the renderer does not model: a shadow edge in the wrong place, a highlight)
    or that few pixels show lean on the current albedo; clean, well-seen texels follow the
    frames.

    `supersample` > 1 solves a texture that many times finer (the current albedo enlarged as its
    prior) and returns its area average at the avatar's size: detail finer than a texel then
    explains the pixels instead of reading as their disagreement. `frames` (indices into the fitted
    frames, default all) are the frames read; `solve_environment` False holds the room light as it
    stands (else it is solved with the albedo, and what it became is not kept). `weigh_openness`:
    each pixel weighed by its openness (solve_avatar_albedo's, where FitSettings.albedo_openness is
    on); without it, as the light's decisions (light_probe.py) score each light, every pixel alike,
    the hollows' too: a light that shadows them must be judged by them."""
    current = problem.avatar.albedo.detach().clamp(0, 1)
    if supersample > 1:
        finer = torch.nn.functional.interpolate(current[None], scale_factor=supersample, mode="bilinear",
                                                align_corners=False)[0]
        albedo, solved, *_ = _solved(problem, shadows, batch_size, finer, solve_environment, frames, weigh_openness)
        albedo = torch.nn.functional.avg_pool2d(albedo[None], supersample)[0]
        solved = torch.nn.functional.max_pool2d(solved[None, None].float(), supersample)[0, 0] > 0
        return albedo, solved
    return _solved(problem, shadows, batch_size, current, solve_environment, frames, weigh_openness)[:2]


def _solved(problem, shadows, batch_size, current, solve_environment=True, frames=None, weigh_openness=False):
    """(albedo, solved, environment coefficients (8, 3) or None when the light has none, the
    reweighted solves' neighbour pull or None when no pixel was usable). In the linear colour model
    the albedo is solved in linear light and returned sRGB-encoded, as the avatar keeps it."""
    linear = problem.avatar.linear_light
    albedo, solved, environment, pull = _solved_in_shading_space(problem, shadows, batch_size,
                                                                 srgb_to_linear(current) if linear else current,
                                                                 solve_environment, frames, weigh_openness)
    return (linear_to_srgb(albedo.clamp(0, 1)) if linear else albedo), solved, environment, pull


def _solved_in_shading_space(problem, shadows, batch_size, current, solve_environment, frames=None,
                             weigh_openness=False):
    size = current.shape[-1]
    seen = _observations(problem, shadows, batch_size, size, frames, weigh_openness)
    environment = problem.avatar.light().environment
    environment = None if environment is None else environment.detach().clone()
    light_solved = environment is not None and solve_environment   # else the observations' shading holds it
    ambient = problem.avatar.ambient.item()
    if not len(seen.colour):                       # no frame shows a usable pixel of the hand
        return current.clone(), torch.zeros(current.shape[1:], dtype=torch.bool, device=current.device), \
            environment, None
    uniform = seen.pixel_weights()
    first = _NormalEquations(size, seen, uniform)
    albedo, solved = first.solve(current, ANCHOR * first.data_weight(), FIRST_PULL)
    if light_solved:
        for _ in range(ENVIRONMENT_ROUNDS):
            environment = _solved_environment(seen, albedo, uniform, ambient)
            seen = seen.under_environment(environment)
            first = _NormalEquations(size, seen, uniform)
            albedo, solved = first.solve(current, ANCHOR * first.data_weight(), FIRST_PULL, start=albedo)
    prior, pull = None, None
    for _ in range(REWEIGHTINGS):
        weights, clip_variance, noise = _consistency_weights(seen, albedo, size)
        pull = neighbour_pull(noise, albedo, first) if pull is None else pull
        weights = seen.pixel_weights(weights)
        if light_solved:
            environment = _solved_environment(seen, albedo, weights, ambient)
            seen = seen.under_environment(environment)
        prior = _prior_weight(seen, first.coverage, albedo, current, clip_variance) if prior is None else prior
        albedo, solved = _NormalEquations(size, seen, weights).solve(current, prior, pull, start=albedo)
    return albedo, solved, environment, pull


def neighbour_pull(noise, albedo, equations) -> float:
    """The reweighted solves' pull between neighbouring texels, against the mean data weight of a
    solved texel: the frames' `noise` (the median over the pixels of the squared residual of
    `albedo`, per channel: _consistency_weights) over the albedo's expected squared step between
    neighbouring texels, per unit of the data weight of `equations` (the _NormalEquations `albedo`
    was solved from): the most
    probable albedo under Gaussian pixel noise and a Gaussian prior on the steps. The expected step:
    `albedo`'s own mean squared step over the solved texels (ink, a tattoo, creases) or skin's,
    ALBEDO_STEP_VARIANCE, whichever is more. Within PULL_RANGE. Clean frames, or more pixels on each
    texel, pull less: the detail they hold is measured, not noise. The phone-like clip's finer solve
    (873 px frames, 74 pixels on a texel) gets about 4e-4 (a fixed 1e-2 blurred the albedo its frames
    hold to 0.61 of its sharpness, 1e-3 to 0.81; 1e-3 and 3e-4 replayed alike); the demo clip (256 px,
    noisier, 27 pixels on a texel) 1e-2, where 2.7e-3 and 1e-3 took its noise in; a ringed albedo under
    a camera's noise 3.5e-3 (tests/test_albedo_solve.py; docs/fidelity.md, "The neighbour pull from the
    frames' noise")."""
    data_weight = equations.data_weight()
    if data_weight <= 0:
        return FIRST_PULL
    steps = max(mean_squared_step(albedo, equations.coverage.view(albedo.shape[1:]) >= MIN_COVERAGE),
                ALBEDO_STEP_VARIANCE)
    low, high = PULL_RANGE
    return min(max(noise / (steps * data_weight), low), high)


def mean_squared_step(albedo, solved) -> float:
    """The mean over channels and over pairs of neighbouring texels both `solved` (T, T) of the
    squared difference of `albedo` (C, T, T); 0 where no pair is."""
    total, pairs = 0.0, 0
    for axis in (0, 1):
        length = solved.shape[axis] - 1
        both = solved.narrow(axis, 0, length) & solved.narrow(axis, 1, length)
        squared = albedo.diff(dim=axis + 1).pow(2).mean(0)
        total, pairs = total + float(squared[both].sum()), pairs + int(both.sum())
    return total / pairs if pairs else 0.0


def _solved_environment(seen, albedo, pixel_weight, ambient):
    """(8, 3) the environment light that explains the observations best for a fixed albedo:
    per colour, weighted least squares over every pixel of I - S0 a = (g a Y) . c, with a ridge
    of ENVIRONMENT_RIDGE of the mean diagonal (a uniform room where the frames say nothing), and
    a world it stands for that is nowhere darker than no light: the radiance a + R(d) . c >= 0
    over the sphere (formats/environment_light.py, `ambient` a the light's ambient ratio). Left
    free, the phone-like clip's rooms came out negative over a quarter of the sphere, which
    Blender's world cannot show (docs/fidelity.md)."""
    at_pixel = seen.albedo_at(albedo)
    world = sphere_radiance_basis(at_pixel.dtype, at_pixel.device)     # (D, 8)
    columns = []
    for channel in range(3):
        design = (seen.gain[:, channel] * at_pixel[:, channel])[:, None] * seen.basis       # (N, 8)
        target = seen.colour[:, channel] - seen.base[:, channel] * at_pixel[:, channel]
        normal = design.t() @ (design * pixel_weight[:, None])
        ridge = ENVIRONMENT_RIDGE * normal.diagonal().mean().clamp(min=1e-12)
        normal = normal + ridge * torch.eye(len(normal), dtype=normal.dtype, device=normal.device)
        columns.append(least_squares_above(normal, design.t() @ (pixel_weight * target), world, -float(ambient)))
    return torch.stack(columns, dim=1)


def least_squares_above(normal, rhs, constraints, floor, stiffness=ENVIRONMENT_STIFFNESS, rounds=50):
    """(K,) x minimising 1/2 x' H x - b' x (H = `normal` (K, K) positive definite, b = `rhs` (K,))
    subject to G x >= floor for the rows of G = `constraints` (D, K). Each row's shortfall is
    penalised by its square, `stiffness` times H's mean diagonal, so that a row is left short by
    about 1 / stiffness of the scale of x; the penalised problem (convex, piecewise quadratic) is
    solved by Newton's method with a backtracking line search. The plain solution where no row is
    in the way."""
    weight = stiffness * normal.diagonal().mean()

    def penalised(x):
        shortfall = (floor - constraints @ x).clamp(min=0)
        return 0.5 * x @ normal @ x - rhs @ x + 0.5 * weight * shortfall.square().sum()

    x = torch.linalg.solve(normal, rhs)
    for _ in range(rounds):
        held = constraints[constraints @ x < floor]
        if not len(held):
            return x
        step = torch.linalg.solve(normal + weight * held.t() @ held, rhs + weight * floor * held.sum(0)) - x
        value, length = penalised(x), 1.0
        while penalised(x + length * step) > value and length > 1e-6:
            length /= 2
        x = x + length * step
        if length == 1.0 and torch.equal(constraints @ x < floor, constraints @ (x - step) < floor):
            return x                                            # the same rows held: the penalised optimum
    return x


def _observations(problem, shadows, batch_size, size, frames=None, weigh_openness=False):
    """The usable pixels of the fitted frames (_Observations; of `frames`, indices into them,
    default all; with `weigh_openness`, each pixel's openness kept, those with none left out). In
    the linear colour model (formats/colour_model.py) the equations hold in linear light: each
    pixel's colour is its frame's value over the exposure gain, decoded from sRGB, and the shading
    is rendered without the encoding (the gain is then 1 in the equations). Weighting each equation
    by the curve's slope at its pixel (residuals in display units) was tried and dropped: the
    deepest shading, which the model explains least well, then weighs most (phone-like clip: albedo
    MAE 0.071 against 0.065, docs/fidelity.md)."""
    avatar, clip = problem.avatar, problem.clip
    appearance = dataclasses.replace(avatar.appearance(), albedo=torch.ones_like(avatar.albedo))
    facing_on = problem.settings.albedo_facing == "on"
    openness_on = weigh_openness
    # the least shading (of an albedo of 1) that carries colour, in the shading's units (the encoding is monotonic)
    darkest = srgb_to_linear(torch.tensor(MIN_SHADING)).item() if avatar.linear_light else MIN_SHADING
    parts = []
    frames = torch.arange(len(problem.frames)) if frames is None else torch.as_tensor(frames, dtype=torch.long)
    for batch in frames.to(avatar.albedo.device).split(batch_size):
        vertices, _ = avatar.posed(batch)
        light = avatar.light(shadows, batch, vertices)
        environment, specular, linear = light.environment, light.specular, light.linear
        light = dataclasses.replace(light, linear=False)
        occluded = environment is not None and light.occlusion is not None
        lobe_lost = specular is not None and light.occlusion is not None   # the lobe's room sheen less the lost share
        outputs = ("rgb", "uv", "alpha") + (() if environment is None and specular is None else ("shading_normal",)) \
            + (("lost_light",) if occluded or lobe_lost else ()) + (("normal",) if facing_on else ()) \
            + (() if specular is None else ("position", "light_visibility")) + (("vertex_values",) if openness_on else ())
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=outputs,
                        appearance=appearance, light=dataclasses.replace(light, environment=None, specular=None),
                        antialiased=False,
                        vertex_values=_room_hidden(avatar, batch, vertices) if openness_on else None)
        # the pixels of the mask that the surface covers, each from here on a row (a fifth of the image or less)
        usable = problem.colour_pixels(batch, albedo_solve=True) & (images["alpha"][..., 0] > 0.5)
        gain = avatar.exposure_gain(batch) if problem.exposure_on else torch.ones_like(avatar.exposure_gain(batch))
        gain = gain.expand_as(images["rgb"])[usable]
        colour = clip.images[batch][usable]
        if linear:   # I = g encode(S a + P): decode(I / g) = S a + P
            colour, gain = srgb_to_linear(colour / gain), torch.ones_like(gain)
        base = images["rgb"][usable] * gain
        basis = None
        shading = base
        if environment is not None:
            basis = environment_basis_values(images["shading_normal"][usable])
            if occluded:   # the harmonics' light less what the hand keeps from the point (render/occlusion.py)
                basis = basis - images["lost_light"][usable][..., 1:]
            shading = base + gain * (basis @ environment)
        bright = shading.min(-1).values > darkest
        if openness_on:
            open_share = openness(images["vertex_values"][usable][:, 0])
            bright = bright & (open_share > 0)
        if specular is not None:
            # the lobe's highlight and its sheen of the room (at the light's environment as it stands: the
            # environment solve below does not move it), from this render's surface at the usable pixels (a
            # second render of the lobe alone took 9 s of a 150-frame clip's 448 px solve)
            reach = falloff_reach(light, vertices)
            frame = usable.nonzero()[:, 0]
            sheen = lobe_colour(images["shading_normal"][usable], images["position"][usable], light, frame,
                                images["light_visibility"][usable], images["lost_light"][usable] if lobe_lost else None,
                                None if reach is None else reach[frame])
            colour = colour - gain * sheen
        facing = _facing(images["normal"], clip.K[batch])[usable][bright] if facing_on else None
        parts.append((images["uv"][usable][bright], shading[bright], colour[bright])
                     + ((facing,) if facing_on else ()) + ((open_share[bright],) if openness_on else ())
                     + (() if environment is None else (base[bright], gain[bright], basis[bright])))
    uv, shading, colour, *rest = (torch.cat(column) for column in zip(*parts))
    facing = rest.pop(0) if facing_on else None
    open_share = rest.pop(0) if openness_on else None
    rows, columns, weights = bilinear_texels(uv, size)
    texels = (rows * size + columns).to(torch.int32)    # int32: memory
    return _Observations(texels, weights, shading, colour, *rest, facing=facing, openness=open_share)


def openness(hidden):
    """The solve's weight of pixels whose surface the hand hides the share `hidden` (O_0 of
    render/occlusion.py: cosine-weighted, 0 in the open, 1 enclosed) of the room from: 1 up to
    OPEN_UP_TO, 0 from ENCLOSED_FROM, linear between."""
    return ((ENCLOSED_FROM - hidden) / (ENCLOSED_FROM - OPEN_UP_TO)).clamp(0.0, 1.0)


def _room_hidden(avatar, batch, vertices):
    """(B, V, 1) O_0 at each vertex of the frames `batch` posed as `vertices`: the avatar's own
    measurement of the room light's occlusion (Avatar.room_occlusion, kept per frame), whether the
    fit shades with it or not."""
    return avatar.room_occlusion(batch, vertices)[..., :1]


def stencil_places(texels, size):
    """(N, 16) uint8: for a pixel's four texels `texels` (N, 4) (flat indices into a size x size
    grid) and each pair (i, j) of them, in row-major order of (i, j), the index in STENCIL of
    texel j's offset from texel i."""
    rows, columns = texels // size, texels % size
    places = (rows[:, None, :] - rows[:, :, None] + 1) * 3 + (columns[:, None, :] - columns[:, :, None] + 1)
    return places.to(torch.uint8).reshape(len(texels), 16)


def _cell_texels(cells, size):
    """(N, 4) flat indices of the four texels bilinear_texels reads in each cell (N,) (the flat
    index of its top-left texel): it, right, below, below right, held at the texture's edge."""
    rows, columns = cells // size, cells % size
    below, right = (rows + 1).clamp(max=size - 1), (columns + 1).clamp(max=size - 1)
    return torch.stack([rows * size + columns, rows * size + right, below * size + columns, below * size + right], 1)


def _facing(normals, K):
    """(B, H, W) the cosine between each pixel's surface normal (B, H, W, 3, camera frame) and the
    ray from the surface back to the camera through the pixel's centre, at least 0."""
    rays = torch.nn.functional.normalize(pixel_rays(K, *normals.shape[:3], normals.dtype, normals.device), dim=-1)
    return (-(normals * rays).sum(-1)).clamp(min=0.0)


@torch.no_grad()
def texel_coverage(problem, batch_size=SOLVE_BATCH, frames=None, squarely_seen=True):
    """((T, T), (T, T) or None): the bilinear weight each texel of the avatar's albedo gets from the
    pixels the solve reads (FitProblem.compared_pixels with albedo_solve) in `frames` (indices into
    the fitted frames, default all), each pixel weighted by its openness where
    FitSettings.albedo_openness is on (as the solve weighs it); and, with `squarely_seen`, the part of
    it from pixels that see their skin squarely, each weighted by smoothstep of its facing (_facing)
    from FACING_GRAZING to FACING_SQUARE."""
    avatar, clip = problem.avatar, problem.clip
    openness_on = problem.settings.albedo_openness == "on"
    size = avatar.albedo.shape[-1]
    coverage = torch.zeros(size * size, dtype=avatar.albedo.dtype, device=avatar.albedo.device)
    squarely = torch.zeros_like(coverage)
    chosen = torch.arange(len(problem.frames)) if frames is None else torch.as_tensor(frames, dtype=torch.long)
    for batch in chosen.to(avatar.albedo.device).split(batch_size):
        vertices, _ = avatar.posed(batch)
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                        outputs=("uv", "alpha") + (("normal",) if squarely_seen else ())
                        + (("vertex_values",) if openness_on else ()),
                        antialiased=False, vertex_values=_room_hidden(avatar, batch, vertices) if openness_on else None)
        usable = problem.compared_pixels(batch, albedo_solve=True) & (images["alpha"][..., 0] > 0.5)
        rows, columns, weights = bilinear_texels(images["uv"][usable], size)
        if openness_on:
            weights = weights * openness(images["vertex_values"][usable][:, :1])
        texels = (rows * size + columns).flatten()
        coverage.index_add_(0, texels, weights.flatten().to(coverage.dtype))
        if squarely_seen:
            square = smoothstep((_facing(images["normal"], clip.K[batch])[usable] - FACING_GRAZING)
                                / (FACING_SQUARE - FACING_GRAZING))
            squarely.index_add_(0, texels, (weights * square[:, None]).flatten().to(coverage.dtype))
    return coverage.view(size, size), squarely.view(size, size) if squarely_seen else None


def decided_texels(problem, batch_size=SOLVE_BATCH, frames=None):
    """(T, T) bool: the texels of the avatar's albedo that its frames decide (texel_coverage: at least
    MIN_COVERAGE of bilinear weight), the texels the solve solves. Any other texel holds what the
    appearance stage left (its starting colour where no compared pixel reached it: a finger's side,
    seen edge-on at the silhouette), and texture_fill.py fills it."""
    return texel_coverage(problem, batch_size, frames, squarely_seen=False)[0] >= MIN_COVERAGE


def texel_trust(problem, batch_size=SOLVE_BATCH, frames=None, square_share=SQUARE_SHARE):
    """(T, T) in [0, 1]: how far the fill keeps each texel as the solve left it (texture_fill.fill_unseen):
    0 where the frames do not decide it, 1 where pixels that see its skin squarely give at least
    `square_share` of its weight (as they weigh in its solved colour), smoothly between. A texel seen
    mostly edge-on (the hand's side in a clip that never turns it to the camera) holds the rim's light
    (the mask's edge, a pose a pixel off, the sheen at grazing angles): kept as solved, it drew a dark
    jagged line where the solved texels met the fill on a real clip (docs/real_footage.md). A share,
    not an amount: the same at any frame size and clip length."""
    coverage, squarely = texel_coverage(problem, batch_size, frames)
    trust = smoothstep(squarely / coverage.clamp(min=1e-12) / square_share)
    return torch.where(coverage >= MIN_COVERAGE, trust, torch.zeros_like(trust))


def _consistency_weights(seen, albedo, size):
    """((N,) each pixel's weight for the next solve; the clip's noise variance, the median
    squared residual, at least NOISE_FLOOR squared; that median as it is, a float). A pixel's
    weight: a Cauchy weight of its residual against the clip's noise (an outlier: a shadow or
    highlight in one frame), times the clip's noise variance over its texels' (bilinear mix), each
    texel's from the residuals of its pixels weighted so (the frames disagree on it, beyond single
    outliers)."""
    squared = (seen.colour - seen.predicted(albedo)).pow(2).mean(1)
    median = squared.median()
    clip_variance = median.clamp(min=NOISE_FLOOR ** 2)
    inlier = 1 / (1 + squared / (OUTLIER_SCALE ** 2 * clip_variance))
    spread = torch.zeros(size * size, dtype=squared.dtype, device=squared.device)
    count = torch.zeros_like(spread)
    spread.index_add_(0, seen.texels.flatten(), (seen.weights * (inlier * squared)[:, None]).flatten())
    count.index_add_(0, seen.texels.flatten(), (seen.weights * inlier[:, None]).flatten())
    # a texel's own residuals underestimate its variance by about one pixel's worth: its value
    # was fitted to them
    texel_variance = (spread + PRIOR_COUNT * clip_variance) / ((count - 1).clamp(min=0) + PRIOR_COUNT)
    pixel_variance = (texel_variance[seen.texels] * seen.weights).sum(1)
    return inlier * clip_variance / pixel_variance, clip_variance, float(median)


def _prior_weight(seen, coverage, solved, current, clip_variance):
    """The reweighted solves' pull towards the current albedo: what a typical pixel adds to a
    texel's diagonal, times the clip's noise variance in albedo units over the current albedo's
    mean squared difference from the first solve on the texels the frames decide well."""
    coverage = coverage.view(current.shape[1:])
    well_seen = coverage >= WELL_SEEN
    if not well_seen.any():
        well_seen = coverage >= MIN_COVERAGE
    if not well_seen.any():
        return 0.0
    shading_squared = (seen.shading ** 2).mean(1)
    typical_pixel = (shading_squared * (seen.weights ** 2).sum(1)).mean()
    albedo_noise = clip_variance / shading_squared.mean()
    prior_error = (solved - current).pow(2).mean(0)[well_seen].mean().clamp(min=1e-8)
    return float(typical_pixel * albedo_noise / prior_error)


class _NormalEquations:
    """sum over pixels of weight * (S * sum_i w_i a_(k_i) - I)^2, per channel, as a 9-point
    stencil per texel (matrix) and a right-hand side, plus each texel's bilinear weight
    (coverage).

    A pixel's four texels are those of its bilinear cell (bilinear_texels: the cell's top-left
    texel and its neighbours right and below, held at the texture's edge), so its 10 distinct
    pair products (w_i w_j = w_j w_i: PAIRS), 4 right-hand-side terms and 4 weights are first
    summed per cell, PIXEL_CHUNK pixels at a time, in one index_add_ of whole rows (half the time
    of scattering every entry to its texel pair), and the cells' sums are then spread to their
    texels' 16 ordered pairs once."""

    def __init__(self, size, seen, pixel_weight):
        self.size = size
        dtype, device = seen.shading.dtype, seen.shading.device
        count, pairs = size * size, len(PAIRS)
        # per cell: the pair sums x 3 channels, then 4 right-hand-side terms x 3, then 4 coverages
        pair_sums, rhs_sums = slice(0, 3 * pairs), slice(3 * pairs, 3 * pairs + 12)
        coverages = slice(3 * pairs + 12, None)
        cells = torch.zeros(count, pairs * 3 + 4 * 3 + 4, dtype=dtype, device=device)
        weighted = seen.shading * pixel_weight[:, None]
        buffer = torch.empty(min(PIXEL_CHUNK, len(seen.texels)), cells.shape[1], dtype=dtype, device=device)
        for start in range(0, len(seen.texels), PIXEL_CHUNK):
            chunk = slice(start, start + PIXEL_CHUNK)
            weights = seen.weights[chunk]
            rows = buffer[:len(weights)]
            products = torch.cat([weights[:, i:i + 1] * weights[:, i:] for i in range(4)], 1)[:, :, None]   # PAIRS
            torch.mul(products, (weighted[chunk] * seen.shading[chunk])[:, None, :],
                      out=rows[:, pair_sums].view(-1, pairs, 3))
            torch.mul(weights[:, :, None], (weighted[chunk] * seen.colour[chunk])[:, None, :],
                      out=rows[:, rhs_sums].view(-1, 4, 3))
            rows[:, coverages] = weights
            cells.index_add_(0, seen.texels[chunk, 0].long(), rows)
        ordered = cells[:, pair_sums].view(count, pairs, 3)[:, PAIR_OF_ORDERED]     # (count, 16, 3)
        texels = _cell_texels(torch.arange(count, device=device), size)    # (count, 4) each cell's texels
        slots = (texels[:, :, None] * len(STENCIL)).expand(-1, 4, 4).reshape(-1, 16) + stencil_places(texels, size)
        matrix = torch.zeros(count * len(STENCIL), 3, dtype=dtype, device=device)
        matrix.index_add_(0, slots.flatten(), ordered.reshape(-1, 3))
        rhs = torch.zeros(count, 3, dtype=dtype, device=device).index_add_(0, texels.flatten(),
                                                                            cells[:, rhs_sums].reshape(-1, 3))
        coverage = torch.zeros(count, dtype=dtype, device=device).index_add_(0, texels.flatten(),
                                                                              cells[:, coverages].flatten())
        self.matrix, self.rhs, self.coverage = matrix.t().contiguous(), rhs.t().contiguous(), coverage

    def diagonal(self):
        """(3, T, T) each texel's own coefficient."""
        return self.matrix.view(3, self.size, self.size, len(STENCIL))[..., STENCIL.index((0, 0))]

    def data_weight(self):
        """The mean diagonal over the texels the frames decide."""
        solved = self.coverage.view(self.size, self.size) >= MIN_COVERAGE
        return float(self.diagonal().mean(0)[solved].mean()) if solved.any() else 0.0

    def solve(self, target, anchor, pull, start=None):
        """(albedo (3, T, T), solved (T, T) bool): conjugate gradients from `start` (default
        `target`: a solve of nearly the same equations starts where the last one ended), with a pull
        `anchor` towards `target` and `pull` times the data weight between neighbours."""
        size = self.size
        matrix = self.matrix.view(3, size, size, len(STENCIL))
        solved = self.coverage.view(size, size) >= MIN_COVERAGE
        if not solved.any():
            return target.clone(), solved
        smoothness = pull * self.data_weight()

        def apply(albedo):
            padded = torch.nn.functional.pad(albedo, (1, 1, 1, 1))
            result = anchor * albedo
            for index, (dy, dx) in enumerate(STENCIL):
                result = result + matrix[..., index] * padded[:, 1 + dy:1 + dy + size, 1 + dx:1 + dx + size]
            return result + smoothness * _grid_laplacian(albedo)

        rhs = self.rhs.view(3, size, size) + anchor * target
        diagonal = self.diagonal() + anchor + 4 * smoothness
        start = target if start is None else start
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


@torch.no_grad()
def solve_avatar_albedo(problem, shadows, solve_environment=True, frames=None) -> dict:
    """Replace the avatar's albedo (and environment light, when it has one and `solve_environment`)
    by the solved ones where the frames decide them (in place); returns the share of the UV charts
    solved, the mean change there, the neighbour pull the frames' noise gave the solve
    (neighbour_pull; None where no pixel was usable) and the environment's relative strength before
    and after.
    With `solve_environment` False the light is held as it stands and the albedo alone is solved
    (the finer pass of fitting._after_the_stages). `frames` (indices into the fitted frames,
    default all): the frames read."""
    avatar = problem.avatar
    before = avatar.light().environment
    light_solved = before is not None and solve_environment
    before = before.detach().clone() if light_solved else None
    albedo, solved, environment, pull = _solved(problem, shadows, SOLVE_BATCH, avatar.albedo.detach().clamp(0, 1),
                                                solve_environment, frames,
                                                weigh_openness=problem.settings.albedo_openness == "on")
    solved = solved & (problem.uv_mask.to(solved.device) > 0)
    change = (albedo - avatar.albedo.clamp(0, 1)).abs().mean(0)[solved]
    avatar.albedo.copy_(torch.where(solved[None], albedo, avatar.albedo))
    figures = {"solved_fraction": float(solved.sum() / (problem.uv_mask > 0).sum().clamp(min=1)),
               "mean_change": float(change.mean()) if change.numel() else 0.0, "neighbour_pull": pull}
    if light_solved:
        avatar.environment.copy_(environment)
        ambient = avatar.ambient.item()
        figures["environment_strength"] = {"before": relative_strength(before.cpu().numpy(), ambient),
                                           "after": relative_strength(environment.cpu().numpy(), ambient)}
    return figures
