"""How long a fit will take, measured rather than guessed.

Before the stages start, `calibrate` times a few throwaway steps of each kind the fit will take
(the alignment, the geometry stage, the joint and appearance stages with and without
self-shadowing) at the fit's own frames, working size and batch, then puts the avatar back
bit-for-bit. The per-step costs give the estimate printed before the fit.

While the fit runs, `TimeLeft` turns them into the time left: the stage under way at its own
observed rate (the median of its recent steps), the stages to come at their calibrated cost
scaled by how fast this machine has been running in the last minute or so compared with the
calibration (a second process that starts halfway slows every stage alike). The work after the stages (the
albedo solve, the texture fill, the outputs: every frame rendered a few times, and some work over the
texture) is costed from the joint step's cost per frame and the texture's size (`after_stages_seconds`).

Small fits (tests, quick looks) skip the calibration: their estimate uses FALLBACK_COSTS.
`measure_step_costs` is the fit's calibration step; FitEstimate reads its costs and, with a
time budget (budget.py), puts the budget's new schedules in force as the fit runs.
"""
from __future__ import annotations

import collections
import copy
import dataclasses
import math
import statistics
import time

import torch

from .budget import REPLAN_STEPS, BudgetKeeper
from .checkpoint import FitState
from .light_probe import PROBE_FRAMES
from .schedule import SHADOWS_DECIDED_IN, Schedule, StageKind, StepKind, step_kind
from .stage_run import StageRun, stage_has_work
from .texel_footprint import likely_texture_size

WARM_UP_STEPS = 1            # untimed steps of each kind first (a new optimiser's state, allocations)
TIMED_STEPS = 2              # timed steps per kind of step
CALIBRATE_MIN_STEPS = 150    # fits with fewer steps left take FALLBACK_COSTS instead of calibrating
RECENT_STEPS = 15            # a stage's rate: the median of this many of its latest steps...
OWN_RATE_AFTER = 4           # ...once it has taken this many
SPEED_PRIOR_SECONDS = 20.0   # the machine's observed speed counts once this much has been timed...
SPEED_MEMORY_SECONDS = 60.0  # ...and follows a change (another process starting) over about this long
# a fit with the room light's occlusion measures every frame's about this many times: at the start of the two
# shaded stages, at the end, and as poses move (the phone-like clip's `fast` fit: 120 measurements of 24 frames)
OCCLUSION_MEASUREMENTS = 5
# without it in the stages, the occlusion drawn after them (FitSettings.occlusion "after") or the albedo solve that
# weighs its pixels by their openness (FitSettings.albedo_openness) measures every frame's once, timed on this many
# frames
OPENNESS_TIMED_FRAMES = 4
# The work after the stages, fitted to report.json's after_stages_seconds and output_seconds (docs/performance.md,
# "The work after the stages"): every fitted frame rendered this many times at a joint step's cost per frame by the
# albedo solve and the outputs, plus seconds of work over a 256 texture (the solve's conjugate gradients, with the
# environment light's alternation when it may be on; the fill), scaled by the texels; the finer solve's frames
# (solve_resolution) at their share of pixels.
SOLVE_FRAME_PASSES = 1.5
OUTPUT_FRAME_PASSES = 0.9
FILL_SECONDS = 4.5
LIGHT_SOLVE_SECONDS = 7.4
FINER_FRAME_PASSES = 1.4
FINER_TEXTURE_SECONDS = 3.0
# where the light's size is decided (light_size.py: shadows may be on): its three probe scores, this many joint-step
# passes over each probe frame (the phone-like clip's 3 fits: 22-27 s for 23 frames at about 0.08 s a frame-pass),
# and the solves' frame passes this many times dearer for a light with a size (8 points: 21 s against 13 for a
# point light over 24 frames; docs/fidelity.md, "The light's size")
LIGHT_SIZE_PROBE_PASSES = 13.0
AREA_SOLVE_FACTOR = 1.6


# seconds per step at 256 px and batches of 6 (the alignment's: per frame, at 128 px, fast's 256 halved by
# settings.align_downscale), on one core: the calibration of the 150-frame sun clip's one-core `fast` fit at e9b523a
# (report.json's estimate); until then these were a 2-core machine's of an older renderer, two to six times higher
FALLBACK_COSTS = {StepKind(StageKind.ALIGN): 0.005, StepKind(StageKind.GEOMETRY): 0.17, StepKind(StageKind.JOINT): 0.52,
                  StepKind(StageKind.JOINT, True): 0.62, StepKind(StageKind.APPEARANCE): 0.47,
                  StepKind(StageKind.APPEARANCE, True): 0.55}


