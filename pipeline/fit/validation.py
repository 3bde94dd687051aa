"""Validation inside the fit: a few frames kept out of it (frames.validation_frames) and scored
as it runs, so that the fit writes its best state, not its last, and ends a stage that no
longer improves them.

A check renders the validation frames with the avatar as it stands: their poses start from the
fitted poses of their temporal neighbours (interpolated: rotations along the shortest arc,
translations linearly), then pose and translation are refined for a few steps of the held-out
stage (shape, displacements, textures, light and exposure frozen: appearance is never fitted on
them), and the frames are scored as the fit's report scores its own (outputs.image_scores: PSNR
and L1 in the mask, silhouette IoU). The fit's own random generator is not touched.

In the stages that fit appearance (VALIDATED_STAGES) a check runs CHECKS_PER_STAGE times per
stage and at its end; the best PSNR so far keeps a copy of the avatar. A stage ends early when
PATIENCE checks in a row gain less than MIN_GAIN_DB over the stage's best. After the stages
the fit goes back to the best copy when the last check scored below it.
"""
from __future__ import annotations

import copy
import dataclasses
import statistics
import time

import numpy as np
import torch

from .avatar import APPEARANCE, SHAPE, SWITCHES
from .checkpoint import FitState
from .outputs import score_renders
from .pose_interpolation import ROTATIONS, start_from_neighbours
from .problem import FitProblem, build_problem
from .schedule import Schedule, StageKind, StageSpec, StepKind
from .stage_run import StageRun

VALIDATED_STAGES = (StageKind.JOINT, StageKind.APPEARANCE)
CHECKS_PER_STAGE = 6
REFINE_STEPS = 10
PATIENCE = 2
MIN_GAIN_DB = 0.05
FROZEN = SHAPE + APPEARANCE + ("exposure",)


@dataclasses.dataclass
class BestState:
    """The avatar at the best validation score so far, and where the fit was."""

    psnr: float
    stage: str
    step: int
    avatar: dict


class Validator:
    """Scores a fit on its validation frames (`frames`, sequence indices kept out of it)."""

    def __init__(self, fit: FitProblem, frames):
        self.fit, self.frames = fit, np.asarray(frames)
        self.problem = build_problem(fit.sequence, fit.settings, self.frames, fit.device, frozen=FROZEN)
        self.best: BestState | None = None
        self.stage_best = -np.inf
        self.stalled_checks = 0
        self.check_seconds = []

    def resume(self, state: FitState, best_avatar):
        """Take up a resumed fit's checks: its best avatar, and the stage under way's gains."""
        if state.best is not None and best_avatar is not None:
            self.best = BestState(state.best["psnr"], state.best["stage"], state.best["step"], best_avatar)
        stage = state.schedule[state.stage].name if not state.finished else None
        for point in state.validation:
            if point["stage"] == stage:
                self._count_gain(point["psnr_mean"])

    def due(self, stage: StageSpec, step: int) -> bool:
        """Whether a check falls after `step` steps of `stage` (evenly over it, and at its end)."""
        if stage.kind not in VALIDATED_STAGES or stage.steps <= 0:
            return False
        every = max(1, stage.steps // CHECKS_PER_STAGE)
        return step % every == 0 or step == stage.steps

    def checks_left(self, state: FitState) -> int:
        """Checks still to come on the schedule in force (VALIDATED_STAGES, due)."""
        count = 0
        for index, stage in enumerate(state.schedule):
            if index < state.stage or stage.kind not in VALIDATED_STAGES or stage.steps <= 0:
                continue
            done, every = state.step if index == state.stage else 0, max(1, stage.steps // CHECKS_PER_STAGE)
            count += max(0, stage.steps // every - done // every + (1 if stage.steps % every else 0))
        return count

    def seconds_left(self, state: FitState, step_seconds: dict) -> float:
        """Seconds the checks still to come take: as the checks so far took, or before the first,
        REFINE_STEPS + 2 joint steps over the validation frames (`step_seconds`: StepCosts.seconds)."""
        if self.check_seconds:
            per_check = statistics.median(self.check_seconds)
        else:
            per_batch = step_seconds.get(StepKind(StageKind.JOINT), 0.0)
            per_check = (REFINE_STEPS + 2) * per_batch * len(self.frames) / self.fit.settings.batch_size
        return self.checks_left(state) * per_check

    def check(self, state: FitState) -> dict:
        """Score the validation frames now: a point for the validation curve (also appended to
        state.validation); keeps the best avatar and counts checks without gain."""
        started = time.perf_counter()
        stage = state.schedule[state.stage]
        scores = self.score(bool(state.shadows.on))
        point = {"fit_seconds": state.fit_seconds, "stage": stage.name, "step": state.step, **scores}
        state.validation.append(point)
        if self.best is None or scores["psnr_mean"] > self.best.psnr:
            self.best = BestState(scores["psnr_mean"], stage.name, state.step,
                                  copy.deepcopy(self.fit.avatar.state_dict()))
            state.best = {"psnr": self.best.psnr, "stage": self.best.stage, "step": self.best.step}
        self._count_gain(scores["psnr_mean"])
        self.check_seconds.append(time.perf_counter() - started)
        return point

    def _count_gain(self, psnr):
        if psnr > self.stage_best + MIN_GAIN_DB:
            self.stage_best, self.stalled_checks = psnr, 0
        else:
            self.stalled_checks += 1

    def stage_stalled(self) -> bool:
        return self.stalled_checks >= PATIENCE

    def new_stage(self):
        self.stage_best, self.stalled_checks = -np.inf, 0

    @torch.no_grad()
    def _take_avatar(self):
        """The fitted avatar's shared parameters, and the validation frames' poses interpolated
        from their fitted neighbours."""
        avatar, fitted = self.problem.avatar, self.fit.avatar
        for name in FROZEN + SWITCHES:
            if name != "exposure":
                getattr(avatar, name).copy_(getattr(fitted, name))
        start_from_neighbours(avatar, {name: getattr(fitted, name) for name in ROTATIONS + ("transl",)},
                              self.fit.frames, self.frames)

    def score(self, shadows) -> dict:
        """{psnr_mean, l1_mean, silhouette_iou_mean, refine_steps} of the validation frames after
        REFINE_STEPS steps of pose refinement from their interpolated poses."""
        self._take_avatar()
        schedule = Schedule((StageSpec(StageKind.HELD_OUT, REFINE_STEPS),))
        state = FitState.fresh(schedule, "on" if shadows else "off")
        run = StageRun(self.problem, schedule[0], state, torch.Generator().manual_seed(self.fit.settings.seed))
        while run.has_work and not run.finished:
            run.step()
        for parameter in self.problem.avatar.parameters():
            parameter.grad = None
        _, _, scores = score_renders(self.problem, shadows)
        return {"psnr_mean": scores["psnr_mean"], "l1_mean": scores["l1_mean"],
                "silhouette_iou_mean": float(np.mean(scores["silhouette_iou"])), "refine_steps": state.step}



def restore_best(validator: Validator, state: FitState) -> BestState | None:
    """After the stages: the fit's avatar goes back to the best check's when the last check
    scored below it (returns that best; None when the avatar stays as it is)."""
    best = validator.best
    if best is None or not state.validation or state.validation[-1]["psnr_mean"] >= best.psnr:
        return None
    validator.fit.avatar.load_state_dict(best.avatar)
    state.best = {**state.best, "restored": True}
    return best
