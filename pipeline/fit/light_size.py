"""The light's size decided after the stages (FitSettings.light_size "auto"): a point light, as
HARP's, or a disc of light some degrees across (render/area_light.py), whichever explains the
frames better.

A window or a softbox a metre from the hand lights it from 10-20 degrees of sky, and its shadows
soften away from the finger that casts them; a point light's shadows are hard, and where they fall
the albedo solve takes in the difference: on the phone-like clip (a 0.6 m window 1 m away) the
residual of the true hand wearing its true albedo under the fit's light falls from 0.121 to 0.100
(the light at the window's centre) and to 0.068 (spread over the window); decided in the fit (11
degrees on 3 seeds of 3), held-out frames +0.34-0.37 dB, new poses +0.24-0.28 dB, the albedo
sharper (docs/fidelity.md, "The light's size").

Each candidate size is scored as the shadow decision scores its choices (light_probe.probe_l1: the
probe frames' L1 with the albedo solved from them for that light), the light's shading averaged
over DECISION_SAMPLES of its points; a size is kept only where it brings that L1 MIN_GAIN below
the point light's. Three scores, 22-27 s on the phone-like clip's 23 probe frames of 256 px (two
threads). Only a light that casts shadows on the hand has a size to decide: without them
its size changes the shading only across the terminator (the soft edge tried on its own moved
nothing: docs/fidelity.md, "A soft terminator in the albedo solve").
"""
from __future__ import annotations

import contextlib
import math

import torch

from .light_probe import probe_l1

POINT, FIRST, WIDER, NARROWER = 0.0, 11.0, 19.0, 6.0   # angular radii (degrees): a point, a window, larger, a shade
DECISION_SAMPLES = 4                          # points of the light each candidate's renders average over
MIN_GAIN = 0.01                               # the share of the point light's probe L1 a size must take off


@contextlib.contextmanager
def _samples(avatar, count):
    kept = avatar.area_samples
    avatar.area_samples = count
    try:
        yield
    finally:
        avatar.area_samples = kept


@torch.no_grad()
def decide_light_size(problem, shadows, probe) -> dict:
    """Set the avatar's light_angle to the size whose probe L1 (the fitted frames `probe`, indices)
    is lowest, where it is at least MIN_GAIN below the point light's, else to 0; without `shadows`,
    0 without trying. Three sizes are scored: the point, FIRST, and then WIDER where FIRST beat
    the point, NARROWER where it did not (on the phone-like clip's three fits: 0.0168, 0.0162,
    0.0158, 0.0164 for 0, 6, 11 and 19 degrees). Returns {"degrees", "candidates": {degrees: L1}}."""
    avatar = problem.avatar
    if not shadows or not len(probe):
        avatar.light_angle.fill_(0.0)
        return {"degrees": 0.0, "candidates": {}}
    scores = {}

    def score(degrees):
        avatar.light_angle.fill_(math.radians(degrees))
        scores[degrees] = probe_l1(problem, True, probe)

    with _samples(avatar, DECISION_SAMPLES):
        score(POINT)
        score(FIRST)
        score(WIDER if scores[FIRST] < scores[POINT] else NARROWER)
    best = min(scores, key=scores.get)
    chosen = best if scores[best] <= scores[POINT] * (1 - MIN_GAIN) else POINT
    avatar.light_angle.fill_(math.radians(chosen))
    return {"degrees": chosen, "candidates": {str(d): round(float(v), 6) for d, v in sorted(scores.items())}}
