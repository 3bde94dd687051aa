"""The fit's plan as data (pipeline/fit/schedule.py) and its energy-term registry
(pipeline/fit/energy_terms.py): schedules are frozen values, and a term added through the
registry alone is fitted in the stages it names, with the data it prepares."""
import dataclasses

import numpy as np
import pytest
import torch

from synth_clips import exact_clip
from pipeline.fit import fitting
from pipeline.fit.checkpoint import CHECKPOINT_FILE, FitState, load_checkpoint
from pipeline.fit.energy import batch_energy
from pipeline.fit.energy_terms import ENERGY_TERMS, SHADED, EnergyTerm, measured_size, scene_depth, terms_for
from pipeline.fit.problem import build_problem
from pipeline.fit.schedule import Schedule, StageKind, StageSpec
from pipeline.fit.stage_run import StageRun
from pipeline.fit.settings import FitSettings, settings_for
from pipeline.formats.initial_estimate import read_initial_estimate
from pipeline.fit.losses import SIZE_TOLERANCE, size_prior_loss
from pipeline.formats.hand_model_file import PALM_KEYPOINT_NAMES
from pipeline.handmodel.lbs import HandModel

FIT = dict(progress="none", texture_size=64, batch_size=2, resolution=96, shadows="off", device="cpu",
           solve_albedo=False)


def test_a_schedule_is_a_frozen_value_and_changes_make_new_ones():
    planned = settings_for("fast", 30).schedule()
    assert [stage.kind for stage in planned] == [StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT,
                                                 StageKind.APPEARANCE]
    assert [stage.steps for stage in planned] == [100, 200, 300, 100]
    cut = planned.with_steps({StageKind.APPEARANCE: 50})
    capped = planned.capped(120)
    assert cut.steps()[StageKind.APPEARANCE] == 50 and planned.steps()[StageKind.APPEARANCE] == 100
    assert [stage.steps for stage in capped] == [100, 120, 120, 100]
    with pytest.raises(dataclasses.FrozenInstanceError):
        planned[0].steps = 1
    assert Schedule.from_list(cut.to_list()) == cut      # as a checkpoint stores it


def test_each_stage_kind_says_what_moves():
    assert [kind.geometry for kind in StageKind] == [True, True, True, False, True]
    assert [kind.appearance for kind in StageKind] == [False, False, True, True, True]
    assert [kind.coarse for kind in StageKind] == [True, False, False, False, False]
    assert [str(kind) for kind in StageKind] == ["align", "geometry", "geometry+appearance", "appearance", "held-out"]


def test_the_held_out_stage_counts_the_data_terms_and_the_anchor_only():
    """Held-out frames fit pose and light to what the frames show (the forearm's direction in the
    mask among it); the avatar's regularisers and the temporal terms (over frames the held-out
    ones are not neighbours of) stay out."""
    settings = settings_for("fast", 30)
    assert [term.name for term in terms_for(StageKind.HELD_OUT, settings)] == [
        "silhouette", "keypoint_anchor", "forearm_direction", "photometric", "perceptual"]
    assert "photometric" not in [term.name for term in terms_for(StageKind.GEOMETRY, settings)]
    no_photometric = dataclasses.replace(settings, weights={**settings.weights, "photometric": 0.0})
    assert "photometric" not in [term.name for term in terms_for(StageKind.JOINT, no_photometric)]


def test_a_terms_weight_can_differ_by_stage():
    """settings.stage_factors scale a term's weight in the stages named; 0 leaves it out there."""
    settings = settings_for("fast", 30, stage_factors={"keypoint_anchor": {"geometry": 0.1, "appearance": 0.0},
                                                       "silhouette": {"align": 0.0}})
    anchor = ENERGY_TERMS["keypoint_anchor"]
    assert anchor.weight_in(settings, StageKind.ALIGN) == 10.0
    assert anchor.weight_in(settings, StageKind.GEOMETRY) == pytest.approx(1.0)
    assert "silhouette" not in [term.name for term in terms_for(StageKind.ALIGN, settings)]
    assert "silhouette" in [term.name for term in terms_for(StageKind.GEOMETRY, settings)]


