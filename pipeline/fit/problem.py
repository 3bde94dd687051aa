"""The fit problem: everything the energy of a fit needs, built once and passed as one object.

The fit, the held-out evaluation (evaluate/held_out.py) and a fit with known appearance
(HARP-known) all build their problem here; they differ only in the frames, the settings and
which parameters come from another fit and stay frozen.
"""
from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..formats.colour_model import LINEAR
from ..formats.hand_model_file import ELBOW_KEYPOINT_NAME
from ..formats.initial_estimate import InitialEstimate, read_initial_estimate
from ..formats.sequence_folder import validate_sequence_folder
from ..handmodel.lbs import HandModel
from ..handmodel.subdivision import midpoint_parents
from ..handmodel.uv_atlas import uv_mask as atlas_mask
from ..render.rasterize import project
from .avatar import MATERIAL, Avatar
from .clip_data import ClipData, load_clip, saturated
from .energy_terms import ENERGY_TERMS, is_on
from .losses import ALBEDO_SOLVE_EROSION, PHOTOMETRIC_EROSION, eroded_mask
from .mask_cuts import cut_regions
from .perceptual import perceptual_term
from .settings import FitSettings
from .surface_regularisers import SurfaceRegularisers


EXPOSURE_VARIATION = 0.03    # relative spread of the background's brightness that switches exposure gains on
# a background darker than this (8-bit level 20) is no exposure meter: one level is 5% of it, and a
# dark cloth behind a face changed by 14% as the hand covered the face (a real clip, the gains then
# ran to green 0.83 .. 1.33)
EXPOSURE_METER_FLOOR = 0.08


class FitError(ValueError):
    """The fit cannot start or continue (one-line message)."""


