"""The fit's time budget (pipeline/fit/budget.py): parsing, the cuts in the order the study's
curves give, and a budgeted fit that cuts its schedule, resumes on its plan and ends."""
import pytest

from pipeline.evaluate.exact_clips import write_clip
from pipeline.fit import fitting
from pipeline.fit.budget import budget_steps, parse_budget
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.init import initialise_sequence
from synth.motions import OPEN

PLANNED = {"align": 100, "geometry": 200, "geometry+appearance": 300, "appearance": 200}
COST = {"align": 0.5, "geometry": 0.5, "geometry+appearance": 1.2, "appearance": 0.9}   # 690 s in all


def seconds(steps, done=None):
    done = done or {}
    return sum(max(0, steps[name] - done.get(name, 0)) * COST[name] for name in steps)


@pytest.mark.parametrize("text, value", [("600", 600), ("90s", 90), ("10m", 600), ("1.5h", 5400), ("2 min", 120)])
def test_budgets_read_as_seconds(text, value):
    assert parse_budget(text) == value


@pytest.mark.parametrize("text", ["", "0", "-5m", "ten minutes", "5d"])
def test_a_budget_that_is_no_time_is_a_clear_error(text):
    with pytest.raises(ValueError, match="--budget"):
        parse_budget(text)


def test_a_budget_the_schedule_fits_in_changes_nothing():
    assert budget_steps(PLANNED, {}, COST, 1000) == PLANNED


def test_the_appearance_stage_goes_first_then_geometry_then_the_alignment():
    cut = budget_steps(PLANNED, {}, COST, 600)          # 90 s over: the appearance stage alone
    assert cut == {**PLANNED, "appearance": 100} and seconds(cut) <= 600
    cut = budget_steps(PLANNED, {}, COST, 480)          # appearance at its floor, geometry cut
    assert cut["appearance"] == 50 and PLANNED["geometry"] > cut["geometry"] >= 50
    assert cut["align"] == 100 and cut["geometry+appearance"] == 300 and seconds(cut) <= 480
    cut = budget_steps(PLANNED, {}, COST, 200)          # every floor reached: all alike
    assert seconds(cut) <= 200 and all(cut[name] >= 1 for name in cut)
    assert cut["geometry+appearance"] < 300 and cut["align"] < 30


def test_steps_already_taken_are_kept_and_not_charged():
    done = {"align": 100, "geometry": 120}
    cut = budget_steps(PLANNED, done, COST, 300)
    assert cut["align"] == 100 and cut["geometry"] >= 120 and seconds(cut, done) <= 300


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("budget") / "clip"
    write_clip(folder, OPEN, frames=4, size=96, turn_degrees=25)
    initialise_sequence(folder, "gt-noise", log=lambda *a: None)
    return folder


def test_a_budgeted_fit_cuts_its_schedule_and_resumes_on_its_plan(tiny_clip, tmp_path):
    """A budget far below the schedule's time: the steps are cut (the joint stage least) and the
    fit ends; resumed without --budget it keeps the plan it saved (no "other settings" error)."""
    options = dict(progress="none", texture_size=64, batch_size=2, resolution=96, steps=(40, 60, 40))
    out = tmp_path / "budgeted"
    report = fitting.fit(tiny_clip, out, budget_seconds=12, **options)
    saved = load_checkpoint(out / CHECKPOINT_FILE, "cpu").settings
    geometry, joint, appearance = saved.steps
    assert saved.budget_seconds == 12 and saved.steps != (40, 60, 40)
    assert joint / 60 >= max(geometry / 40, appearance / 40)
    assert report["estimate"]["calibrated"] and report["estimate"]["budget_seconds"] == 12
    again = fitting.fit(tiny_clip, out, resume=True, **options)
    assert load_checkpoint(out / CHECKPOINT_FILE, "cpu").settings.steps == saved.steps
    assert again["metrics"] == report["metrics"]
