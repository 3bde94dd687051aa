"""A time budget for a fit (`harp fit --budget 10m`): the stages' steps are cut so that the fit,
the work after the stages included, ends within the budget.

Where the time goes follows the study's error-against-run-time curves (docs/study.md, the
run-time section): the alignment brings the joint error down within its first 20-30 steps; the
joint stage buys nearly all of the photometric error (L1 0.134 to 0.039 in its first 80 steps
on the sun clip); the geometry stage (silhouette alone) and the appearance stage move neither
figure much (the appearance stage took L1 from 0.0364 to 0.0358 in 150 s). So when a schedule
does not fit its budget, steps are cut in CUT_ORDER, each stage down to its floor (a share of
its planned steps), and only then every stage alike. A budget larger than the schedule needs
changes nothing: the fit ends early.

The plan is made with the step costs measured before the stages (estimate.calibrate) and made
again every REPLAN_STEPS steps with the rates the fit actually runs at, so a fit that runs
slower than measured still ends on time. Each plan is a new schedule (schedule.Schedule); the
settings are never changed.
"""
from __future__ import annotations

import re

from .schedule import Schedule, StageKind, StepKind

CUT_ORDER = ((StageKind.APPEARANCE, 0.25), (StageKind.GEOMETRY, 0.25), (StageKind.ALIGN, 0.3))
REPLAN_STEPS = 10
AIM = 0.97          # plan for this share of the time left (the last steps and the outputs vary)

_UNITS = {"s": 1, "m": 60, "min": 60, "h": 3600}


def parse_budget(text) -> float:
    """Seconds of a budget written as 600, 90s, 10m, 1.5h."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*(s|m|min|h)?\s*", str(text))
    if not match or float(match.group(1)) <= 0:
        raise ValueError(f"--budget {text!r}: give a positive time such as 300, 90s, 10m or 1.5h")
    return float(match.group(1)) * _UNITS[match.group(2) or "s"]


def budget_steps(planned, done, seconds_per_step, seconds) -> dict:
    """Steps of each stage (StageKind -> total steps, those done included) that fit in `seconds`.
    `planned`: the schedule's steps per stage; `done`: steps already taken per stage (the
    stages past and the one under way); `seconds_per_step`: per stage, for the steps left."""
    steps = dict(planned)

    def cost():
        return sum(max(0, steps[name] - done.get(name, 0)) * seconds_per_step[name] for name in steps)

    for name, floor in CUT_ORDER:
        if name not in steps or cost() <= seconds:
            continue
        lowest = max(done.get(name, 0), round(floor * planned[name]))
        over = cost() - seconds
        steps[name] = max(lowest, steps[name] - int(-(-over // seconds_per_step[name])))
    if cost() > seconds:
        left = {name: max(0, steps[name] - done.get(name, 0)) for name in steps}
        scale = max(0.0, seconds) / max(cost(), 1e-9)
        for name, count in left.items():
            if count:
                steps[name] = done.get(name, 0) + max(1, int(count * scale))
    return steps


def floor_seconds(planned, done, seconds_per_step) -> float:
    """Seconds the steps left take with every stage of CUT_ORDER at its floor: with less time
    than this, every stage is cut alike, below what the study's curves show each needs."""
    floors = {name: round(floor * planned[name]) for name, floor in CUT_ORDER if name in planned}
    return sum(max(0, floors.get(name, steps) - done.get(name, 0)) * seconds_per_step[name]
               for name, steps in planned.items())


class BudgetKeeper:
    """Holds a fit to `seconds`: `replan()` (at the start and every REPLAN_STEPS steps) returns the
    schedule that fits in the time left, from `planned` (the settings' schedule; its stages that
    `active` says have work). `started` is the fit's perf_counter start; `spent_before` the
    fitting time of earlier sessions of a resumed fit, `measured_before` the observers' time
    then (FitState.measure_seconds). Time the observers take (the anytime curve's measuring) is
    not spent from the budget, as it is not fitting time on the curves."""

    def __init__(self, seconds, planned: Schedule, active, started, spent_before=0.0, measured_before=0.0):
        self.seconds, self.started = seconds, started
        self.spent_before, self.measured_before = spent_before, measured_before
        self.planned = {stage.kind: stage.steps for stage in planned if active(stage)}
        self.stage_seconds = self.needed_seconds = None   # of the first plan: for the opening line

    @property
    def too_short(self):
        """The first plan had to cut every stage below its floor (the budget suits a lighter preset)."""
        return self.stage_seconds is not None and self.stage_seconds < self.needed_seconds

    def spent(self, now, state):
        return self.spent_before + now - self.started - (state.measure_seconds - self.measured_before)

    def replan(self, now, state, plan, time_left, after_stages_seconds) -> Schedule:
        """The schedule that fits in the time left at `now`, from the one in force
        (state.schedule), `plan` (estimate.remaining_plan: [(StepKind, steps)] still to take), the
        rates of `time_left` (estimate.TimeLeft) and the calibrated seconds of the work after
        the stages."""
        planned, done = {}, {}
        for index, stage in enumerate(state.schedule):
            if stage.kind in self.planned:
                # a stage that has ended keeps the steps it took
                planned[stage.kind] = stage.steps if index < state.stage else self.planned[stage.kind]
                done[stage.kind] = stage.steps if index < state.stage else state.step if index == state.stage else 0
        rates = dict.fromkeys(self.planned, 0.0)
        counts = dict.fromkeys(self.planned, 0.0)
        for kind, steps in plan:
            rates[kind.stage] += time_left.rate(kind) * steps
            counts[kind.stage] += steps
        rates = {stage: rates[stage] / counts[stage] if counts[stage] else time_left.rate(StepKind(stage))
                 for stage in rates}
        available = AIM * (self.seconds - self.spent(now, state)) - after_stages_seconds * time_left.speed
        steps = budget_steps(planned, done, rates, available)
        if self.stage_seconds is None:
            self.stage_seconds, self.needed_seconds = available, floor_seconds(planned, done, rates)
        return state.schedule.with_steps(steps)