def test_a_terms_weight_can_fade_along_a_stage():
    """settings.stage_fades: the weight at a stage's start as stage_factors make it, at its end
    the fraction given, half way between them half way through (a half cosine); other stages and
    terms keep theirs."""
    settings = settings_for("fast", 30, stage_fades={"keypoint_anchor": {"align": 0.1}})
    anchor = ENERGY_TERMS["keypoint_anchor"]
    assert anchor.weight_in(settings, StageKind.ALIGN, 0.0) == pytest.approx(10.0)
    assert anchor.weight_in(settings, StageKind.ALIGN, 0.5) == pytest.approx(5.5)
    assert anchor.weight_in(settings, StageKind.ALIGN, 0.25) == pytest.approx(1.0 + 9.0 * (0.5 + 0.5 ** 1.5))
    assert anchor.weight_in(settings, StageKind.ALIGN, 1.0) == pytest.approx(1.0)
    assert anchor.weight_in(settings, StageKind.ALIGN) == pytest.approx(10.0)       # no progress: the start
    assert anchor.weight_in(settings, StageKind.GEOMETRY, 1.0) == pytest.approx(1.0)
    assert ENERGY_TERMS["silhouette"].weight_in(settings, StageKind.ALIGN, 1.0) == pytest.approx(7.0)
    with pytest.raises(ValueError, match="stage_fades: no energy term named 'anchor'"):
        settings_for("fast", 30, stage_fades={"anchor": {"align": 0.1}})
    with pytest.raises(ValueError, match=r"stage_fades\['keypoint_anchor'\]\['align'\] must be 0 or more"):
        settings_for("fast", 30, stage_fades={"keypoint_anchor": {"align": -0.5}})


def test_a_fading_weight_weighs_the_term_by_the_stages_progress(tiny_clip):
    """batch_energy's total counts a fading term at its weight at the progress given: the
    difference between two progresses is the term's value times the weights' difference."""
    settings = settings_for("fast", 4, resolution=96, texture_size=64,
                            stage_fades={"keypoint_anchor": {"align": 0.2}})
    problem = build_problem(tiny_clip, settings, np.arange(4), "cpu")
    with torch.no_grad():
        problem.avatar.pose.add_(0.05)         # away from the anchor's keypoints: a term worth weighing
    frames, stage = torch.arange(4), StageSpec(StageKind.ALIGN, 10)
    start, terms = batch_energy(problem, stage, frames, False, torch.Generator(), progress=0.0)
    end, _ = batch_energy(problem, stage, frames, False, torch.Generator(), progress=1.0)
    assert terms["keypoint_anchor"] > 0
    assert float((start - end).detach()) == pytest.approx(terms["keypoint_anchor"] * (10.0 - 2.0), rel=1e-4)


def test_a_misspelt_term_or_stage_in_stage_factors_is_an_error():
    """A stage factor that names no term or no stage would change nothing: it is refused."""
    with pytest.raises(ValueError, match="no stage named 'joint'.*geometry\\+appearance"):
        settings_for("fast", 30, stage_factors={"keypoint_anchor": {"joint": 0.0}})
    with pytest.raises(ValueError, match="no energy term named 'anchor'"):
        settings_for("fast", 30, stage_factors={"anchor": {"geometry": 0.0}})


def test_the_held_out_refinement_anchors_the_keypoints_as_the_fits_later_stages_do():
    """The held-out poses are refined with the anchor's weight of the geometry and joint stages
    (1), not the alignment's (10), which held them on the initial keypoints (docs/fit.md)."""
    settings = settings_for("fast", 30)
    anchor = ENERGY_TERMS["keypoint_anchor"]
    assert anchor.weight_in(settings, StageKind.ALIGN) == 10.0
    for kind in (StageKind.GEOMETRY, StageKind.JOINT, StageKind.HELD_OUT):
        assert anchor.weight_in(settings, kind) == pytest.approx(1.0)


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    return exact_clip(tmp_path_factory.mktemp("schedule") / "clip", frames=4)