@dataclasses.dataclass
class FitProblem:
    """A clip, the avatar being fitted to it and the fixed data of the energy terms."""

    sequence: Path
    settings: FitSettings
    initial: InitialEstimate
    clip: ClipData                      # frames, masks and K at the working resolution
    avatar: Avatar
    surface: SurfaceRegularisers        # the subdivided mesh's Laplacian, normal-consistency and edge-length terms
    perceptual: Callable | None         # the perceptual term, None when its weight is 0
    perceptual_name: str
    anchor_keypoints: torch.Tensor      # (F, 21, 3) keypoints at the start: the anchor term's targets
    reference_edge_lengths: torch.Tensor    # (F, E) the surface's edges at the start: the edge-length term's reference
    frozen: tuple = ()                  # avatar parameters that never move
    silhouette_weight: torch.Tensor | None = None   # (F, H, W, 1) 0 where masks say nothing (None: 1)
    mask_cut_frames: int = 0            # frames whose mask is cut across the forearm (mask_cuts.py)
    exposure_note: str = ""             # how the exposure gains were switched on or off
    exposure_measured: tuple | None = None   # measured_exposure(clip) when the gains are on: their prior
    term_data: dict = dataclasses.field(default_factory=dict)   # {term name: its prepared data} (energy_terms.py)
    workers: object = None              # batch_workers.BatchWorkers: other processes taking parts of each batch
    uv_masks: dict = dataclasses.field(default_factory=dict)    # {texture size: its uv_mask}, made once each

    @property
    def uv_mask(self) -> torch.Tensor:
        """(T, T) the texels inside the UV charts at the avatar's texture size (which the finer
        albedo solve may grow: texel_footprint.py), made once per size."""
        size = int(self.avatar.albedo.shape[-1])
        if size not in self.uv_masks:
            data = self.avatar.model.data
            self.uv_masks[size] = torch.as_tensor(atlas_mask(data.uvs, data.faces_uv, size), device=self.device,
                                                  dtype=self.clip.images.dtype)
        return self.uv_masks[size]

    @property
    def exposure_on(self) -> bool:
        return self.settings.exposure == "on"

    @property
    def known_appearance(self) -> bool:
        return "albedo" in self.frozen

    @property
    def frames(self) -> np.ndarray:
        """(F,) indices into the sequence of the frames fitted."""
        return self.clip.frames

    @property
    def device(self) -> torch.device:
        return self.clip.images.device

    def all_frames(self) -> torch.Tensor:
        return torch.arange(len(self.frames), device=self.device)

    @functools.cached_property
    def alignment_view(self) -> "SilhouetteView":
        """The frames' masks and cameras as the alignment renders them: `align_downscale` times
        smaller than the working frames (silhouette_view), made once."""
        return silhouette_view(self.clip, self.silhouette_weight, self.settings.align_downscale)

    @functools.cached_property
    def working_view(self) -> "SilhouetteView":
        """The frames' masks and cameras at the working size, as the other stages render them."""
        return silhouette_view(self.clip, self.silhouette_weight, 1)

    def at_resolution(self, resolution) -> "FitProblem":
        """The same problem (its avatar itself, not a copy) over its frames loaded at `resolution`
        (long side, pixels; never above the clip's own size): the view the albedo solve reads. Itself
        when that is the size it already works at (or `resolution` is None or 0)."""
        if not resolution:
            return self
        clip = load_clip(self.sequence, resolution, self.frames, device=self.device, dtype=self.clip.images.dtype)
        if clip.images.shape[1:3] == self.clip.images.shape[1:3]:
            return self
        return dataclasses.replace(self, clip=clip, silhouette_weight=None)

    @functools.cached_property
    def photometric_inside(self) -> torch.Tensor:
        """(F, H, W, 1) bool: each frame's mask eroded as the photometric term compares it,
        computed once (per step it took as long as the rest of the term)."""
        return self._eroded_masks(PHOTOMETRIC_EROSION)

    @functools.cached_property
    def albedo_solve_inside(self) -> torch.Tensor:
        """(F, H, W, 1) bool: each frame's mask eroded as the albedo solve reads it (less than the
        photometric term), computed once."""
        return self._eroded_masks(ALBEDO_SOLVE_EROSION)

    def _eroded_masks(self, pixels):
        masks = self.clip.masks
        return torch.cat([eroded_mask(masks[start:start + 16], pixels) > 0.5 for start in range(0, len(masks), 16)])

    def compared_pixels(self, frames=None, albedo_solve=False) -> torch.Tensor:
        """(F, H, W) bool: the pixels whose colour the fit compares in each frame (or in `frames`):
        inside the photometric term's eroded mask (with `albedo_solve`, the albedo solve's, a pixel
        nearer the edge) and recorded by the camera. The albedo solve reads these, and a texel no
        such pixel shows counts as unseen (texture_fill.py)."""
        eroded = self.albedo_solve_inside if albedo_solve else self.photometric_inside
        inside = eroded[..., 0] if frames is None else eroded[frames][..., 0]
        return inside if self.clip.valid is None else inside & (self.clip.valid[..., 0] > 0.5)

    @functools.cached_property
    def saturated(self) -> torch.Tensor | None:
        """(F, H, W, 3) bool: the frames' channels the camera clipped at white (clip_data.saturated),
        found once; None when the clip has none (most clips: then nothing is done for them)."""
        clipped = saturated(self.clip.images)
        return clipped if bool(clipped.any()) else None

    def colour_pixels(self, frames, albedo_solve=False) -> torch.Tensor:
        """(B, H, W) bool: the compared pixels of `frames` (compared_pixels) whose colour measures the
        light, those with no channel clipped at white (a clipped one says only "at least white"). The
        albedo solve and the light search read these."""
        pixels = self.compared_pixels(frames, albedo_solve)
        return pixels if self.saturated is None else pixels & ~self.saturated[frames].any(-1)


def default_device(device=None):
    return device or ("cuda" if torch.cuda.is_available() else "cpu")


