"""One stage of a fit under way: its Adam optimiser, the batches it draws, and the step with
its safeguards (lazy per-frame updates, rollback on a non-finite or diverging loss: a full
batch's loss against its best, a batch's against the median of the stage's recent batches).

Each step records itself in the FitState (step count, history, events), so a stage can be
stopped and resumed between any two steps.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import statistics

import torch

from .avatar import APPEARANCE, PER_FRAME, POSE
from .checkpoint import FitState
from .energy import batch_energy
from .energy_terms import measured_size, scene_depth
from .problem import FitProblem
from .schedule import StageKind, StageSpec, half_cosine

ROLLBACK_EVERY = 20       # steps between the snapshots a rollback returns to
ALIGN_CHUNK_FRAMES = 32   # frames of the unsubdivided mesh rendered at once in a full batch
DIVERGENCE_FACTOR = 1.5   # a full-batch loss this much above the best so far counts as divergence
# a batch loss this much above the median of the stage's last BATCH_DIVERGENCE_WINDOW batch losses counts as
# divergence (batches differ, so no single best compares). In 103 finished fits (the demo, phone-like, MediaPipe,
# 150-frame and stability clips, every preset) the most was 6.2x, at a stage's second step (Adam's first step
# moves every parameter by its whole rate) on a 3-frame clip, else 4.4x; the stability sweep's pose rate x10
# went to 87x at its geometry stage's second step and ended at 10 mm, its displacement rate x10 to 13x
# (docs/study.md)
BATCH_DIVERGENCE_FACTOR = 10.0
BATCH_DIVERGENCE_WINDOW = 25
PLATEAU_WINDOW = 25       # steps whose mean loss settings.plateau_tolerance compares with the window before
PLATEAU_FLOOR = 0.125     # the plateaus halve a stage's rates down to this share at most


def learning_rate_factor(progress: float, final: float) -> float:
    """The factor on a stage's learning rates at `progress` (steps taken / steps planned, 0..1):
    a half cosine from 1 down to `final`."""
    return half_cosine(progress, final)


def plateau_factor(losses, tolerance: float, window: int = PLATEAU_WINDOW, floor: float = PLATEAU_FLOOR) -> float:
    """The factor on a stage's learning rates after its steps' `losses` so far: halved after
    each full window of `window` steps whose mean loss fell by less than `tolerance` (a share)
    from the window before, down to `floor`; 1 with `tolerance` 0."""
    if tolerance <= 0:
        return 1.0
    means = [sum(losses[start:start + window]) / window for start in range(0, len(losses) - window + 1, window)]
    factor = 1.0
    for before, after in zip(means, means[1:]):
        if after > before * (1.0 - tolerance):
            factor = max(floor, 0.5 * factor)
    return factor


@dataclasses.dataclass
class StepResult:
    loss: float
    terms: dict
    event: str | None = None   # what went wrong and was undone, if anything


def parameter_groups(problem: FitProblem, stage: StageSpec):
    """Adam parameter groups of a stage, frozen parameters left out (empty: nothing to fit).
    The alignment moves rotations and translations at their own rates and no displacements."""
    if stage.coarse:
        groups = [(("global_orient", "pose"), "lr_align_rotation"), (("transl",), "lr_align_translation"),
                  (("betas",), "lr_betas")]
    elif stage.geometry:
        groups = [(POSE, "lr_geometry"), (("betas",), "lr_betas"), (("displacement",), "lr_displacement")]
    else:
        groups = []
    if stage.appearance:
        groups.append((APPEARANCE + ("exposure",), "lr_appearance"))
    result = []
    for names, rate in groups:
        parameters = [getattr(problem.avatar, name) for name in names if name not in problem.frozen]
        if parameters:
            lr = getattr(problem.settings, rate)
            result.append({"params": parameters, "lr": lr, "base_lr": lr, "rate": rate})
    return result


def chunked_energy(problem, stage: StageSpec, frames, chunk_size, batch_size, shadows, generator, backward=True,
                   progress=0.0):
    """(loss, terms) of `frames`, part of a batch of `batch_size` frames, rendered in chunks of
    `chunk_size` whose energies are weighted by their share of the batch; each chunk's gradient
    is added to the parameters' (a non-finite chunk adds none). `progress`: how far the stage is
    (steps taken / planned), for the terms whose weight fades along it."""
    loss, terms = 0.0, {}
    for chunk in frames.split(chunk_size):
        share = len(chunk) / batch_size
        part, part_terms = batch_energy(problem, stage, chunk, shadows, generator, progress=progress)
        if backward and torch.isfinite(part):
            (part * share).backward()
        loss = loss + float(part.detach()) * share
        terms = {name: terms.get(name, 0.0) + value * share for name, value in part_terms.items()}
    return loss, terms


def split_batch(batch: torch.Tensor, parts: int) -> list:
    """`batch` in at most `parts` contiguous parts of near-equal size (no empty part)."""
    return [part for part in torch.tensor_split(batch, min(parts, len(batch))) if len(part)]


def stage_has_work(problem: FitProblem, stage: StageSpec) -> bool:
    """Whether a stage has steps and anything to move (every parameter it moves may be frozen)."""
    return stage.steps > 0 and bool(parameter_groups(problem, stage))


def anchor_size(problem, state):
    """With size_anchor "alignment" and the size prior weighted: the size it holds in the stages
    after the alignment, the hand's as the alignment left it (set when the first of them starts,
    kept in the state so that a resumed fit holds the same); with the depth prior weighted, the
    scene's depth (scene_depth) alike."""
    if "depth_prior" in problem.term_data:
        if state.depth_anchor is None:
            with torch.no_grad():
                state.depth_anchor = float(scene_depth(problem.avatar.transl))
        problem.term_data["depth_prior"].fill_(state.depth_anchor)
    if problem.settings.size_anchor != "alignment" or "size_prior" not in problem.term_data:
        return
    if state.size_anchor is None:
        with torch.no_grad():
            state.size_anchor = float(measured_size(problem, problem.avatar.betas))
    problem.term_data["size_prior"].fill_(state.size_anchor)


