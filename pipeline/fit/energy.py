"""The fit's energy for one batch of frames: renders the avatar as the stage's terms need it and
sums the weighted terms of the registry (energy_terms.py) that count in the stage."""
from __future__ import annotations

import functools

import torch

from ..render.renderer import render
from .clip_data import saturated
from .energy_terms import SHADED, terms_for
from .problem import FitProblem
from .schedule import StageSpec


class BatchData:
    """What the energy terms read for one batch: the posed avatar, its render, the frames' images
    and masks, and the problem. Data only some terms use is made on first use, once."""

    def __init__(self, problem: FitProblem, stage: StageSpec, frames, shadows, generator, shaded):
        self.problem, self.stage, self.frames, self.generator = problem, stage, frames, generator
        avatar, clip = problem.avatar, problem.clip
        self.vertices, self.keypoints = avatar.posed_coarse(frames) if stage.coarse else avatar.posed(frames)
        # the alignment compares silhouettes at its own, smaller size (FitProblem.alignment_view)
        self.view = problem.alignment_view if stage.coarse else problem.working_view
        self.images = render(self.vertices, avatar.coarse_mesh if stage.coarse else avatar.mesh, self.view.K[frames],
                             self.view.height, self.view.width, outputs=("alpha", "rgb") if shaded else ("alpha",),
                             appearance=avatar.appearance() if shaded else None,
                             light=avatar.light(shadows, None if stage.coarse else frames, self.vertices, samples=1)
                             if shaded else None,
                             background=torch.zeros(3, dtype=self.vertices.dtype, device=self.vertices.device))
        self.masks = self.view.masks[frames]

    @property
    def silhouette_weight(self):
        """(B, h, w, 1) the weight of the masks' pixels, None: 1 everywhere."""
        return None if self.view.weight is None else self.view.weight[self.frames]

    @functools.cached_property
    def target(self):
        """(B, H, W, 3) the frames inside their masks."""
        return self.problem.clip.images[self.frames] * self.masks

    @functools.cached_property
    def rendered(self):
        """(B, H, W, 3) the shaded render as each frame's camera saw it: its exposure gain, and clipped
        at white where the frame is (a saturated channel says only "at least white": a render above
        it matches it, one below is pulled up)."""
        rgb = self.images["rgb"]
        if self.problem.exposure_on:
            rgb = rgb * self.problem.avatar.exposure_gain(self.frames)
        if self.problem.saturated is None:     # nothing clipped in the clip
            return rgb
        target = self.target
        return torch.where(saturated(target) & (rgb > target), target.to(rgb.dtype), rgb)

    @functools.cached_property
    def displacement_field(self):
        return self.problem.avatar.displacement_field()


def batch_energy(problem: FitProblem, stage: StageSpec, frames, shadows, generator, progress=0.0):
    """(total loss, {term: value}) for `frames` (indices into the problem's frames) in `stage`,
    `progress` into it (steps taken / planned: a term's weight may fade along it), self-shadowing on
    or off; `generator` draws the texture regularisers' offsets. Terms with weight 0 are not
    computed; the shaded render is made only when a term needs it."""
    settings = problem.settings
    terms = terms_for(stage.kind, settings, problem)
    shaded = stage.appearance and any(SHADED in term.needs for term in terms)
    batch = BatchData(problem, stage, frames, shadows, generator, shaded)
    values = {term.name: term.evaluate(batch) for term in terms}
    total = sum((term.weight_in(settings, stage.kind, progress) * values[term.name] for term in terms),
                batch.vertices.new_zeros(()))
    return total, {name: float(value.detach()) for name, value in values.items()}
