"""The fit's schedule as a value: its stages in order, each a kind and a number of steps.

A stage's kind says what it moves and how it draws its frames; which energy terms count in it
is each term's own declaration (energy_terms.py). A Schedule is frozen: the time budget
(budget.py) and a step cap make new schedules, and the one in force lives in the fit's state
(checkpoint.FitState), so a resumed fit goes on with the plan it had.
"""
from __future__ import annotations

import dataclasses
import enum
import math
from typing import Iterator, Mapping, NamedTuple


def half_cosine(progress: float, final: float) -> float:
    """A factor along a stage at `progress` (steps taken / steps planned, 0..1): a half cosine from 1
    down to `final` (the learning rates of a settling stage; a term's weight that fades)."""
    progress = min(max(progress, 0.0), 1.0)
    return final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * progress))


class StageKind(enum.Enum):
    """The kinds of stage; the value is the stage's name in reports, curves and progress lines."""

    ALIGN = "align"                  # ours: every frame on the unsubdivided mesh, pose and shape only
    GEOMETRY = "geometry"            # appendix C.3, stage 1: geometry from silhouettes and keypoints
    JOINT = "geometry+appearance"    # stage 2: geometry and appearance together
    APPEARANCE = "appearance"        # stage 3: appearance alone
    HELD_OUT = "held-out"            # evaluation: pose and light on frames the fit left out

    @property
    def geometry(self) -> bool:
        """Geometry parameters (pose, shape, displacements; those not frozen) move."""
        return self is not StageKind.APPEARANCE

    @property
    def appearance(self) -> bool:
        """Appearance parameters (textures, light, exposure; those not frozen) move and the
        avatar is rendered shaded."""
        return self in (StageKind.JOINT, StageKind.APPEARANCE, StageKind.HELD_OUT)

    @property
    def coarse(self) -> bool:
        """On the unsubdivided mesh, without displacements."""
        return self is StageKind.ALIGN

    @property
    def settles(self) -> bool:
        """The last stage of the fit to move its parameters (the poses and shape in the joint
        stage, the appearance in the appearance stage): its learning rates fall towards its end
        (FitSettings.final_rate_fraction)."""
        return self in (StageKind.JOINT, StageKind.APPEARANCE)

    @property
    def full_batch(self) -> bool:
        """Every frame in each step (else batches drawn from a shuffled epoch)."""
        return self in (StageKind.ALIGN, StageKind.HELD_OUT)

    def __str__(self):
        return self.value


@dataclasses.dataclass(frozen=True)
class StageSpec:
    """One stage of a schedule: its kind and how many steps it takes."""

    kind: StageKind
    steps: int

    @property
    def name(self) -> str:
        return self.kind.value

    geometry = property(lambda self: self.kind.geometry)
    appearance = property(lambda self: self.kind.appearance)
    coarse = property(lambda self: self.kind.coarse)
    full_batch = property(lambda self: self.kind.full_batch)


FIT_ORDER = (StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT, StageKind.APPEARANCE)
SHADOWS_DECIDED_IN = StageKind.JOINT   # `auto` self-shadowing is decided half-way through this stage


@dataclasses.dataclass(frozen=True)
class Schedule:
    """The stages of a fit in order (a frozen value: changes make new schedules)."""

    stages: tuple[StageSpec, ...]

    @classmethod
    def of_steps(cls, steps: Mapping[StageKind, int], order=FIT_ORDER) -> "Schedule":
        """The stages of `order` with their steps from `steps` (kinds missing: 0 steps)."""
        return cls(tuple(StageSpec(kind, int(steps.get(kind, 0))) for kind in order))

    def __len__(self):
        return len(self.stages)

    def __getitem__(self, index) -> StageSpec:
        return self.stages[index]

    def __iter__(self) -> Iterator[StageSpec]:
        return iter(self.stages)

    def steps(self) -> dict:
        """{StageKind: steps} of every stage."""
        return {stage.kind: stage.steps for stage in self.stages}

    def with_steps(self, steps: Mapping[StageKind, int]) -> "Schedule":
        """A new schedule whose stages named in `steps` take those steps (the others as they were)."""
        return Schedule(tuple(dataclasses.replace(stage, steps=int(steps[stage.kind])) if stage.kind in steps
                              else stage for stage in self.stages))

    def capped(self, most: int) -> "Schedule":
        """A new schedule with every stage at most `most` steps (a quick look; tests)."""
        return self.with_steps({stage.kind: min(stage.steps, most) for stage in self.stages})

    def to_list(self) -> list:
        """[[stage name, steps], ...]: plain values, as a checkpoint stores them."""
        return [[stage.kind.value, stage.steps] for stage in self.stages]

    @classmethod
    def from_list(cls, values) -> "Schedule":
        return cls(tuple(StageSpec(StageKind(name), int(steps)) for name, steps in values))


class StepKind(NamedTuple):
    """The kind of a step for its cost: its stage's kind, and self-shadowing where it renders shading."""

    stage: StageKind
    shadows: bool = False

    def __str__(self):
        return self.stage.value + (" shadows" if self.shadows else "")


def step_kind(stage: StageSpec, shadows: bool) -> StepKind:
    return StepKind(stage.kind, bool(shadows and stage.appearance))