def test_the_shaded_render_is_made_only_when_a_term_needs_it(tiny_clip, monkeypatch):
    """An appearance stage whose image terms are off renders the silhouette alone."""
    from pipeline.fit import energy

    settings = settings_for("fast", 4, resolution=96, texture_size=64)
    weights = {**settings.weights, "photometric": 0.0, "perceptual": 0.0}
    problem = build_problem(tiny_clip, dataclasses.replace(settings, weights=weights), np.arange(4), "cpu")
    outputs = []
    original = energy.render
    monkeypatch.setattr(energy, "render", lambda *args, **kwargs: outputs.append(kwargs["outputs"]) or
                        original(*args, **kwargs))
    frames = torch.arange(2)
    _, terms = batch_energy(problem, StageSpec(StageKind.APPEARANCE, 1), frames, False, torch.Generator())
    assert outputs == [("alpha",)] and set(terms) == {"texture", "normal_map", "environment", "environment_realisable"}
    problem.settings.weights["photometric"] = 1.0
    _, terms = batch_energy(problem, StageSpec(StageKind.APPEARANCE, 1), frames, False, torch.Generator())
    assert outputs[-1] == ("alpha", "rgb") and "photometric" in terms
    assert all(SHADED in ENERGY_TERMS[name].needs for name in ("photometric", "perceptual"))


LIGHT_SHIFT = torch.tensor([0.2, 0.0, 0.0])   # metres: where the test's term wants the light


def _light_pull(batch):
    """A term of the test's own: the light pulled towards its prepared target (in cm)."""
    return ((batch.problem.avatar.light_position - batch.problem.term_data["light_pull"]) / 0.01).square().sum()


def test_a_term_added_through_the_registry_alone_is_fitted(tiny_clip, tmp_path, monkeypatch):
    """One registry entry, no other change: its default weight reaches the settings, its data is
    prepared once with the problem (the light 20 cm to the side of where it starts), it counts
    in the stages it names (and no other) and it moves the fit there; a fit without it leaves
    the light elsewhere."""
    prepared = []

    def prepare(problem):
        prepared.append(problem.avatar.light_position.detach() + LIGHT_SHIFT.to(problem.avatar.light_position))
        return prepared[-1]

    term = EnergyTerm("light_pull", 1.0, frozenset({StageKind.JOINT, StageKind.APPEARANCE}), _light_pull,
                      prepare=prepare)
    without = fitting.fit(tiny_clip, tmp_path / "without", max_steps=25, **FIT)
    monkeypatch.setitem(ENERGY_TERMS, term.name, term)
    with_term = fitting.fit(tiny_clip, tmp_path / "with", max_steps=25, **FIT)
    saved = load_checkpoint(tmp_path / "with" / CHECKPOINT_FILE, "cpu")
    assert saved.settings.weights["light_pull"] == 1.0 and len(prepared) == 1
    stages_with_term = {entry["stage"] for entry in saved.state.history if "light_pull" in entry}
    assert stages_with_term == {"geometry+appearance", "appearance"}
    target = prepared[0].numpy()
    assert np.linalg.norm(np.asarray(with_term["light_position"]) - target) < 0.02
    assert np.linalg.norm(np.asarray(without["light_position"]) - target) > 0.1


def test_the_schedule_in_force_is_the_states_and_survives_a_checkpoint(tiny_clip, tmp_path):
    fitting.fit(tiny_clip, tmp_path / "avatar", max_steps=3, **FIT)
    saved = load_checkpoint(tmp_path / "avatar" / CHECKPOINT_FILE, "cpu")
    assert saved.state.schedule == saved.settings.schedule() == settings_for("fast", 4).schedule().capped(3)
    assert saved.state.finished and FitState.from_dict(saved.state.to_dict()) == saved.state


def test_the_shape_prior_holds_the_shape_near_the_initial_estimates(tiny_clip, tmp_path):
    """Off by default; weighted, the fitted shape stays nearer the shape the fit started from."""
    weights = settings_for("fast", 4).weights
    assert weights["shape_prior"] == 0.0
    start = torch.as_tensor(read_initial_estimate(tiny_clip).betas)
    drift = {}
    for weight in (0.0, 1000.0):
        out = tmp_path / f"prior{weight:g}"
        fitting.fit(tiny_clip, out, weights={**weights, "shape_prior": weight}, max_steps=25, lr_betas=0.05, **FIT)
        betas = load_checkpoint(out / CHECKPOINT_FILE, "cpu").avatar["betas"]
        drift[weight] = float((betas - start.to(betas.dtype)).abs().max())
    assert drift[0.0] > 0.05 and drift[1000.0] < 0.3 * drift[0.0]


