"""The probe the light's `auto` decisions score their choices on: a few fitted frames rendered
with the albedo solved from them for each choice (the light held), their L1 in the masks.

A choice is compared with the albedo that suits it: the avatar's own albedo has taken in what the
light so far could not explain (every shadow, while the fit had none), and a render with the new
light on that albedo would count it twice."""
from __future__ import annotations

import numpy as np
import torch

from .albedo_solve import solved_albedo
from .outputs import masked_l1

# `shadows auto` renders this many fitted frames (spread over the clip) with and without self-shadowing
# and keeps whichever matches them better. A fitted ambient ratio (the earlier rule: shadows under 0.75)
# could not tell a dominant light that casts shadows from one that casts none: it said on for the
# exact clips, drawn without shadows (ratio 0.56: 36.3 dB without, 32.1 with), as for the Cycles sun
# clip (ratio 0.57: 28.2 dB without, 29.4 with) (docs/fit.md); the light's size is decided on as many
PROBE_FRAMES = 24


def probe_frames(count, kept=None) -> np.ndarray:
    """The fitted frames (indices) a decision renders: up to PROBE_FRAMES of `count`, spread evenly
    over the clip; of `kept` (indices) only, when given."""
    pool = np.arange(count) if kept is None else np.asarray(kept, dtype=int)
    if not len(pool):
        return pool
    return pool[np.unique(np.linspace(0, len(pool) - 1, min(len(pool), PROBE_FRAMES)).round().astype(int))]


@torch.no_grad()
def probe_l1(problem, shadows, probe):
    """masked_l1 of the fitted frames `probe` with the albedo solved from them for `shadows` and
    the light as it stands (held); the avatar's albedo is left as it was."""
    albedo = problem.avatar.albedo
    kept = albedo.detach().clone()
    solved_colours, solved = solved_albedo(problem, shadows, frames=probe, solve_environment=False)
    solved = solved & (problem.uv_mask.to(solved.device) > 0)
    albedo.copy_(torch.where(solved[None], solved_colours, kept))
    try:
        return masked_l1(problem, shadows, probe)
    finally:
        albedo.copy_(kept)
