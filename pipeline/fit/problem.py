"""The fit problem: everything the energy of a fit needs, built once and passed as one object.

The fit, the held-out evaluation (evaluate/held_out.py) and a fit with known appearance
(HARP-known) all build their problem here; they differ only in the frames, the settings and
which parameters come from another fit and stay frozen.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..formats.initial_estimate import InitialEstimate, read_initial_estimate
from ..formats.sequence_folder import validate_sequence_folder
from ..handmodel.lbs import HandModel
from ..handmodel.uv_atlas import uv_mask as atlas_mask
from .avatar import Avatar
from .clip_data import ClipData, load_clip
from .perceptual import perceptual_term
from .settings import FitSettings


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
    edges: torch.Tensor                 # (E, 2) undirected edges of the subdivided mesh
    face_pairs: torch.Tensor            # (P, 2) faces sharing an edge
    uv_mask: torch.Tensor               # (T, T) texels inside the UV charts
    perceptual: Callable | None         # the perceptual term, None when its weight is 0
    perceptual_name: str
    anchor_keypoints: torch.Tensor      # (F, 21, 3) keypoints at the start: the anchor term's targets
    reference_vertices: torch.Tensor    # (F, V, 3) surface at the start: the edge-length term's reference
    frozen: tuple = ()                  # avatar parameters that never move

    @property
    def frames(self) -> np.ndarray:
        """(F,) indices into the sequence of the frames fitted."""
        return self.clip.frames

    @property
    def device(self) -> torch.device:
        return self.clip.images.device

    def all_frames(self) -> torch.Tensor:
        return torch.arange(len(self.frames), device=self.device)


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
    avatar = build_avatar(initial, clip.frames, settings.texture_size, device)
    _take_shared(avatar, shared)
    for name in frozen:
        getattr(avatar, name).requires_grad_(False)
    with torch.no_grad():
        reference_vertices, keypoints = avatar.posed(torch.arange(len(clip.frames), device=device))
    topology = avatar.mesh.edges()
    data = avatar.model.data
    uv_mask = torch.as_tensor(atlas_mask(data.uvs, data.faces_uv, settings.texture_size),
                              device=device, dtype=clip.images.dtype)
    if settings.weights.get("perceptual", 0.0) == 0.0:
        perceptual_name, perceptual = "off (weight 0)", None
    else:
        perceptual_name, perceptual = perceptual_term(settings.perceptual_weights, device)
    return FitProblem(sequence, settings, initial, clip, avatar, topology.edges,
                      topology.faces[topology.faces[:, 1] >= 0], uv_mask, perceptual, perceptual_name,
                      keypoints[:, :21].detach(), reference_vertices.detach(), tuple(frozen))


def build_avatar(initial: InitialEstimate, frames, texture_size, device=None) -> Avatar:
    """A new Avatar over `frames` of the initial estimate, on the subdivided model of its mode
    and side (and the unsubdivided one for the alignment)."""
    device = default_device(device)
    model = HandModel.load(initial.mode, initial.side, subdivided=True, device=device)
    coarse_model = HandModel.load(initial.mode, initial.side, subdivided=False, device=device)
    return Avatar(model, initial, np.asarray(frames), texture_size, coarse_model=coarse_model)


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
