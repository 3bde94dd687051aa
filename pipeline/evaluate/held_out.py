"""Held-out frames: the avatar judged on frames its fit never saw (method_facts.md, "Evaluation").

The fit (fit(..., hold_out_every=N)) leaves them out and lists them in report.json. Here the
fit problem is built over them (fit/problem.py, the fit's own builder and settings) with shape,
displacements and textures taken from the fit's checkpoint and frozen (appearance is never
fitted on them), the light taken from it and fitted. One stage of the fit's own steps
(fit/stage_run.py), a stage of kind HELD_OUT with every held-out frame in every step, minimises
the energy terms that count in that kind (fit/energy_terms.py: silhouette, keypoint anchor,
photometric and perceptual) with the fit's weights. Self-shadowing is as the fit decided. Then
PSNR and L1 in the mask, MS-SSIM and silhouette IoU per frame and mean (fit/outputs.image_scores).

Two protocols differ in where the poses start and how long they are refined:
- "neighbours" (the default): from the fitted poses of each frame's temporal neighbours
  (fit/pose_interpolation.py), or from its keypoint estimate where that explains the frame
  better (across a fast turn the neighbours' pose can lie on the wrong side), refined until the
  loss stops falling (less than CONVERGED_FRACTION over CONVERGED_WINDOW steps) or a cap: the
  figure measures the avatar's appearance, not how far a pose search gets from the keypoints.
- "keypoints" (the protocol before it, kept for continuity): from init.npz, a fixed number of steps.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from ..fit.avatar import LIGHT, MATERIAL, POSE, SHAPE, SWITCHES, TEXTURES, Avatar
from ..fit.checkpoint import FitState
from ..fit.clip_data import mask_at_size
from ..fit.pose_interpolation import start_from_neighbours
from ..fit.outputs import image_scores, score_renders, write_grid
from ..fit.progress import Progress
from ..fit.problem import build_problem, default_device
from ..fit.energy_terms import ENERGY_TERMS
from ..fit.schedule import Schedule, StageKind, StageSpec
from ..fit.stage_run import StageRun
from ..formats.fit_report import HELD_OUT_FRAMES
from ..formats.initial_estimate import read_initial_estimate
from .finished_fit import EvaluationError, load_finished_fit

HELD_OUT_TERMS = tuple(name for name, term in ENERGY_TERMS.items() if StageKind.HELD_OUT in term.stages)
# taken from the fit, never changed (the point light is taken, then fitted). The environment light is the
# room's and stays as fitted: refined on a few held-out frames its 24 coefficients ran off (exact room clip,
# frames 4 and 9: to 2-3 times their fitted size, held-out PSNR 25.30 dB against 25.87 with them kept)
FROZEN = SHAPE + TEXTURES + MATERIAL + ("environment",)   # the specular lobe is the skin's: as fitted
PROTOCOLS = ("neighbours", "keypoints")
ANCHOR_TERM = "keypoint_anchor"   # held towards the keypoint start: no judge of which start is better
KEYPOINT_PROTOCOL_STEPS = 100   # the keypoints protocol's fixed steps
CONVERGED_WINDOW = 10           # the neighbours protocol stops when the mean loss of the last window
CONVERGED_FRACTION = 1e-3       # fell by less than this fraction from the window before it


@dataclasses.dataclass
class HeldOutResult:
    frames: np.ndarray        # (K,) sequence frame indices
    metrics: dict             # image_scores after fitting pose and light (+ silhouette_iou_mean)
    metrics_before: dict      # the same at the initial estimate with the fit's light
    loss_before: float        # held-out energy (HELD_OUT_TERMS, the fit's weights) over all K frames
    loss_after: float
    history: list             # per step: loss and terms before the step's update
    events: list
    shadows: bool
    avatar: Avatar            # its per-frame parameters are the held-out frames'
    protocol: str = "neighbours"
    converged: bool = False   # the neighbours protocol stopped on its own, before its cap
    metrics_in_reference: dict | None = None   # the final renders scored in `reference_masks` (when given)
    started_from_keypoints: np.ndarray | None = None   # neighbours protocol: (K,) bool, frames begun at init.npz

    def to_json(self):
        return {"frames": self.frames.tolist(), "protocol": self.protocol, "steps": len(self.history),
                "converged": self.converged,
                **({} if self.started_from_keypoints is None else
                   {"started_from_keypoints": np.asarray(self.frames)[self.started_from_keypoints].tolist()}),
                "terms": list(HELD_OUT_TERMS),
                "loss_before": self.loss_before, "loss_after": self.loss_after,
                "loss_history": [entry["loss"] for entry in self.history], "shadows": self.shadows,
                "events": self.events, "metrics": self.metrics, "metrics_before": self.metrics_before,
                **({} if self.metrics_in_reference is None else {"metrics_in_reference": self.metrics_in_reference})}


def evaluate_held_out(fit_folder, sequence, frames=None, steps=300, device=None, progress="none",
                      picture=None, protocol="neighbours", stage_factors=None, reference_masks=None) -> HeldOutResult:
    """Fit pose, translation and light to frames the fit left out (default: the report's
    held-out frames), appearance and shape frozen; score them before and after. `protocol`
    (PROTOCOLS): "neighbours" starts from the fitted neighbours' poses (or the keypoints', frame by
    frame, where those explain the frame better) and refines until the loss
    stops falling, at most `steps` steps; "keypoints" starts from init.npz and takes exactly
    `steps`. `progress`: "bar", "jsonl" or "none" (fit/progress.py); `picture`: a PNG path for
    the held-out frames as the fit's grid shows its own (input, render, difference).
    `stage_factors` ({term: {stage kind value: factor}}) are laid over the fit's own, to score one
    fit under other weights (benchmarks/bench_held_out_weights.py). `reference_masks` ((K, H, W)
    arrays at the sequence's size, e.g. masks a person drew for these frames): the final renders
    are also scored inside them, shrunk to the working size as the clip's own masks are
    (metrics_in_reference); the poses are still fitted to the sequence's own masks."""
    if protocol not in PROTOCOLS:
        raise EvaluationError(f"held-out protocol {protocol!r}: choose one of {', '.join(PROTOCOLS)}")
    device = default_device(device)
    saved, report = load_finished_fit(fit_folder, device)
    frames = np.asarray(report.get(HELD_OUT_FRAMES, []) if frames is None else frames, dtype=np.int64)
    if steps < 0:
        raise EvaluationError(f"held-out steps must be 0 or more, got {steps}")
    if not len(frames):
        raise EvaluationError(f"the fit in {fit_folder} held out no frames (fit with hold_out_every=N)")
    count = read_initial_estimate(sequence).frame_count
    if frames.min() < 0 or frames.max() >= count:
        raise EvaluationError(f"held-out frames {frames.tolist()} outside the clip's {count} frames")
    settings = saved.settings
    if stage_factors:
        settings = dataclasses.replace(settings, stage_factors={**settings.stage_factors, **stage_factors})
    problem = build_problem(Path(sequence), settings, frames, device,
                            shared={name: saved.avatar[name] for name in FROZEN + LIGHT + SWITCHES}, frozen=FROZEN)
    problem.avatar.occlusion = settings.occlusion_drawn      # the finished avatar's shading
    shadows = bool(saved.state.shadows.on)
    schedule = Schedule((StageSpec(StageKind.HELD_OUT, steps),))

    def fresh_run():
        state = FitState.fresh(schedule, "on" if shadows else "off")
        return StageRun(problem, schedule[0], state, torch.Generator().manual_seed(settings.seed)), state

    started_from_keypoints = None            # the keypoints protocol: every frame, by definition
    if protocol == "neighbours":
        started_from_keypoints = _start_from_neighbours_or_keypoints(fresh_run()[0], saved.avatar, report["frames"],
                                                                     frames)
    run, state = fresh_run()    # made at the chosen start: a rollback returns there, not to the keypoints

    def loss_and_scores():
        with torch.no_grad():
            loss, _ = run.energy(problem.all_frames(), backward=False)
        rgb, alpha, scores = score_renders(problem, shadows)
        return loss, with_mean_iou(scores), rgb, alpha

    loss_before, metrics_before, _, _ = loss_and_scores()
    converged = False
    with Progress(progress, steps) as bar:
        while run.has_work and not run.finished and not converged:
            run.step()
            bar.update("held-out frames", len(state.history), state.history[-1]["loss"] if state.history else float("nan"))
            converged = protocol == "neighbours" and loss_converged([entry["loss"] for entry in state.history])
    loss_after, metrics, rgb, alpha = loss_and_scores()
    if picture is not None:
        write_grid(picture, problem.clip, rgb)
    in_reference = None
    if reference_masks is not None:
        reference_masks = np.asarray(reference_masks)
        info = problem.clip.info
        if reference_masks.shape != (len(frames), info.height, info.width):
            raise EvaluationError(f"reference masks of shape {reference_masks.shape} for {len(frames)} held-out frames "
                                  f"of {info.width}x{info.height}")
        size = (problem.clip.width, problem.clip.height)
        masks = np.stack([mask_at_size(mask > 0.5, size) for mask in reference_masks])
        reference = dataclasses.replace(problem.clip, masks=torch.as_tensor(masks[..., None], dtype=rgb.dtype,
                                                                            device=rgb.device))
        in_reference = with_mean_iou(image_scores(rgb, alpha, reference, problem.silhouette_weight))
    return HeldOutResult(frames, metrics, metrics_before, loss_before, loss_after, state.history, state.events,
                         shadows, problem.avatar, protocol, converged, in_reference, started_from_keypoints)


@torch.no_grad()
def _start_from_neighbours_or_keypoints(run, fitted, fitted_frames, frames) -> np.ndarray:
    """Start each held-out frame from its fitted neighbours' interpolated pose or from its keypoint
    estimate (init.npz, as the problem was built), whichever has the lower held-out energy there;
    (K,) bool: the frames started from the keypoints. The neighbours' pose is the better start where
    the hand moves smoothly; across a fast turn (the phone-like clip's flip, frame 9) it can lie on
    the wrong side and the refinement never gets back (16.8 dB against 24.5 from the keypoints)."""
    avatar = run.problem.avatar
    from_keypoints = {name: getattr(avatar, name).detach().clone() for name in POSE}
    keypoint_losses = _frame_energies(run)
    start_from_neighbours(avatar, fitted, fitted_frames, frames)
    better = keypoint_losses < _frame_energies(run)
    for name, value in from_keypoints.items():
        target = getattr(avatar, name)
        where = torch.as_tensor(better, device=target.device).view((-1,) + (1,) * (target.dim() - 1))
        target.copy_(torch.where(where, value, target))
    return better


def _frame_energies(run) -> np.ndarray:
    """(K,) the held-out energy of each frame on its own, as the problem's avatar stands, less
    the keypoint anchor's share (which measures the distance from the keypoint start itself)."""
    frames = run.problem.all_frames()
    anchor = ENERGY_TERMS[ANCHOR_TERM].weight_in(run.problem.settings, StageKind.HELD_OUT)
    energies = []
    for i in range(len(frames)):
        loss, terms = run.energy(frames[i:i + 1], backward=False)
        energies.append(float(loss) - anchor * terms.get(ANCHOR_TERM, 0.0))
    return np.array(energies)


def with_mean_iou(scores) -> dict:
    return {**scores, "silhouette_iou_mean": float(np.mean(scores["silhouette_iou"]))}


def loss_converged(losses, window=CONVERGED_WINDOW, fraction=CONVERGED_FRACTION) -> bool:
    """Whether the mean of the last `window` losses fell by less than `fraction` of the mean of
    the window before it (not yet two windows: no)."""
    if len(losses) < 2 * window:
        return False
    before, last = np.mean(losses[-2 * window:-window]), np.mean(losses[-window:])
    return bool(before - last < fraction * abs(before))
