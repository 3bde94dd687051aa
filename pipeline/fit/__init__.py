"""The fit (`harp fit`): an avatar fitted to a sequence folder in stages of Adam.

    from pipeline.fit import fit
    report = fit("clip", "avatar", preset="fast")
"""
from .checkpoint import CHECKPOINT_FILE, FitState, load_checkpoint
from .fitting import FitObserver, fit
from .problem import FitError, FitProblem, build_problem
from .settings import PRESETS, FitSettings, Stage, settings_for

__all__ = ["fit", "FitObserver", "FitError", "FitProblem", "build_problem", "FitSettings", "Stage", "PRESETS",
           "settings_for", "FitState", "load_checkpoint", "CHECKPOINT_FILE"]
