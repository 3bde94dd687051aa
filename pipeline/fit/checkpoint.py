"""The state of a fit under way and its checkpoint file (AVATAR/checkpoint.pt).

A checkpoint holds everything a fit needs to go on exactly where it stopped: the settings, the
loop's state (FitState), every avatar parameter, the optimiser's moments (None at a stage's
end: the next stage starts a fresh optimiser) and the random generator. It is written
atomically (a temporary file, then a rename), so a fit killed while saving keeps the previous
checkpoint. Only tensors, numbers, strings, lists and dicts are stored, so it loads with
torch's safe `weights_only` loader.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from ..formats.environment_light import COEFFICIENTS as ENVIRONMENT_COEFFICIENTS
from .avatar import initial_material
from .problem import FitError
from .schedule import Schedule
from .settings import FitSettings

CHECKPOINT_FILE = "checkpoint.pt"
CHECKPOINT_FORMAT = "harp-fit-checkpoint"
CHECKPOINT_VERSION = 7          # 3: per-frame exposure gains (avatar "exposure", settings.exposure); 4: the
#                                 schedule in force in the state (a budget no longer rewrites the settings),
#                                 the validation checks and the best one's avatar; 5: the environment light;
#                                 6: the specular lobe; 7: the light's size (avatar "light_angle")
READABLE_VERSIONS = (2, 3, 4, 5, 6, 7)   # a finished fit of version 2 reads as one with its gains off, before 5
#                                          without an environment light, before 6 without a specular lobe, before 7
#                                          with a point light


@dataclasses.dataclass
class ShadowDecision:
    """Self-shadowing: as asked (`auto`, `on`, `off`), and for `auto` when and how it was decided
    (the L1 in the masks of the probe's renders without and with it; checkpoints from before the
    measured decision have none)."""

    requested: str = "auto"
    on: bool = False
    decided: bool = False
    ambient_at_decision: float | None = None
    l1_without: float | None = None
    l1_with: float | None = None

    @classmethod
    def requested_as(cls, shadows):
        return cls(requested=shadows, on=shadows == "on", decided=shadows != "auto")


@dataclasses.dataclass
class FitState:
    """Where a fit stands: the schedule in force (the settings' plan, or a budget's), the stage
    under way and the steps done in it, the time spent per stage, the loss history, the events
    (rollbacks) and the frames still to draw this epoch."""

    schedule: Schedule
    stage_seconds: list                 # seconds of fitting per stage (measuring excluded)
    shadows: ShadowDecision
    stage: int = 0                      # index of the stage under way (len(stages) when done)
    step: int = 0                       # steps done in that stage
    history: list = dataclasses.field(default_factory=list)   # per step: stage, step, loss, terms
    events: list = dataclasses.field(default_factory=list)    # one line each (rollbacks)
    order: list = dataclasses.field(default_factory=list)     # frames of the current epoch not yet drawn
    measure_seconds: float = 0.0        # time observers (the anytime curve) took, not fit time
    texture_fill: dict | None = None    # texture_fill.fill_avatar_albedo's figures, once it has run
    albedo_solve: dict | None = None    # albedo_solve.solve_avatar_albedo's figures, once it has run
    solve_left_out: dict | None = None  # lost_frames.frames_off_their_silhouettes: frames the albedo solve leaves out
    validation: list = dataclasses.field(default_factory=list)   # validation.Validator's checks, in order
    best: dict | None = None            # the best check's psnr, stage and step (its avatar: Checkpoint.best_avatar)
    environment: dict | None = None     # `auto` environment light, once decided: on, relative_strength
    specular: dict | None = None        # `auto` specular lobe, once decided: on, share, highlight, roughness, level
    light_size: dict | None = None      # `auto` light size, once decided (light_size.decide_light_size): degrees, ...
    restarted: dict | None = None       # lost_frames.restart_lost_frames' figures, once it has run (after the alignment)
    light_search: dict | None = None    # light_search.search_light's figures, once it has run (before the light moves)
    size_anchor: float | None = None    # the size the size_prior term holds with size_anchor "alignment", once set
    depth_anchor: float | None = None   # the scene's depth the depth_prior term holds (where the alignment left it)
    after_stages_seconds: dict = dataclasses.field(default_factory=dict)   # the work after the stages, by part
    # the figures of each pass of the albedo's solves and fill after the first (fitting.solve_and_fill_again)
    albedo_passes: list = dataclasses.field(default_factory=list)
    # {settings rate name ("lr_geometry", ...): factor}: the halvings of rollbacks so far, which the stages after the
    # one that rolled back start from (a rate 10x too high otherwise diverged again at the next stage's first step)
    rate_factors: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def fresh(cls, schedule: Schedule, shadows="auto"):
        return cls(schedule=schedule, stage_seconds=[0.0] * len(schedule), shadows=ShadowDecision.requested_as(shadows))

    @property
    def finished(self) -> bool:
        return self.stage >= len(self.schedule)

    @property
    def fit_seconds(self) -> float:
        return float(sum(self.stage_seconds))

    def to_dict(self) -> dict:
        """Plain values (torch's safe loader reads them)."""
        values = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        return {**values, "schedule": self.schedule.to_list(), "shadows": dataclasses.asdict(self.shadows)}

    @classmethod
    def from_dict(cls, values) -> "FitState":
        values = dict(values)
        values["shadows"] = ShadowDecision(**values["shadows"])
        values["schedule"] = Schedule.from_list(values["schedule"])
        return cls(**values)


@dataclasses.dataclass
class Checkpoint:
    settings: FitSettings
    state: FitState
    avatar: dict                        # the Avatar's state_dict
    optimiser: dict | None              # the stage's optimiser state_dict; None at a stage's end
    generator: torch.Tensor             # torch.Generator state
    best_avatar: dict | None = None     # the Avatar's state_dict at the best validation check (validation.py)
    version: int = CHECKPOINT_VERSION   # as written; an older one can be read but not resumed


def save_checkpoint(path, checkpoint: Checkpoint) -> Path:
    path = Path(path)
    temporary = path.with_suffix(".tmp")
    torch.save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION,
                "settings": vars(checkpoint.settings), "state": checkpoint.state.to_dict(),
                "avatar": checkpoint.avatar, "optimiser": checkpoint.optimiser,
                "generator": checkpoint.generator, "best_avatar": checkpoint.best_avatar}, temporary)
    temporary.replace(path)
    return path


