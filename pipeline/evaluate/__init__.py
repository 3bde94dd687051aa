"""Judging fits (`harp evaluate`): held-out frames, the albedo and the poses against the truth.

    from pipeline.evaluate import evaluate_fit
    result = evaluate_fit("avatar", "clip")
"""
from .albedo import evaluate_albedo
from .evaluation import EVALUATION_FILE, evaluate_fit, summary_lines
from .finished_fit import EvaluationError
from .held_out import evaluate_held_out
from .poses import PoseScorer, evaluate_poses

__all__ = ["evaluate_fit", "summary_lines", "EVALUATION_FILE", "EvaluationError", "evaluate_held_out",
           "evaluate_albedo", "evaluate_poses", "PoseScorer"]
