"""A finished fit read back for evaluation: its report, its checkpoint and its avatar."""
from __future__ import annotations

from pathlib import Path

import torch

from ..fit.checkpoint import CHECKPOINT_FILE, Checkpoint, load_checkpoint
from ..fit.problem import build_avatar, default_device
from ..formats.fit_report import read_report
from ..formats.initial_estimate import read_initial_estimate


class EvaluationError(ValueError):
    """The fit or the sequence cannot be evaluated (one-line message)."""


def load_finished_fit(fit_folder, device=None) -> tuple[Checkpoint, dict]:
    """(checkpoint, report) of a finished fit folder."""
    folder = Path(fit_folder)
    report = read_report(folder)
    if not (folder / CHECKPOINT_FILE).is_file():
        raise EvaluationError(f"the fit in {folder} has no {CHECKPOINT_FILE}")
    return load_checkpoint(folder / CHECKPOINT_FILE, default_device(device)), report


def fitted_avatar(fit_folder, sequence, device=None):
    """(the fit's Avatar over its frames, every parameter as in checkpoint.pt; the report)."""
    device = default_device(device)
    saved, report = load_finished_fit(fit_folder, device)
    avatar = build_avatar(read_initial_estimate(sequence), report["frames"], saved.avatar["albedo"].shape[-1], device,
                          saved.settings.displacement_grid, saved.settings.colour_model)
    avatar.load_state_dict(saved.avatar)
    return avatar, report


@torch.no_grad()
def posed_surfaces(avatar):
    """(F, V, 3) the avatar's displaced surface in every one of its frames."""
    vertices, _ = avatar.posed(torch.arange(avatar.pose.shape[0], device=avatar.pose.device))
    return vertices
