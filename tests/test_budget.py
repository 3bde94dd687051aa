"""The fit's time budget (pipeline/fit/budget.py): parsing, the cuts in the order the study's
curves give, and a budgeted fit that cuts its schedule, resumes on its plan and ends."""
import pytest

from pipeline.evaluate.exact_clips import write_clip
from pipeline.fit import fitting
from pipeline.fit.budget import budget_steps, floor_seconds, parse_budget
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.schedule import StageKind, StepKind
from pipeline.init import initialise_sequence
from synth.motions import OPEN

ALIGN, GEOMETRY, JOINT, APPEARANCE = StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT, StageKind.APPEARANCE
PLANNED = {ALIGN: 100, GEOMETRY: 200, JOINT: 300, APPEARANCE: 200}
COST = {ALIGN: 0.5, GEOMETRY: 0.5, JOINT: 1.2, APPEARANCE: 0.9}   # 690 s in all


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
    assert cut == {**PLANNED, APPEARANCE: 100} and seconds(cut) <= 600
    cut = budget_steps(PLANNED, {}, COST, 480)          # appearance at its floor, geometry cut
    assert cut[APPEARANCE] == 50 and PLANNED[GEOMETRY] > cut[GEOMETRY] >= 50
    assert cut[ALIGN] == 100 and cut[JOINT] == 300 and seconds(cut) <= 480
    cut = budget_steps(PLANNED, {}, COST, 200)          # every floor reached: all alike
    assert seconds(cut) <= 200 and all(cut[name] >= 1 for name in cut)
    assert cut[JOINT] < 300 and cut[ALIGN] < 30


def test_the_floor_is_where_every_stage_starts_being_cut_alike():
    """floor_seconds: the cut stages at their floors and the joint stage whole. Above it the
    joint stage keeps every step; below it, it is cut too (the fit says the budget is short)."""
    floor = floor_seconds(PLANNED, {}, COST)
    assert floor == 30 * 0.5 + 50 * 0.5 + 300 * 1.2 + 50 * 0.9
    assert budget_steps(PLANNED, {}, COST, floor + 1)[JOINT] == 300
    assert budget_steps(PLANNED, {}, COST, floor - 10)[JOINT] < 300
    done = {ALIGN: 100, GEOMETRY: 120}                    # steps taken are not charged again
    assert floor_seconds(PLANNED, done, COST) == 300 * 1.2 + 50 * 0.9


def test_a_short_budget_says_which_preset_would_suit_it():
    from types import SimpleNamespace

    note = fitting._short_budget_note(SimpleNamespace(stage_seconds=164.0, needed_seconds=1900.0), "paper")
    assert "2.7 min of the 31.7 min" in note and "preset full, fast or preview" in note
    assert "preset fast or preview" in fitting._short_budget_note(SimpleNamespace(stage_seconds=60.0,
                                                                                   needed_seconds=500.0), "full")
    assert "preset preview" in fitting._short_budget_note(SimpleNamespace(stage_seconds=-5.0, needed_seconds=60.0), "fast")
    assert "longer budget" in fitting._short_budget_note(SimpleNamespace(stage_seconds=-5.0, needed_seconds=60.0),
                                                         "preview")


def test_steps_already_taken_are_kept_and_not_charged():
    done = {ALIGN: 100, GEOMETRY: 120}
    cut = budget_steps(PLANNED, done, COST, 300)
    assert cut[ALIGN] == 100 and cut[GEOMETRY] >= 120 and seconds(cut, done) <= 300


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("budget") / "clip"
    write_clip(folder, OPEN, frames=4, size=96, turn_degrees=25)
    initialise_sequence(folder, "gt-noise", log=lambda *a: None)
    return folder


def test_the_keeper_returns_a_new_schedule_with_the_rates_the_fit_runs_at():
    """Each plan is a new Schedule; the settings and the schedule it replaces stay as they were."""
    from pipeline.fit.budget import AIM, BudgetKeeper
    from pipeline.fit.checkpoint import FitState
    from pipeline.fit.estimate import StepCosts, TimeLeft, remaining_plan
    from pipeline.fit.settings import settings_for

    settings = settings_for("fast", 30, shadows="off", budget_seconds=610.0, steps=(200, 300, 200))
    planned = settings.schedule()
    state = FitState.fresh(planned, "off")
    time_left = TimeLeft(StepCosts({StepKind(kind): cost for kind, cost in COST.items()}, after_stages=10.0,
                                   calibrated=True))
    keeper = BudgetKeeper(610.0, planned, lambda stage: True, started=0.0)

    def replan(now):
        return keeper.replan(now, state, remaining_plan(state.schedule, state, "off", lambda stage: True), time_left,
                             after_stages_seconds=10.0)

    first = replan(now=0.0)     # 690 s planned, 0.97 * 610 - 10 available: the appearance stage cut
    steps = first.steps()
    assert (steps[ALIGN], steps[GEOMETRY], steps[JOINT]) == (100, 200, 300) and steps[APPEARANCE] < 200
    assert seconds(steps) <= AIM * 610 - 10
    assert state.schedule is planned and planned.steps() == PLANNED                  # the old one untouched
    assert settings.steps == (200, 300, 200) and settings.align_steps == 100        # the settings too
    # the alignment done (50 s), the geometry stage half-way, and the machine running twice as slow
    state.schedule, state.stage, state.step = first, 1, 100
    for _ in range(20):
        time_left.step(StepKind(GEOMETRY), 2 * COST[GEOMETRY])
    second = replan(now=150.0)
    steps = second.steps()
    assert steps[ALIGN] == 100                            # it ended: it keeps its steps
    assert steps[GEOMETRY] == 100 and steps[JOINT] < 300 and steps[JOINT] / 300 > steps[APPEARANCE] / 200
    assert first.steps()[GEOMETRY] == 200                 # the plan it replaced, unchanged
    state.schedule = second
    assert time_left.seconds_left(remaining_plan(second, state, "off", lambda stage: True)) < 1.1 * (610 - 150)


def test_a_budgeted_fit_cuts_its_schedule_and_resumes_on_its_plan(tiny_clip, tmp_path, capsys):
    """A budget below anything the fit could do: every stage cut, down to a step if need be,
    and the fit ends; the settings keep what was asked, the state the schedule in force;
    resumed without --budget it keeps the plan it saved (no "other settings" error)."""
    options = dict(progress="none", texture_size=64, batch_size=2, resolution=96, steps=(40, 60, 40))
    out = tmp_path / "budgeted"
    report = fitting.fit(tiny_clip, out, budget_seconds=2, **options)
    saved = load_checkpoint(out / CHECKPOINT_FILE, "cpu")
    assert saved.settings.budget_seconds == 2 and saved.settings.steps == (40, 60, 40)
    cut = saved.state.schedule.steps()
    assert cut[ALIGN] < 100 and all(1 <= cut[kind] < planned for kind, planned in
                                    zip((GEOMETRY, JOINT, APPEARANCE), (40, 60, 40)))
    assert report["schedule"] == {kind.value: steps for kind, steps in cut.items()}
    assert report["estimate"]["calibrated"] and report["estimate"]["budget_seconds"] == 2
    assert "so every stage is cut short" in capsys.readouterr().err    # the opening line says so
    again = fitting.fit(tiny_clip, out, resume=True, **options)
    assert load_checkpoint(out / CHECKPOINT_FILE, "cpu").state.schedule == saved.state.schedule
    assert again["metrics"] == report["metrics"]