def build_problem(sequence, settings: FitSettings, frames, device=None, shared=None, frozen=()) -> FitProblem:
    """The fit problem over `frames` (sequence frame indices) of a sequence folder with an
    init.npz. Per-frame parameters start from init.npz. `shared` ({parameter name: tensor},
    e.g. from another fit's checkpoint) replaces those parameters of the new avatar before the
    anchor and reference data are taken; the parameters named in `frozen` never move. The
    texture size follows a shared albedo."""
    sequence = Path(sequence)
    device = default_device(device)
    validate_sequence_folder(sequence)
    initial = read_initial_estimate(sequence)
    shared = dict(shared or {})
    if "albedo" in shared and shared["albedo"].shape[-1] != settings.texture_size:
        settings = dataclasses.replace(settings, texture_size=int(shared["albedo"].shape[-1]))
    clip = load_clip(sequence, settings.resolution, frames, device=device)
    settings, exposure_note = _decide_exposure(settings, clip)
    avatar = build_avatar(initial, clip.frames, settings.texture_size, device, settings.displacement_grid,
                          settings.colour_model)
    exposure_measured = None
    if settings.exposure == "on":
        exposure_measured = measured_exposure(clip)
        with torch.no_grad():   # a gain the photometric term alone had to find would take many steps
            avatar.exposure.copy_(exposure_measured[0])
    avatar.switch_environment(settings.environment != "off")   # `auto`: fitted until fitting.py decides
    avatar.switch_specular(settings.specular != "off")         # likewise
    avatar.occlusion = settings.occlusion_in_stages   # `after`: switched on by fitting._after_the_stages
    avatar.light_falloff = settings.light_falloff == "on"
    _take_shared(avatar, shared)
    frozen = tuple(frozen) + (() if settings.exposure == "on" else ("exposure",)) \
        + (("environment",) if settings.environment == "off" else ()) \
        + (MATERIAL if settings.specular == "off" else ())
    for name in frozen:
        getattr(avatar, name).requires_grad_(False)
    with torch.no_grad():
        reference_vertices, keypoints = avatar.posed(torch.arange(len(clip.frames), device=device))
    silhouette_weight, cut_frames = _silhouette_weight(clip, avatar, keypoints)
    topology = avatar.mesh.edges()
    surface = SurfaceRegularisers(avatar.mesh.faces, topology.edges, topology.faces[topology.faces[:, 1] >= 0],
                                  reference_vertices.shape[1], dtype=reference_vertices.dtype, device=device)
    if ENERGY_TERMS["perceptual"].weight_in(settings) == 0.0:
        perceptual_name, perceptual = "off (weight 0)", None
    else:
        perceptual_name, perceptual = perceptual_term(settings.perceptual_weights, device)
    problem = FitProblem(sequence=sequence, settings=settings, initial=initial, clip=clip, avatar=avatar,
                         surface=surface,
                         perceptual=perceptual, perceptual_name=perceptual_name,
                         anchor_keypoints=keypoints[:, :21].detach(),
                         reference_edge_lengths=surface.edge_lengths(reference_vertices),
                         frozen=frozen, silhouette_weight=silhouette_weight, mask_cut_frames=cut_frames,
                         exposure_note=exposure_note, exposure_measured=exposure_measured)
    problem.term_data = prepare_terms(problem)
    return problem


def prepare_terms(problem: FitProblem) -> dict:
    """{term name: data} of the energy terms that prepare fixed data, are weighted and apply to
    the problem, made once with the avatar as it starts (energy_terms.EnergyTerm.prepare)."""
    return {term.name: term.prepare(problem) for term in ENERGY_TERMS.values()
            if term.prepare is not None and is_on(term, problem.settings, problem)}


def _decide_exposure(settings, clip):
    """(settings with exposure "on" or "off", a note): `auto` switches the per-frame exposure
    gains on when the background's brightness changes over the clip (the camera's automatic
    exposure or white balance at work) by more than EXPOSURE_VARIATION."""
    if settings.exposure != "auto":
        return settings, f"{settings.exposure} (as asked)"
    brightness = clip.background_brightness
    brightness = brightness[np.isfinite(brightness)]
    if len(brightness) and brightness.mean() < EXPOSURE_METER_FLOOR:
        return dataclasses.replace(settings, exposure="off"), \
            (f"off (auto: the background is too dark to meter the exposure, {100 * brightness.mean():.1f}% "
             "brightness)")
    variation = float(brightness.std() / max(brightness.mean(), 1e-6)) if len(brightness) > 1 else 0.0
    decided = "on" if variation > EXPOSURE_VARIATION else "off"
    return dataclasses.replace(settings, exposure=decided), \
        f"{decided} (auto: the background's brightness varies by {100 * variation:.1f}% over the clip)"


def measured_exposure(clip):
    """((F, 3) log gain, (F,) bool where known) of each frame's camera as its background shows
    it: the background's colour relative to the clip's geometric mean (a camera's exposure and
    white balance change the whole picture alike). Frames without a usable background: 0, unknown."""
    colour = clip.background_colour
    known = np.isfinite(colour).all(1) & (colour > 1e-3).all(1)
    log_gain = np.zeros_like(colour)
    if known.sum() >= 2:
        log_colour = np.log(colour[known])
        log_gain[known] = log_colour - log_colour.mean(0)
    else:
        known[:] = False
    device = clip.images.device
    return (torch.as_tensor(log_gain, dtype=clip.images.dtype, device=device),
            torch.as_tensor(known, device=device))


