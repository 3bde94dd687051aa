"""The anytime curve of a fit (`harp fit --curve`): the figures that can be had without stopping
the fit, measured at fit-time marks and written to AVATAR/curve.json (formats/fit_curve.py).

Marks are spaced evenly on a log time axis (POINTS_PER_DOUBLING per doubling of the fit's time,
from FIRST_MARK_SECONDS), plus the start (the initial estimate) and the end (the final avatar,
the same figures as report.json's). Each measurement renders every fitted frame as the final
report does (fit/outputs.py: silhouette IoU, PSNR, L1, MS-SSIM inside the mask over the
background plate) and, on a synthetic clip, scores the current poses against gt.npz
(evaluate/poses.py: Procrustes-aligned and camera-frame joint and vertex errors) and the current
albedo against the truth in the visible UV area (evaluate/albedo.py). The time it takes is
left out of the fit's time axis and reported as measure_seconds. The fit's own validation
checks (fit/validation.py, on the frames it keeps out) go beside the points as they are.

A resumed fit keeps the points measured before its checkpoint and goes on from there.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from ..fit.fitting import FitObserver
from ..fit.outputs import score_renders
from ..formats import sequence_folder as seq
from ..formats.fit_curve import CURVE_FILE, FitCurveError, read_curve, write_curve
from .albedo import albedo_error, albedo_truth
from .poses import PoseScorer

FIRST_MARK_SECONDS = 1.0
POINTS_PER_DOUBLING = 2


class CurveRecorder(FitObserver):
    """A FitObserver that writes `out`/curve.json as the fit runs."""

    def __init__(self, out, points_per_doubling=POINTS_PER_DOUBLING, first_mark_seconds=FIRST_MARK_SECONDS):
        self.out, self.factor = Path(out), 2.0 ** (1.0 / points_per_doubling)
        self.points, self.next_mark, self.seconds = [], first_mark_seconds, 0.0
        self.poses = self.albedo = None

    def start(self, problem, state):
        info = seq.read_sequence_info(problem.sequence)
        if info.ground_truth:
            self.poses = PoseScorer(problem.sequence, problem.initial)
        if info.albedo:
            self.albedo = albedo_truth(problem.sequence, problem.settings.texture_size, problem.device)
        try:  # a resumed fit keeps what was measured up to its checkpoint
            earlier = read_curve(self.out) if (self.out / CURVE_FILE).is_file() else {}
        except FitCurveError:
            earlier = {}
        self.points = [point for point in earlier.get("points", []) if point["fit_seconds"] <= state.fit_seconds]
        self.seconds = earlier.get("measure_seconds", 0.0) if self.points else 0.0
        while self.next_mark <= state.fit_seconds:
            self.next_mark *= self.factor
        if not self.points:
            self._measure(problem, state)

    def step(self, problem, state):
        if state.fit_seconds >= self.next_mark:
            self._measure(problem, state)
            while self.next_mark <= state.fit_seconds:
                self.next_mark *= self.factor

    def end(self, problem, state):
        self._measure(problem, state)

    @torch.no_grad()
    def _measure(self, problem, state):
        started = time.perf_counter()
        point = {"fit_seconds": state.fit_seconds,
                 "stage": "done" if state.finished else state.schedule[state.stage].name, "step": state.step}
        _, _, scores = score_renders(problem, bool(state.shadows.on))
        point.update(silhouette_iou_mean=float(np.mean(scores["silhouette_iou"])),
                     silhouette_iou_min=scores["silhouette_iou_min"], psnr_mean=scores["psnr_mean"],
                     l1_mean=scores["l1_mean"])
        if "ms_ssim_mean" in scores:
            point["ms_ssim_mean"] = scores["ms_ssim_mean"]
        if self.poses is not None:
            errors = self.poses.avatar_errors(problem.avatar, problem.frames)
            point.update(joint_mm=errors["joints"]["procrustes_mm_mean"],
                         joint_camera_mm=errors["joints"]["camera_mm_mean"])
            if "vertices" in errors:
                point.update(vertex_mm=errors["vertices"]["procrustes_mm_mean"],
                             vertex_camera_mm=errors["vertices"]["camera_mm_mean"])
        if self.albedo is not None:
            fitted = problem.avatar.albedo.detach().clamp(0, 1).permute(1, 2, 0).cpu().double().numpy()
            error = albedo_error(fitted, self.albedo.image, self.albedo.visible)
            point.update(albedo_mae=error["mae"], albedo_psnr=error["psnr"])
        self.points.append(point)
        self.seconds += time.perf_counter() - started
        write_curve(self.out, {"sequence": str(problem.sequence), "preset": problem.settings.preset,
                               "frames": len(problem.frames), "measure_seconds": self.seconds,
                               "points": self.points, "validation": list(state.validation)})