def test_the_size_prior_holds_the_hands_size_and_leaves_its_proportions_free(tiny_clip, tmp_path, monkeypatch):
    """Anchored at the initial estimate's size, measured over the whole hand, with a free band. A
    test term pulls the shape towards a larger hand with longer index fingers: unweighted, the size
    grows with it; weighted, the size stays within the prior's free band of the initial estimate's
    while the index finger still lengthens."""
    weights = settings_for("fast", 4).weights
    model = HandModel.load("hand", "right", dtype=torch.float64)
    start_betas = torch.as_tensor(read_initial_estimate(tiny_clip).betas, dtype=torch.float64)
    start_size = float(model.size(start_betas))
    target = start_betas.clone()
    target[0] += 3.0       # 15% larger
    target[5] += 3.0       # the index finger 12% longer

    def _shape_pull(batch):
        betas = batch.problem.avatar.betas
        return (betas - target.to(betas)).square().mean()

    pull = EnergyTerm("shape_pull", 1.0, frozenset({StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT}), _shape_pull)
    monkeypatch.setitem(ENERGY_TERMS, pull.name, pull)
    size_change, index_change = {}, {}
    for weight in (0.0, 1.0):
        out = tmp_path / f"size{weight:g}"
        fitting.fit(tiny_clip, out, weights={**weights, "size_prior": weight}, size_anchor="initial",
                    size_tolerance=SIZE_TOLERANCE, size_measure="hand", max_steps=25, lr_betas=0.05, **FIT)
        betas = load_checkpoint(out / CHECKPOINT_FILE, "cpu").avatar["betas"].to(torch.float64)
        size_change[weight] = float(model.size(betas)) / start_size - 1
        index_change[weight] = float(betas[5] - start_betas[5])
    assert size_change[0.0] > 0.08 and SIZE_TOLERANCE - 0.01 < size_change[1.0] < SIZE_TOLERANCE + 0.005
    assert index_change[0.0] > 0.3 and index_change[1.0] > 0.5 * index_change[0.0]


def test_the_size_prior_can_hold_the_size_where_the_alignment_left_it(tiny_clip, tmp_path, monkeypatch):
    """size_anchor "alignment" (the default, with no free band): the size is free in the alignment
    and held from its end on. A test term pulls the shape towards a hand 15% larger in the alignment
    and 15% smaller after it: unweighted, the size follows the second pull; weighted, it stays where
    the alignment took it, which the report and the checkpoint's state keep."""
    defaults = settings_for("fast", 4)
    assert (defaults.weights["size_prior"], defaults.size_anchor, defaults.size_tolerance, defaults.size_measure) \
        == (1.0, "alignment", 0.0, "scale")
    weights = defaults.weights
    model = HandModel.load("hand", "right", dtype=torch.float64)
    start_betas = torch.as_tensor(read_initial_estimate(tiny_clip).betas, dtype=torch.float64)
    start_size = float(model.size(start_betas))
    larger, smaller = start_betas.clone(), start_betas.clone()
    larger[0] += 3.0
    smaller[0] -= 3.0

    def _shape_pull(batch):
        betas = batch.problem.avatar.betas
        target = larger if batch.stage.kind is StageKind.ALIGN else smaller
        return (betas - target.to(betas)).square().mean()

    pull = EnergyTerm("shape_pull", 1.0, frozenset({StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT}), _shape_pull)
    monkeypatch.setitem(ENERGY_TERMS, pull.name, pull)
    sizes = {}
    for weight in (0.0, 1.0):
        out = tmp_path / f"anchor{weight:g}"
        report = fitting.fit(tiny_clip, out, weights={**weights, "size_prior": weight}, size_measure="hand",
                             max_steps=25, lr_betas=0.05, **FIT)
        saved = load_checkpoint(out / CHECKPOINT_FILE, "cpu")
        sizes[weight] = (float(model.size(saved.avatar["betas"].to(torch.float64))), report["size_anchor"],
                         saved.state.size_anchor)
    free, held = sizes[0.0], sizes[1.0]
    assert free[1] is None                                   # unweighted: nothing anchored
    anchored = held[1]
    assert anchored == held[2] and anchored / start_size - 1 > 0.05        # the alignment moved it freely
    assert free[0] / anchored - 1 < -0.05                                  # the later pull, unheld
    assert abs(held[0] / anchored - 1) < 0.01, (held, anchored)