@dataclasses.dataclass(frozen=True)
class SilhouetteView:
    """Masks and cameras at a size a stage renders its silhouettes: K (F, 3, 3), masks (F, h, w, 1)
    in [0, 1] and their weight (F, h, w, 1) or None (1 everywhere)."""

    K: torch.Tensor
    height: int
    width: int
    masks: torch.Tensor
    weight: torch.Tensor | None


def silhouette_view(clip: ClipData, weight, factor: int) -> SilhouetteView:
    """The clip's masks and silhouette weight averaged over `factor` x `factor` pixel blocks, and
    its cameras for the smaller images (K / factor: a block's centre is where its pixels' centres
    average, under the pixel-centre convention of rasterize.py). Frames whose sides are not a
    multiple of `factor` are padded with pixels of weight 0 (outside the picture, nothing is
    said). `factor` 1: the clip itself."""
    if factor <= 1:
        return SilhouetteView(clip.K, clip.height, clip.width, clip.masks, weight)
    height, width = -(-clip.height // factor), -(-clip.width // factor)
    pad = (0, width * factor - clip.width, 0, height * factor - clip.height)

    def pooled(images):
        return torch.nn.functional.avg_pool2d(torch.nn.functional.pad(images.movedim(-1, 1), pad), factor).movedim(1, -1)

    if weight is None and any(pad):       # the padding says nothing: a weight of 0 there
        weight = torch.ones_like(clip.masks)
    pooled_weight = None if weight is None else pooled(weight)
    pooled_masks = pooled(clip.masks)
    scale = torch.tensor([1.0 / factor, 1.0 / factor, 1.0], dtype=clip.K.dtype, device=clip.K.device)
    return SilhouetteView(clip.K * scale[:, None], height, width, pooled_masks, pooled_weight)


def _silhouette_weight(clip, avatar, keypoints):
    """((F, H, W, 1) weight or None, frames with a mask cut): 0 outside the recorded pixels and
    beyond a cut across the forearm (mask_cuts.py, hand + forearm models only)."""
    weight = None if clip.valid is None else clip.valid.expand_as(clip.masks).clone()
    names = avatar.model.data.keypoint_names
    if ELBOW_KEYPOINT_NAME not in names:
        return weight, 0
    points = project(keypoints[:, [0, names.index(ELBOW_KEYPOINT_NAME)]], clip.K).cpu().numpy()
    cuts = cut_regions(clip.masks[..., 0].cpu().numpy() > 0.5, points[:, 0], points[:, 1])
    if not cuts.any():
        return weight, 0
    kept = torch.as_tensor(~cuts[..., None], dtype=clip.masks.dtype, device=clip.masks.device)
    return (kept if weight is None else weight * kept), int(cuts.any((1, 2)).sum())


def build_avatar(initial: InitialEstimate, frames, texture_size, device=None, displacement_grid="coarse",
                 colour_model=LINEAR) -> Avatar:
    """A new Avatar over `frames` of the initial estimate, on the subdivided model of its mode
    and side (and the unsubdivided one for the alignment); its displacements on the subdivided
    mesh ("fine") or on the unsubdivided one ("coarse", FitSettings.displacement_grid); shading
    in the `colour_model` (formats/colour_model.py, FitSettings.colour_model)."""
    if displacement_grid not in ("coarse", "fine"):
        raise FitError(f"displacement_grid must be 'coarse' or 'fine', got {displacement_grid!r}")
    device = default_device(device)
    model = HandModel.load(initial.mode, initial.side, subdivided=True, device=device)
    coarse_model = HandModel.load(initial.mode, initial.side, subdivided=False, device=device)
    parents = midpoint_parents(coarse_model.data) if displacement_grid == "coarse" else None
    return Avatar(model, initial, np.asarray(frames), texture_size, coarse_model=coarse_model,
                  displacement_parents=parents, colour_model=colour_model)


def _take_shared(avatar, shared):
    """Copy the `shared` parameters into the avatar; a mismatch (another template mode, say)
    is one FitError line."""
    with torch.no_grad():
        for name, value in shared.items():
            parameter = getattr(avatar, name)
            if tuple(value.shape) != tuple(parameter.shape):
                raise FitError(f"the given {name} has shape {tuple(value.shape)}, this clip's avatar needs "
                               f"{tuple(parameter.shape)} ({avatar.model.mode} mode): fit both clips in one "
                               "template mode (harp init --mode)")
            parameter.copy_(value.to(parameter.device, parameter.dtype))