@dataclasses.dataclass
class StepCosts:
    """Seconds per step of each kind (step_kind), and seconds of the work after the stages."""

    seconds: dict
    after_stages: float
    calibrated: bool
    calibration_seconds: float = 0.0

    def plan_seconds(self, plan) -> float:
        """Seconds for a plan: [(kind, steps)], plus the work after the stages."""
        return sum(self.seconds[kind] * steps for kind, steps in plan) + self.after_stages


def remaining_plan(schedule: Schedule, state: FitState, shadows_requested: str, active) -> list:
    """[(StepKind, steps)] still to take of `schedule` from `state` on; `active(stage)` says
    whether a stage has anything to move. An undecided `auto` self-shadowing (decided half-way
    through the joint stage) counts its later steps half with, half without shadows."""
    decision = state.shadows
    plan = []
    for index, stage in enumerate(schedule):
        if index < state.stage or not active(stage):
            continue
        steps = stage.steps - (state.step if index == state.stage else 0)
        if steps <= 0:
            continue
        if decision.decided or shadows_requested != "auto" or not stage.appearance:
            plan.append((step_kind(stage, decision.on), steps))
            continue
        # the decision comes half-way through the joint stage: the steps before it take none
        done = state.step if index == state.stage else 0
        before = max(0, stage.steps // 2 - done) if stage.kind is SHADOWS_DECIDED_IN else 0
        undecided = steps - before
        plan += [(step_kind(stage, False), before + undecided / 2), (step_kind(stage, True), undecided / 2)]
    return [(kind, steps) for kind, steps in plan if steps > 0]


def fallback_costs(settings, frame_count) -> StepCosts:
    """The cost model of a small fit: FALLBACK_COSTS scaled by batch and working size."""
    scale = (settings.batch_size / 6) * (settings.resolution / 256) ** 2
    seconds = {kind: cost * scale for kind, cost in FALLBACK_COSTS.items()}
    align = StepKind(StageKind.ALIGN)
    seconds[align] = FALLBACK_COSTS[align] * frame_count * (settings.resolution / settings.align_downscale / 128) ** 2
    return StepCosts(seconds, after_stages_seconds(seconds, settings, frame_count), calibrated=False)


def after_stages_seconds(seconds, settings, frame_count) -> float:
    """Seconds of the work after the stages of a fit with step costs `seconds` ({StepKind: s});
    where the light's size may be decided, as if it were given one (the dearer case)."""
    per_frame = seconds[StepKind(StageKind.JOINT)] / settings.batch_size
    frames = per_frame * frame_count   # one joint pass over them
    texels = (settings.texture_size / 256) ** 2
    finer = settings.solve_albedo and settings.solve_resolution and settings.solve_resolution > settings.resolution
    written = likely_texture_size(settings.texture_size, settings.solve_resolution) \
        if finer and settings.grow_texture else settings.texture_size
    written_texels = (written / 256) ** 2     # the texture the finer solve and the fill work on
    total = OUTPUT_FRAME_PASSES * frames + FILL_SECONDS * written_texels
    if settings.solve_albedo:
        sized = settings.light_size == "auto" and settings.shadows != "off"
        area = AREA_SOLVE_FACTOR if sized else 1.0
        light = LIGHT_SOLVE_SECONDS if settings.environment != "off" else 0.0
        finer_solve = (area * FINER_FRAME_PASSES * (settings.solve_resolution / settings.resolution) ** 2 * frames
                       + FINER_TEXTURE_SECONDS * written_texels) if finer else 0.0
        total += area * SOLVE_FRAME_PASSES * frames + light * texels + finer_solve
        # each later pass (settings.albedo_passes) solves and fills the texture the first one wrote
        total += (settings.albedo_passes - 1) * (area * SOLVE_FRAME_PASSES * frames + light * written_texels
                                                 + finer_solve + FILL_SECONDS * written_texels)
        if sized:
            total += LIGHT_SIZE_PROBE_PASSES * per_frame * min(frame_count, PROBE_FRAMES)
    return total


def active_stages(problem, schedule: Schedule):
    """`active(stage)`: whether a stage of the kind has anything to move, as planned in `schedule`
    (decided once: a budget that cuts a stage's steps does not make it inactive)."""
    active = {stage.kind: stage_has_work(problem, stage) for stage in schedule}
    return lambda stage: active[stage.kind]


def measure_step_costs(problem, state: FitState, active) -> StepCosts:
    """The fit's calibration step: the step costs of the plan still to take, measured on the
    problem (calibrate) when the fit is long enough to pay for it or runs on a budget, else the
    fallback model's."""
    plan = remaining_plan(state.schedule, state, problem.settings.shadows, active)
    if problem.settings.budget_seconds is not None or sum(steps for _, steps in plan) >= CALIBRATE_MIN_STEPS:
        return calibrate(problem, state.schedule, list(dict.fromkeys(kind for kind, _ in plan)))
    return fallback_costs(problem.settings, len(problem.frames))


def calibrate(problem, schedule: Schedule, kinds) -> StepCosts:
    """Times TIMED_STEPS throwaway steps of each kind in `kinds` on the problem (the StageRun of
    the fit, on a scratch state and random generator), each after WARM_UP_STEPS (a kind's first
    step runs slower: a new optimiser's state, new buffer sizes; one warm-up shared by all kinds
    left the measured costs up to 30% high on a fast fit); the
    avatar's parameters come back bit-for-bit and the fit's generator is not touched. The room
    light's occlusion (Avatar.room_occlusion), when on, is measured for every frame first, timed on
    its own: the steps then time what they cost while the poses stay within its tolerance, and the
    estimate counts OCCLUSION_MEASUREMENTS such measurements of every frame. Without it, the
    occlusion drawn after the stages (FitSettings.occlusion "after") or an albedo solve that weighs
    its pixels by their openness measures every frame's once: timed on OPENNESS_TIMED_FRAMES frames."""
    start = time.perf_counter()
    occlusion_seconds = 0.0
    if problem.avatar.occlusion:
        problem.avatar.measure_occlusion()
        occlusion_seconds = (time.perf_counter() - start) * OCCLUSION_MEASUREMENTS
    elif problem.settings.occlusion_drawn or (problem.settings.solve_albedo and problem.settings.albedo_openness == "on"):
        timed = torch.arange(min(OPENNESS_TIMED_FRAMES, len(problem.frames)), device=problem.avatar.pose.device)
        before = problem.avatar.occlusion_state()      # the solve measures these frames at their final poses
        with torch.no_grad():
            problem.avatar.room_occlusion(timed, problem.avatar.posed(timed)[0])
        occlusion_seconds = (time.perf_counter() - start) * len(problem.frames) / max(len(timed), 1)
        problem.avatar.restore_occlusion_state(before)
    saved = copy.deepcopy(problem.avatar.state_dict())
    saved_occlusion = problem.avatar.occlusion_state()
    by_kind = {stage.kind: stage for stage in schedule}
    seconds = {}
    try:
        for kind in kinds:
            state = FitState.fresh(schedule, "on" if kind.shadows else "off")
            run = StageRun(problem, by_kind[kind.stage], state, torch.Generator().manual_seed(0))
            if not run.has_work:
                continue
            durations = []
            for index in range(WARM_UP_STEPS + TIMED_STEPS):
                begin = time.perf_counter()
                run.step()
                if index >= WARM_UP_STEPS:
                    durations.append(time.perf_counter() - begin)
            seconds[kind] = statistics.fmean(durations)
    finally:
        problem.avatar.load_state_dict(saved)
        problem.avatar.restore_occlusion_state(saved_occlusion)
        for parameter in problem.avatar.parameters():
            parameter.grad = None
    fallback = fallback_costs(problem.settings, len(problem.frames)).seconds
    for kind, cost in fallback.items():   # kinds not timed (nothing to move) cost what the model says
        seconds.setdefault(kind, cost)
    return StepCosts(seconds, after_stages_seconds(seconds, problem.settings, len(problem.frames)) + occlusion_seconds,
                     calibrated=True, calibration_seconds=time.perf_counter() - start)


class TimeLeft:
    """The time left of a fit as it runs: `step(kind, seconds)` after each step, then
    `seconds_left(plan)` for the plan still to take (remaining_plan)."""

    def __init__(self, costs: StepCosts):
        self.costs = costs
        self.recent = collections.defaultdict(lambda: collections.deque(maxlen=RECENT_STEPS))
        self.observed_seconds = 0.0
        self.predicted_seconds = 0.0

    def step(self, kind, seconds):
        self.recent[kind].append(seconds)
        forget = math.exp(-seconds / SPEED_MEMORY_SECONDS)
        self.observed_seconds = self.observed_seconds * forget + seconds
        self.predicted_seconds = self.predicted_seconds * forget + self.costs.seconds[kind]

    @property
    def speed(self) -> float:
        """Observed over calibrated time, recent steps weighing most (1: as calibrated)."""
        return (self.observed_seconds + SPEED_PRIOR_SECONDS) / (self.predicted_seconds + SPEED_PRIOR_SECONDS)

    def rate(self, kind) -> float:
        recent = self.recent[kind]
        if len(recent) >= OWN_RATE_AFTER:
            return statistics.median(recent)
        return self.costs.seconds[kind] * self.speed

    def seconds_left(self, plan) -> float:
        return sum(self.rate(kind) * steps for kind, steps in plan) + self.costs.after_stages * self.speed


class FitEstimate:
    """A fit's time: from the step costs of the calibration step (measure_step_costs), the time
    left after each step and a trace of it for the report (every TRACE_SECONDS), so that the
    estimate can be checked against the truth. With a `budget` (budget.BudgetKeeper) the
    schedule in force (state.schedule) is re-planned to fit it, at the start and every
    REPLAN_STEPS steps."""

    TRACE_SECONDS = 10.0

    def __init__(self, problem, state, costs: StepCosts, active, budget: BudgetKeeper | None = None,
                 validator=None):
        self.problem, self.state, self.costs, self.active, self.budget = problem, state, costs, active, budget
        self.validator = validator     # validation.Validator: its checks are costed beside the steps
        self.time_left = TimeLeft(costs)
        if budget is not None:
            self._replan(time.perf_counter())
        plan = self.plan()
        self.steps_left = int(round(sum(steps for _, steps in plan)))
        self.expected_seconds = self.costs.plan_seconds(plan) + self._validation_seconds()
        self.start = self.last_step = time.perf_counter()
        self.measured_at_start = self.measured_at_last_step = state.measure_seconds
        self.trace = [[0.0, round(self.expected_seconds, 1)]]

    def plan(self):
        return remaining_plan(self.state.schedule, self.state, self.problem.settings.shadows, self.active)

    def _replan(self, now):
        reserved = self.costs.after_stages + self._validation_seconds() / self.time_left.speed
        self.state.schedule = self.budget.replan(now, self.state, self.plan(), self.time_left, reserved)

    def _validation_seconds(self):
        return 0.0 if self.validator is None else self.validator.seconds_left(self.state, self.costs.seconds)

    def checked(self, seconds):
        """A validation check took `seconds` since the last step: not part of the next step's time."""
        self.last_step += seconds

    def step(self, kind: StepKind):
        """(seconds left, steps left) after a step of `kind` (timed from the previous call); a
        budget may have put a new schedule in force (state.schedule)."""
        now = time.perf_counter()
        measured = self.state.measure_seconds   # observers' time (the anytime curve) is no step's
        self.time_left.step(kind, now - self.last_step - (measured - self.measured_at_last_step))
        self.last_step, self.measured_at_last_step = now, measured
        if self.budget is not None and self.state.step % REPLAN_STEPS == 0:
            self._replan(now)
        plan = self.plan()
        left = self.time_left.seconds_left(plan) + self._validation_seconds()
        fitting = self.fitting_seconds(now)
        if fitting >= self.trace[-1][0] + self.TRACE_SECONDS:
            self.trace.append([round(fitting, 1), round(left, 1)])
        return left, int(round(sum(steps for _, steps in plan)))

    def fitting_seconds(self, now):
        """Seconds since the estimate was made, less the time observers took."""
        return now - self.start - (self.state.measure_seconds - self.measured_at_start)

    def report(self):
        """This session's estimate (a resumed fit estimates what it has left), for report.json;
        its `seconds_before_outputs` plus the report's output_seconds is the true time it estimated."""
        return {"expected_seconds": round(self.expected_seconds, 1), "calibrated": self.costs.calibrated,
                "calibration_seconds": round(self.costs.calibration_seconds, 1),
                "step_seconds": {str(kind): round(cost, 4) for kind, cost in self.costs.seconds.items()},
                "after_stages_seconds": round(self.costs.after_stages, 1),
                "budget_seconds": self.problem.settings.budget_seconds,
                "seconds_before_outputs": round(self.fitting_seconds(time.perf_counter()), 1),
                "time_left": self.trace}