def test_the_size_prior_measured_on_the_palm_or_the_scale_leaves_the_fingers_lengths_free(tiny_clip, tmp_path,
                                                                                          monkeypatch):
    """size_measure "palm" or "scale": held where the alignment left it, the palm's size or the
    shape's scale parameter does not stand in the way of fingers that the later stages lengthen.
    A test term pulls every finger 12% longer after the alignment: with the whole hand's size held,
    the scale shrinks to make room for them; with the palm's or the scale held, it stays."""
    weights = settings_for("fast", 4).weights
    model = HandModel.load("hand", "right", dtype=torch.float64)
    start_betas = torch.as_tensor(read_initial_estimate(tiny_clip).betas, dtype=torch.float64)
    longer = start_betas.clone()
    longer[4:9] += 3.0                 # thumb, index, middle, ring and little finger: +12% each

    def _finger_pull(batch):
        if batch.stage.kind is StageKind.ALIGN:
            return batch.problem.avatar.betas.new_zeros(())
        betas = batch.problem.avatar.betas
        return (betas[4:9] - longer[4:9].to(betas)).square().mean()

    def size(betas, measure):
        if measure == "scale":         # the size of an average-proportioned hand at the shape's scale
            return float(model.size(torch.cat([betas[:1], torch.zeros_like(betas[1:])])))
        return float(model.size(betas, measure))

    pull = EnergyTerm("finger_pull", 1.0, frozenset({StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT}), _finger_pull)
    monkeypatch.setitem(ENERGY_TERMS, pull.name, pull)
    fitted = {}
    for measure in ("hand", "palm", "scale"):
        out = tmp_path / measure
        report = fitting.fit(tiny_clip, out, weights={**weights, "size_prior": 1.0}, size_anchor="alignment",
                             size_tolerance=0.0, size_measure=measure, max_steps=25, lr_betas=0.05, **FIT)
        betas = load_checkpoint(out / CHECKPOINT_FILE, "cpu").avatar["betas"].to(torch.float64)
        assert abs(size(betas, measure) / report["size_anchor"] - 1) < 0.01, measure   # held where the alignment left it
        fitted[measure] = betas
    for measure in ("palm", "scale"):
        assert float((fitted[measure][4:9] - start_betas[4:9]).mean()) > 0.5, measure    # the fingers lengthened
        assert float(fitted[measure][0] - fitted["hand"][0]) > 0.3, fitted    # where the hand's size made room for them


def test_a_later_stage_run_outside_a_fit_holds_the_size_where_the_shape_stands(tiny_clip):
    """A joint-stage run started without a fit before it (a benchmark's replay, the step costs'
    calibration, a test) anchors the size and depth priors itself: their energy is finite, the size
    and depth held are the ones the avatar has then, and an avatar moved off them is pulled back."""
    settings = settings_for("fast", 4, resolution=96, texture_size=64,      # the depth prior is off by default
                            weights={**settings_for("fast", 4).weights, "depth_prior": 1.0})
    problem = build_problem(tiny_clip, settings, np.arange(4), "cpu")
    schedule = settings.schedule()
    stage = next(stage for stage in schedule if stage.kind is StageKind.JOINT)
    assert bool(problem.term_data["size_prior"].isnan())
    run = StageRun(problem, stage, FitState.fresh(schedule, "off"), torch.Generator().manual_seed(0))
    _, terms = run.energy(torch.arange(2), backward=False)
    assert float(terms["size_prior"]) == 0.0
    held = float(problem.term_data["size_prior"])
    assert held == pytest.approx(float(measured_size(problem, problem.avatar.betas.detach())))
    assert run.state.size_anchor == held
    with torch.no_grad():
        problem.avatar.betas[0] += 1.0      # the scale: 5% larger
    _, terms = run.energy(torch.arange(2), backward=False)
    assert float(terms["size_prior"]) > 1.0 and float(problem.term_data["size_prior"]) == held
    # the scene's depth alike (the depth prior, where it is weighted)
    assert run.state.depth_anchor == pytest.approx(float(scene_depth(problem.avatar.transl.detach())))
    assert float(terms["depth_prior"]) == pytest.approx(0.0, abs=1e-9)
    with torch.no_grad():
        problem.avatar.transl[:, 2] *= 1.05
    _, terms = run.energy(torch.arange(2), backward=False)
    assert float(terms["depth_prior"]) == pytest.approx((100 * np.log(1.05)) ** 2, rel=1e-3)


