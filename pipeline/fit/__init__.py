"""The fit (`harp fit`): an avatar fitted to a sequence folder in stages of Adam.

    from pipeline.fit import fit
    report = fit("clip", "avatar", preset="fast")
"""
from .checkpoint import CHECKPOINT_FILE, FitState, load_checkpoint
from .fitting import FitObserver, fit
from .problem import FitError, FitProblem, build_problem
from .schedule import Schedule, StageKind, StageSpec
from .settings import PRESETS, FitSettings, settings_for

__all__ = ["fit", "FitObserver", "FitError", "FitProblem", "build_problem", "FitSettings", "Schedule", "StageKind",
           "StageSpec", "PRESETS", "settings_for", "FitState", "load_checkpoint", "CHECKPOINT_FILE"]
