"""`shadows auto` decided by measurement: the fitted frames rendered with and without
self-shadowing, the better kept. Two exact clips under the same strong side light (ambient
0.6, the ratio at which the earlier rule, ambient < 0.75, said "on" for both), one drawn with
the light's self-shadows and one without; the avatar set to each clip's truth."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pipeline.evaluate.exact_clips import AMBIENT, write_clip
from pipeline.fit import fitting
from pipeline.fit.checkpoint import ShadowDecision
from pipeline.fit.schedule import SHADOWS_DECIDED_IN
from pipeline.formats import sequence_folder as seq
from pipeline.formats.initial_estimate import write_initial_estimate
from pipeline.init.initial_from_ground_truth import ground_truth_with_noise
from synth.motions import RELAXED

SIDE_LIGHT = (0.7, -0.3, 0.6)   # right of and above the hand, a little nearer the camera (metres)


def _problem_at_truth(folder, shadows, frames=3, turn_degrees=20, ambient=AMBIENT):
    write_clip(folder, RELAXED, frames=frames, size=96, turn_degrees=turn_degrees, shadows=shadows,
               light_position=SIDE_LIGHT, ambient=ambient)
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    write_initial_estimate(folder, ground_truth_with_noise(gt, joint_degrees=0.0, translation_m=0.0, seed=0))
    # the clips are drawn without a specular lobe: the avatar at their truth has none either
    problem = fitting._set_up(folder, fitting.FitJob("fast", device="cpu"),
                              {"exposure": "off", "specular": "off"}).problem
    avatar = problem.avatar
    size = avatar.albedo.shape[-1]
    albedo = torch.as_tensor(seq.read_rgb(folder / seq.GT_ALBEDO_FILE) / 255.0).permute(2, 0, 1)[None]
    with torch.no_grad():
        avatar.albedo.copy_(torch.nn.functional.interpolate(albedo, size=(size, size), mode="area")[0])
        avatar.light_position.copy_(torch.tensor(SIDE_LIGHT))
        avatar.ambient_logit.fill_(float(np.log(ambient / (1 - ambient))))
    return problem


def _decide(problem):
    state = SimpleNamespace(shadows=ShadowDecision.requested_as("auto"), step=10)
    run = SimpleNamespace(state=state, stage=SimpleNamespace(kind=SHADOWS_DECIDED_IN, steps=20))
    lines = []
    fitting._decide_shadows(problem, run, SimpleNamespace(log=lines.append))
    assert len(lines) == 1 and lines[0].startswith("shadows auto:"), lines
    return state.shadows


@pytest.mark.parametrize("drawn_with_shadows", [True, False])
def test_shadows_auto_keeps_what_the_frames_show(tmp_path, drawn_with_shadows):
    problem = _problem_at_truth(tmp_path / "clip", drawn_with_shadows)
    decision = _decide(problem)
    assert decision.decided and decision.on is drawn_with_shadows
    better, worse = ((decision.l1_with, decision.l1_without) if drawn_with_shadows
                     else (decision.l1_without, decision.l1_with))
    assert better < 0.8 * worse, (better, worse)     # not a coin toss: the shadows are plain to see
    assert abs(decision.ambient_at_decision - AMBIENT) < 1e-6


def test_shadows_auto_is_decided_once_and_only_at_its_step(tmp_path):
    problem = _problem_at_truth(tmp_path / "clip", True)
    early = SimpleNamespace(state=SimpleNamespace(shadows=ShadowDecision.requested_as("auto"), step=9),
                            stage=SimpleNamespace(kind=SHADOWS_DECIDED_IN, steps=20))
    fitting._decide_shadows(problem, early, SimpleNamespace(log=lambda line: pytest.fail(line)))
    assert not early.state.shadows.decided
    fixed = ShadowDecision.requested_as("off")
    run = SimpleNamespace(state=SimpleNamespace(shadows=fixed, step=10),
                          stage=SimpleNamespace(kind=SHADOWS_DECIDED_IN, steps=20))
    fitting._decide_shadows(problem, run, SimpleNamespace(log=lambda line: pytest.fail(line)))
    assert fixed.on is False and fixed.l1_with is None


@pytest.mark.parametrize("ambient", [0.3, 0.7])
def test_a_shadow_taken_into_the_albedo_is_still_seen_as_a_shadow(tmp_path, ambient):
    """Half-way through the joint stage the avatar has been fitted without shadows, and its albedo
    holds every shadow that falls on the same skin in each frame that shows it (here: a hand held
    still for two frames). Rendered with shadows as it is, it is shadowed twice, and the rule that
    rendered the avatar as it stood said "off". Each option is now scored with the albedo solved for
    it: under a dominant point light (ambient 0.3) the shadows stay on, and under a dominant room
    light (0.7), where both explain the frames alike, they do not pay for their cost. The decision
    leaves the avatar's albedo bit for bit as it found it."""
    from pipeline.fit.albedo_solve import solved_albedo
    from pipeline.fit.outputs import masked_l1

    problem = _problem_at_truth(tmp_path / "clip", True, frames=2, turn_degrees=0, ambient=ambient)
    avatar = problem.avatar
    with torch.no_grad():
        avatar.albedo.copy_(avatar.albedo.mean((1, 2), keepdim=True).expand_as(avatar.albedo))
        baked, solved = solved_albedo(problem, shadows=False)
        avatar.albedo.copy_(torch.where(solved[None], baked, avatar.albedo))
        frames = np.arange(len(problem.frames))
        as_it_stands = masked_l1(problem, True, frames), masked_l1(problem, False, frames)
    assert as_it_stands[0] > as_it_stands[1]                     # the old rule: "off"
    before = avatar.albedo.detach().clone()
    decision = _decide(problem)
    assert decision.on is (ambient < fitting.SHADOW_DOMINANT_AMBIENT)
    if decision.on:      # measured: 6% nearer the frames with the shadows at 0.3, 2.9% further at 0.7
        assert decision.l1_with < decision.l1_without
    else:                # (0.4% further at 0.7 while the solve's neighbour pull was ten times as strong)
        assert abs(decision.l1_with / decision.l1_without - 1) < 2 * fitting.SHADOW_TOLERANCE
    assert torch.equal(avatar.albedo.detach(), before)