def test_the_scene_depth_is_the_geometric_mean_of_the_frames_depths():
    translations = torch.tensor([[0.1, 0.0, 0.2], [0.0, -0.1, 0.8], [0.3, 0.2, 0.5]], dtype=torch.float64)
    assert float(scene_depth(translations)) == pytest.approx((0.2 * 0.8 * 0.5) ** (1 / 3), rel=1e-12)


def test_the_depth_prior_holds_the_scene_where_the_alignment_left_it(tiny_clip, tmp_path, monkeypatch):
    """A larger hand farther away looks the same: a test term pulls every frame 5% nearer than the
    initial estimate after the alignment. Without the depth prior the scene follows it; with it,
    the scene's depth stays within 0.5% of where the alignment left it (the report's depth_anchor)."""
    weights = settings_for("fast", 4).weights

    def initial_depths(problem):
        return torch.as_tensor(problem.initial.transl[problem.clip.frames, 2]).to(problem.avatar.transl)

    def _nearer(batch):
        if batch.stage.kind is StageKind.ALIGN:
            return batch.problem.avatar.betas.new_zeros(())
        depths = batch.problem.avatar.transl[:, 2]
        return ((depths - 0.95 * initial_depths(batch.problem)) / 0.05).square().mean()

    pull = EnergyTerm("pull_nearer", 1.0, frozenset({StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT}), _nearer)
    monkeypatch.setitem(ENERGY_TERMS, pull.name, pull)
    change = {}
    for weight in (0.0, 1.0):
        out = tmp_path / str(weight)
        report = fitting.fit(tiny_clip, out, weights={**weights, "depth_prior": weight}, max_steps=25, **FIT)
        depth = float(scene_depth(load_checkpoint(out / CHECKPOINT_FILE, "cpu").avatar["transl"]))
        assert (report["depth_anchor"] is None) == (weight == 0)      # nothing held where it is not weighted
        change[weight] = depth / (report["depth_anchor"] or float(scene_depth(torch.as_tensor(
            read_initial_estimate(tiny_clip).transl)))) - 1
    assert change[0.0] < -0.01, change      # the pull took the unheld scene nearer (measured: -1.6%)
    assert abs(change[1.0]) < min(0.005, 0.3 * abs(change[0.0])), change     # held (measured: -0.3%)


def test_settings_saved_before_the_size_was_held_by_default_keep_the_size_prior_as_it_was():
    """A checkpoint's settings from before the size prior existed (no weight for it, no anchor,
    band or measure) load with it off and its old anchor, band and measure, and from before the
    depth prior with that off, so a resumed fit goes on as it began; settings saved today keep the hold."""
    held = settings_for("fast", 30)
    older = {k: v for k, v in vars(held).items() if k not in ("size_anchor", "size_tolerance", "size_measure")}
    older["weights"] = {k: v for k, v in held.weights.items() if k not in ("size_prior", "depth_prior")}
    loaded = FitSettings.from_dict(older)
    assert (loaded.weights["size_prior"], loaded.size_anchor, loaded.size_tolerance, loaded.size_measure) == \
        (0.0, "initial", SIZE_TOLERANCE, "hand")
    assert loaded.weights["depth_prior"] == 0.0
    assert loaded.weights["silhouette"] == held.weights["silhouette"]
    again = FitSettings.from_dict(vars(held))
    assert (again.weights["size_prior"], again.size_anchor, again.size_tolerance, again.size_measure) == \
        (1.0, "alignment", 0.0, "scale")