def load_checkpoint(path, device=None) -> Checkpoint:
    """The checkpoint at `path`; a missing, unreadable or older file is one FitError line."""
    path = Path(path)
    if not path.is_file():
        raise FitError(f"no checkpoint at {path}")
    try:
        saved = torch.load(path, map_location=device, weights_only=True)
    except Exception as error:  # truncated, not a torch file, unsafe content
        raise FitError(f"cannot read the checkpoint {path}: {str(error).splitlines()[0]}") from None
    version = saved.get("version")
    if saved.get("format") != CHECKPOINT_FORMAT or version not in READABLE_VERSIONS:
        raise FitError(f"{path} is a checkpoint of another harp version ({version}; this one reads "
                       f"{', '.join(map(str, READABLE_VERSIONS))}): fit again")
    settings, avatar, state = dict(saved["settings"]), dict(saved["avatar"]), dict(saved["state"])
    if version == 2:     # before exposure gains: they were off
        settings["exposure"] = "off"
        avatar["exposure"] = torch.zeros(len(avatar["global_orient"]), 3, dtype=avatar["global_orient"].dtype,
                                         device=avatar["global_orient"].device)
    try:
        settings = FitSettings.from_dict(settings)
    except ValueError as error:     # a newer harp's setting, or a value this one refuses
        raise FitError(f"{path} holds settings this harp cannot use ({error}): it was written by a newer "
                       "version; update harp, or fit again") from None
    if version < 4:      # the schedule in force was the settings' steps (a budget rewrote them)
        state["schedule"] = settings.schedule().to_list()
    if version < 5:      # no environment light
        for saved_avatar in (avatar, saved.get("best_avatar")):
            if saved_avatar is not None:
                _without_environment(saved_avatar)
    if version < 6:      # no specular lobe
        for saved_avatar in (avatar, saved.get("best_avatar")):
            if saved_avatar is not None:
                _without_specular(saved_avatar)
    if version < 7:      # a point light
        for saved_avatar in (avatar, saved.get("best_avatar")):
            if saved_avatar is not None:
                saved_avatar["light_angle"] = torch.zeros((), dtype=saved_avatar["ambient_logit"].dtype,
                                                          device=saved_avatar["ambient_logit"].device)
    return Checkpoint(settings, FitState.from_dict(state), avatar, saved["optimiser"], saved["generator"],
                      saved.get("best_avatar"), version)


def _without_specular(avatar_state: dict):
    """An avatar state_dict from before the specular lobe, given one at its initial values, off."""
    like = avatar_state["ambient_logit"]
    for name, value in initial_material().items():
        avatar_state[name] = torch.tensor(value, dtype=like.dtype, device=like.device)
    avatar_state["specular_on"] = torch.zeros((), dtype=torch.bool, device=like.device)


def _without_environment(avatar_state: dict):
    """An avatar state_dict from before the environment light, given one that is switched off."""
    like = avatar_state["ambient_logit"]
    avatar_state["environment"] = torch.zeros(ENVIRONMENT_COEFFICIENTS, 3, dtype=like.dtype, device=like.device)
    avatar_state["environment_on"] = torch.zeros((), dtype=torch.bool, device=like.device)