class StageRun:
    """Steps of one stage over a problem; `optimiser_state` resumes a stage stopped midway."""

    def __init__(self, problem: FitProblem, stage: StageSpec, state: FitState, generator: torch.Generator,
                 optimiser_state=None):
        self.problem, self.stage, self.state, self.generator = problem, stage, state, generator
        if stage.kind in (StageKind.GEOMETRY, StageKind.JOINT):
            anchor_size(problem, state)
        groups = parameter_groups(problem, stage)
        for group in groups:    # rates that rollbacks of earlier stages halved stay halved (FitState.rate_factors)
            group["lr"] = group["base_lr"] = group["base_lr"] * state.rate_factors.get(group["rate"], 1.0)
        self.optimiser = torch.optim.Adam(groups) if groups else None
        if self.optimiser is not None and optimiser_state is not None:
            self.optimiser.load_state_dict(optimiser_state)
            for group in self.optimiser.param_groups:   # saved before the rates decayed: constant
                group.setdefault("base_lr", group["lr"])
        self.last_good = self._snapshot()
        self.last_good_loss = math.inf   # the loss at the snapshot's parameters (measured by the step after it)
        self.snapshot_unmeasured = True
        self.best_loss = math.inf

    @property
    def has_work(self) -> bool:
        """False when every parameter this stage moves is frozen."""
        return self.optimiser is not None and self.stage.steps > 0

    @property
    def finished(self) -> bool:
        return self.state.step >= self.stage.steps

    @property
    def progress(self) -> float:
        """How far the stage is: steps taken / steps planned (its rates' decay, its terms' fades)."""
        return self.state.step / max(1, self.stage.steps)

    def shadows(self) -> bool:
        return self.stage.appearance and self.state.shadows.on

    def next_batch(self) -> torch.Tensor:
        """Every frame in a full-batch stage; otherwise the next frames of a shuffled epoch."""
        count, device = len(self.problem.frames), self.problem.device
        if self.stage.full_batch:
            return torch.arange(count, device=device)
        if not self.state.order:
            self.state.order = torch.randperm(count, generator=self.generator).tolist()
        size = self.problem.settings.batch_size
        batch, self.state.order = self.state.order[:size], self.state.order[size:]
        return torch.tensor(batch, device=device)

    def energy(self, batch, backward=True):
        """(loss, terms) over `batch`, rendered in chunks whose gradients add up; with batch
        workers (problem.workers) each takes a part of the batch."""
        chunk_size = ALIGN_CHUNK_FRAMES if self.stage.coarse else self.problem.settings.batch_size
        workers = self.problem.workers if backward else None
        parts = [batch] if workers is None else split_batch(batch, 1 + workers.count)
        progress = self.progress
        asked = []
        for connection, part in zip([] if workers is None else workers.connections, parts[1:]):
            seed = int(torch.randint(0, 2 ** 62, (1,), generator=self.generator))
            workers.send(connection, self.stage, part, chunk_size, len(batch), self.shadows(), seed, progress)
            asked.append(connection)
        loss, terms = chunked_energy(self.problem, self.stage, parts[0], chunk_size, len(batch), self.shadows(),
                                     self.generator, backward, progress)
        for connection in asked:
            part_loss, part_terms = workers.collect(connection)
            loss += part_loss
            terms = {name: terms.get(name, 0.0) + part_terms.get(name, 0.0) for name in terms.keys() | part_terms}
        return loss, terms

    def step(self) -> StepResult:
        """One Adam step; a non-finite loss or parameter, or a full-batch loss that rose past
        DIVERGENCE_FACTOR times its best, is undone (back to the last snapshot, learning rates
        halved) and reported as the result's event."""
        self._set_learning_rates()
        batch = self.next_batch()
        self.optimiser.zero_grad(set_to_none=True)
        loss, terms = self.energy(batch)
        if math.isfinite(loss):
            self._mask_frozen_gradients()
            self._lazy_step(batch)
        if self.snapshot_unmeasured and math.isfinite(loss):    # this step's loss is the snapshot's
            self.last_good_loss, self.snapshot_unmeasured = loss, False
        reference = self._divergence_reference()
        diverged = math.isfinite(loss) and reference is not None and loss > reference[0]
        self.best_loss = min(self.best_loss, loss) if math.isfinite(loss) else self.best_loss
        self.state.step += 1
        if not math.isfinite(loss) or not self._finite() or diverged:
            self._restore(self.last_good)
            # the best since the snapshot is gone with what came after it: compared with it, the snapshot's own
            # loss would count as divergence at every step (a 3-frame clip rolled back 87 times in a row)
            problem = f"loss rose to {loss:.4g} from {reference[1]:.4g}" if diverged else "non-finite loss"
            self.best_loss = self.last_good_loss
            for group in self.optimiser.param_groups:
                group["base_lr"] *= 0.5
                group["lr"] *= 0.5
                if "rate" in group:     # and in the stages after this one (a resumed stage's older groups lack it)
                    self.state.rate_factors[group["rate"]] = self.state.rate_factors.get(group["rate"], 1.0) * 0.5
            event = f"{problem} at {self.stage.name} step {self.state.step - 1}: rolled back, learning rates halved"
            self.state.events.append(event)
            return StepResult(loss, terms, event)
        if self.state.step % ROLLBACK_EVERY == 0:
            self.last_good, self.snapshot_unmeasured = self._snapshot(), True
        self.state.history.append({"stage": self.stage.name, "step": self.state.step, "loss": loss, **terms})
        return StepResult(loss, terms)

    def _divergence_reference(self):
        """(the loss above which this step counts as divergence, what it was compared with), or None
        before there is anything to compare with: in a full-batch stage DIVERGENCE_FACTOR times its best
        loss; in a batch stage BATCH_DIVERGENCE_FACTOR times the median of its last batch losses."""
        if self.stage.full_batch:
            return (DIVERGENCE_FACTOR * self.best_loss, self.best_loss) if math.isfinite(self.best_loss) else None
        recent = [entry["loss"] for entry in self.state.history[-BATCH_DIVERGENCE_WINDOW:]
                  if entry["stage"] == self.stage.name]
        if not recent:
            return None
        median = statistics.median(recent)
        return BATCH_DIVERGENCE_FACTOR * median, median

    def _set_learning_rates(self):
        """Each group's rate: its base rate (halved by each rollback) times, in a stage that
        settles its parameters (StageKind.settles), the decay at this step
        (settings.final_rate_fraction) and the plateaus' factor (settings.plateau_tolerance, from
        the stage's losses in the history, so a resumed stage continues alike)."""
        settings, factor = self.problem.settings, 1.0
        if self.stage.kind.settles:
            factor = learning_rate_factor(self.progress, settings.final_rate_fraction)
            if settings.plateau_tolerance > 0:
                losses = [entry["loss"] for entry in self.state.history if entry["stage"] == self.stage.name]
                factor *= plateau_factor(losses, settings.plateau_tolerance)
        for group in self.optimiser.param_groups:
            group["lr"] = group["base_lr"] * factor

    def _lazy_step(self, batch):
        """Adam step that leaves the per-frame parameters of frames outside the batch untouched,
        values and moments alike (otherwise stale momentum keeps moving them: a "lazy" Adam)."""
        avatar = self.problem.avatar
        outside = torch.ones(avatar.pose.shape[0], dtype=torch.bool, device=batch.device)
        outside[batch] = False
        if not outside.any():
            self.optimiser.step()
            return
        saved = []
        for name in PER_FRAME:
            parameter = getattr(avatar, name)
            moments = self.optimiser.state.get(parameter, {})
            saved.append((parameter, parameter.data[outside].clone(),
                          {k: v[outside].clone() for k, v in moments.items() if torch.is_tensor(v) and v.dim() > 0}))
        self.optimiser.step()
        for parameter, values, moments in saved:
            parameter.data[outside] = values
            for key, value in moments.items():
                self.optimiser.state[parameter][key][outside] = value

    def _mask_frozen_gradients(self):
        """The wrist is no joint without a forearm: its rotation gets no update in hand mode."""
        avatar = self.problem.avatar
        if avatar.pose.grad is not None:
            avatar.pose.grad *= avatar.pose_mask

    def _finite(self):
        return all(bool(torch.isfinite(p).all()) for p in self.problem.avatar.parameters())

    def _snapshot(self):
        optimiser = None if self.optimiser is None else copy.deepcopy(self.optimiser.state_dict())
        return copy.deepcopy(self.problem.avatar.state_dict()), optimiser

    def _restore(self, snapshot):
        learning_rates = [(group["lr"], group["base_lr"]) for group in self.optimiser.param_groups]
        self.problem.avatar.load_state_dict(snapshot[0])
        self.optimiser.load_state_dict(snapshot[1])
        for group, (lr, base_lr) in zip(self.optimiser.param_groups, learning_rates):
            group["lr"], group["base_lr"] = lr, base_lr