def test_the_size_prior_is_free_within_its_band_and_quadratic_in_per_cent_beyond():
    target = torch.tensor(0.05, dtype=torch.float64)
    for change, expected in ((0.0, 0.0), (0.029, 0.0), (-0.029, 0.0), (0.05, 4.0), (-0.05, 4.0), (0.10, 49.0)):
        size = target * np.exp(change)
        assert float(size_prior_loss(size, target, tolerance=0.03)) == pytest.approx(expected, abs=1e-9)
    size = (target * 1.06).requires_grad_()
    size_prior_loss(size, target, tolerance=0.03).backward()
    step = 1e-7
    numeric = (float(size_prior_loss(size.detach() + step, target)) - float(size_prior_loss(size.detach() - step, target))) / (2 * step)
    assert float(size.grad) == pytest.approx(numeric, rel=1e-5)


def test_the_hands_size_is_the_rms_spread_of_its_rest_keypoints():
    """HandModel.size against its definition, and the scale parameter's +5% per unit."""
    model = HandModel.load("hand", "right", dtype=torch.float64)
    keypoints = torch.as_tensor(model.data.keypoints[:21], dtype=torch.float64)
    expected = float(np.sqrt(((keypoints - keypoints.mean(0)) ** 2).sum(1).mean()))
    betas = torch.zeros(model.num_betas, dtype=torch.float64)
    assert float(model.size(betas)) == pytest.approx(expected, rel=1e-12)
    betas[0] = 1.0
    assert float(model.size(betas)) == pytest.approx(1.05 * expected, rel=1e-6)


def test_the_palms_size_is_the_spread_of_the_wrist_and_knuckles_and_ignores_the_fingers_lengths():
    model = HandModel.load("hand", "right", dtype=torch.float64)
    names = list(model.data.keypoint_names)
    palm = torch.as_tensor(model.data.keypoints[[names.index(name) for name in PALM_KEYPOINT_NAMES]], dtype=torch.float64)
    expected = float(np.sqrt(((palm - palm.mean(0)) ** 2).sum(1).mean()))
    betas = torch.zeros(model.num_betas, dtype=torch.float64)
    assert float(model.size(betas, "palm")) == pytest.approx(expected, rel=1e-12)
    betas[4:9] = 2.0                   # every finger 8% longer: the palm as it was, the hand larger
    assert float(model.size(betas, "palm")) == pytest.approx(expected, rel=1e-9)
    assert float(model.size(betas, "hand")) > 1.02 * float(model.size(torch.zeros_like(betas)))
    betas[0] = 1.0
    assert float(model.size(betas, "palm")) == pytest.approx(1.05 * expected, rel=1e-6)


def test_the_keypoint_anchor_blind_to_the_size_holds_the_pose_and_proportions_alone(tiny_clip):
    """settings.anchor_size "free": the anchor brings the fitted keypoints to the initial
    estimate's size before comparing them, so a larger hand of the same proportions in the same
    poses costs nothing (in metres it costs), while a longer index finger or a bent pose still does."""
    def anchor_after(settings, change):
        problem = build_problem(tiny_clip, settings, np.arange(4), "cpu")
        avatar = problem.avatar
        with torch.no_grad():
            change(avatar)
        _, terms = batch_energy(problem, StageSpec(StageKind.GEOMETRY, 1), torch.arange(2), False,
                                torch.Generator())
        return float(terms["keypoint_anchor"])

    scale = build_problem(tiny_clip, settings_for("fast", 4), np.arange(4), "cpu").avatar.model.data \
        .shape_names.index("scale")

    def larger(avatar):
        avatar.betas[scale] += 1.0           # 5% larger, every proportion kept

    def longer_index(avatar):
        avatar.betas[5] += 2.0

    def bent(avatar):
        avatar.pose[:2, 3:6] += 0.3          # the index finger's first joint

    for name in ("held", "free"):
        settings = settings_for("fast", 4, resolution=96, texture_size=64, shadows="off", anchor_size=name)
        unchanged = anchor_after(settings, lambda avatar: None)
        assert unchanged == pytest.approx(0.0, abs=1e-12)
        if name == "held":
            assert anchor_after(settings, larger) > 1e-4
        else:
            assert anchor_after(settings, larger) < 1e-10
        assert anchor_after(settings, longer_index) > 1e-5
        assert anchor_after(settings, bent) > 1e-5
    with pytest.raises(ValueError, match="anchor_size"):
        settings_for("fast", 4, anchor_size="loose")
