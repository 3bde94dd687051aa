"""The fit: three stages of Adam over the avatar (appendix C.3), with checkpoints, resume,
rollback on non-finite losses, progress and the scene adaptations (mode, shadows, frames).

Only this module knows about stages; the energy terms are plain functions (losses.py).
"""
from __future__ import annotations

import copy
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..formats.initial_estimate import read_initial_estimate
from ..formats.sequence_folder import validate_sequence_folder
from ..handmodel.lbs import HandModel
from ..handmodel.uv_atlas import uv_mask as atlas_mask
from ..render.antialias import edge_topology
from .avatar import APPEARANCE, Avatar
from .clip_data import load_clip
from .energy import batch_energy
from .held_out import held_out_frames, record_held_out
from .perceptual import perceptual_term
from .settings import settings_for

CHECKPOINT_FILE = "checkpoint.pt"
SHADOW_AMBIENT_THRESHOLD = 0.75   # a fitted ambient ratio below this means a dominant light
ROLLBACK_EVERY = 20
ALIGN_CHUNK_FRAMES = 32   # frames rendered at once in the alignment's full batches
DIVERGENCE_FACTOR = 1.5   # a full-batch loss this much above the best so far counts as divergence


class FitError(ValueError):
    """The fit cannot start or continue (one-line message)."""


def select_frames(count, maximum, exclude=()):
    """Evenly spaced frame indices (all of them when the clip is short enough): an even spread
    over time keeps the clip's coverage of views for flipping and turning motions. Frames in
    `exclude` (held out for evaluation, held_out.py) are never chosen."""
    candidates = np.setdiff1d(np.arange(count), np.asarray(exclude, dtype=np.int64))
    if len(candidates) <= maximum:
        return candidates
    return candidates[np.unique(np.round(np.linspace(0, len(candidates) - 1, maximum)).astype(int))]


class Progress:
    """tqdm on a terminal, or JSON lines (for the Blender add-on), or nothing."""

    def __init__(self, kind, total):
        self.kind, self.total, self.done, self.start = kind, total, 0, time.time()
        self.bar = None
        if kind == "bar":
            from tqdm import tqdm
            self.bar = tqdm(total=total, unit="step", dynamic_ncols=True)

    def update(self, stage, step, loss):
        self.done += 1
        elapsed = time.time() - self.start
        left = elapsed / self.done * (self.total - self.done)
        if self.bar is not None:
            self.bar.set_description(stage)
            self.bar.set_postfix(loss=f"{loss:.4f}")
            self.bar.update(1)
        elif self.kind == "jsonl" and (self.done % 10 == 0 or self.done == self.total):
            print(json.dumps({"event": "progress", "stage": stage, "step": step, "loss": loss,
                              "done": self.done, "total": self.total, "seconds_left": round(left, 1)}), flush=True)

    def log(self, message):
        if self.kind == "jsonl":
            print(json.dumps({"event": "log", "message": message}), flush=True)
        elif self.bar is not None:
            self.bar.write(message)
        else:
            print(message, file=sys.stderr)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def fit(sequence, out, preset="fast", resume=False, progress="bar", device=None, shadows="auto",
        max_steps=None, hold_out_every=None, **overrides):
    """Fit an avatar to a sequence folder with an init.npz; writes `out` and returns the report.
    hold_out_every=N leaves every N-th frame out of the fit (held_out.py) for held-out evaluation."""
    sequence, out = Path(sequence), Path(out)
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    validate_sequence_folder(sequence)
    initial = read_initial_estimate(sequence)
    settings = settings_for(preset, initial.frame_count, shadows=shadows, **overrides)
    if max_steps is not None:  # for tests: cap every stage
        settings.steps = tuple(min(s, max_steps) for s in settings.steps)
        settings.align_steps = min(settings.align_steps, max_steps)
    held_out = held_out_frames(initial.frame_count, hold_out_every)
    frames = select_frames(initial.frame_count, settings.max_frames, exclude=held_out)
    clip = load_clip(sequence, settings.resolution, frames, device=device)
    out.mkdir(parents=True, exist_ok=True)
    model = HandModel.load(initial.mode, initial.side, subdivided=True, device=device)
    coarse_model = HandModel.load(initial.mode, initial.side, subdivided=False, device=device)
    avatar = Avatar(model, initial, frames, settings.texture_size, coarse_model=coarse_model)
    torch.manual_seed(settings.seed)
    generator = torch.Generator().manual_seed(settings.seed)
    topology = edge_topology(avatar.mesh.faces)
    edges = topology.edges
    face_pairs = topology.faces[topology.faces[:, 1] >= 0]
    with torch.no_grad():
        initial_vertices, initial_keypoints = avatar.posed(torch.arange(len(frames), device=device))
    initial_keypoints = initial_keypoints[:, :21].detach()
    uv_mask = torch.as_tensor(atlas_mask(model.data.uvs, model.data.faces_uv, settings.texture_size),
                              device=device, dtype=clip.images.dtype)
    perceptual_name, perceptual = ("off (weight 0)", None) if settings.weights.get("perceptual", 0.0) == 0.0 \
        else perceptual_term(settings.perceptual_weights, device)
    stages = settings.stages()
    state = {"stage": 0, "step": 0, "history": [], "events": [], "stage_seconds": [0.0] * len(stages),
             "shadows": {"auto": None, "decided": settings.shadows != "auto", "on": settings.shadows == "on"}}
    checkpoint_path = out / CHECKPOINT_FILE
    optimiser_state = None
    if resume:
        if not checkpoint_path.is_file():
            raise FitError(f"nothing to resume: no {checkpoint_path}")
        saved = torch.load(checkpoint_path, map_location=device, weights_only=False)
        avatar.load_state_dict(saved["avatar"])
        state.update(saved["state"])
        optimiser_state = saved["optimiser"]
        generator.set_state(saved["generator"])
    reporter = Progress(progress, sum(s.steps for s in stages) - sum(s.steps for s in stages[:state["stage"]]) - state["step"])
    reporter.log(f"fitting {len(frames)} frames ({initial.mode} mode, {initial.side} hand) with preset "
                 f"{preset}, perceptual term {perceptual_name}; expected time {settings.expected_seconds(len(frames)) / 60:.1f} min on {device}")
    interrupted = {"flag": False}
    previous_handler = signal.signal(signal.SIGINT, lambda *_: interrupted.__setitem__("flag", True))

    def save_checkpoint(optimiser):
        """optimiser None at a stage's end: the next stage starts a fresh one."""
        temporary = checkpoint_path.with_suffix(".tmp")
        torch.save({"avatar": avatar.state_dict(), "state": state,
                    "optimiser": None if optimiser is None else optimiser.state_dict(),
                    "generator": generator.get_state(), "settings": vars(settings)}, temporary)
        temporary.replace(checkpoint_path)

    try:
        for stage_index in range(state["stage"], len(stages)):
            stage = stages[stage_index]
            optimiser = _optimiser(avatar, stage, settings)
            if optimiser_state is not None:
                optimiser.load_state_dict(optimiser_state)
                optimiser_state = None
            last_good = _snapshot(avatar, optimiser)
            best_loss = float("inf")
            last_save = time.time()
            stage_start = time.time() - state["stage_seconds"][stage_index]
            order = state.pop("order", [])
            while state["step"] < stage.steps:
                if interrupted["flag"]:
                    state["order"] = order
                    state["stage_seconds"][stage_index] = time.time() - stage_start
                    save_checkpoint(optimiser)
                    reporter.log(f"interrupted: saved {checkpoint_path}; continue with --resume")
                    raise KeyboardInterrupt
                if not order:
                    order = torch.randperm(len(frames), generator=generator).tolist()
                size = len(frames) if stage.coarse else settings.batch_size
                batch = torch.tensor(order[:size], device=device)
                order = order[size:]
                shadows_on = stage.appearance and state["shadows"]["on"]
                optimiser.zero_grad(set_to_none=True)
                # a long clip's full batch is rendered in chunks; their gradients add up
                loss, terms = 0.0, {}
                for chunk in batch.split(ALIGN_CHUNK_FRAMES):
                    share = len(chunk) / len(batch)
                    part, part_terms = batch_energy(avatar, clip, chunk, settings, stage, initial_keypoints,
                                                    initial_vertices, edges, face_pairs, perceptual, uv_mask,
                                                    shadows_on, generator)
                    if torch.isfinite(part):
                        (part * share).backward()
                    loss = loss + part.detach() * share
                    terms = {name: terms.get(name, 0.0) + value * share for name, value in part_terms.items()}
                if torch.isfinite(loss):
                    _mask_frozen_gradients(avatar)
                    _lazy_step(avatar, optimiser, batch)
                diverged = stage.coarse and loss.item() > DIVERGENCE_FACTOR * best_loss  # full batches: comparable
                best_loss = min(best_loss, loss.item()) if torch.isfinite(loss) else best_loss
                if not torch.isfinite(loss) or not _finite(avatar) or diverged:
                    _restore(avatar, optimiser, last_good)
                    for group in optimiser.param_groups:
                        group["lr"] *= 0.5
                    problem = f"loss rose to {loss.item():.4g} from {best_loss:.4g}" if diverged else "non-finite loss"
                    message = f"{problem} at {stage.name} step {state['step']}: rolled back, learning rates halved"
                    state["events"].append(message)
                    reporter.log(message)
                    state["step"] += 1
                    continue
                state["step"] += 1
                if state["step"] % ROLLBACK_EVERY == 0:
                    last_good = _snapshot(avatar, optimiser)
                state["history"].append({"stage": stage.name, "step": state["step"], "loss": loss.item(), **terms})
                reporter.update(stage.name, state["step"], loss.item())
                if stage.name == "geometry+appearance" and not state["shadows"]["decided"] \
                        and state["step"] >= stage.steps // 2:
                    _decide_shadows(avatar, state, reporter)
                if time.time() - last_save > settings.checkpoint_seconds:
                    state["order"] = order
                    state["stage_seconds"][stage_index] = time.time() - stage_start
                    save_checkpoint(optimiser)
                    state.pop("order")
                    last_save = time.time()
            state["stage_seconds"][stage_index] = time.time() - stage_start
            state["stage"], state["step"] = stage_index + 1, 0
            save_checkpoint(None)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        reporter.close()
    from .outputs import write_outputs

    report = write_outputs(out, sequence, avatar, clip, settings, state, initial, perceptual_name)
    return record_held_out(out, report, held_out)


def _optimiser(avatar, stage, settings):
    groups = []
    if stage.coarse:  # rotations and translations at their own rates; no displacements yet
        groups.append({"params": [avatar.global_orient, avatar.pose], "lr": settings.lr_align_rotation})
        groups.append({"params": [avatar.transl], "lr": settings.lr_align_translation})
        groups.append({"params": [avatar.betas], "lr": settings.lr_betas})
    elif stage.geometry:
        groups.append({"params": avatar.parameter_group(PER_FRAME), "lr": settings.lr_geometry})
        groups.append({"params": [avatar.betas], "lr": settings.lr_betas})
        groups.append({"params": [avatar.displacement], "lr": settings.lr_displacement})
    if stage.appearance:
        groups.append({"params": avatar.parameter_group(APPEARANCE), "lr": settings.lr_appearance})
    return torch.optim.Adam(groups)


PER_FRAME = ("global_orient", "transl", "pose")


def _lazy_step(avatar, optimiser, batch):
    """Adam step that leaves the per-frame parameters of frames outside the batch untouched,
    values and moments alike (otherwise stale momentum keeps moving them: a "lazy" Adam)."""
    outside = torch.ones(avatar.pose.shape[0], dtype=torch.bool, device=batch.device)
    outside[batch] = False
    saved = []
    for name in PER_FRAME:
        parameter = getattr(avatar, name)
        moments = optimiser.state.get(parameter, {})
        saved.append((parameter, parameter.data[outside].clone(),
                      {k: v[outside].clone() for k, v in moments.items() if torch.is_tensor(v) and v.dim() > 0}))
    optimiser.step()
    for parameter, values, moments in saved:
        parameter.data[outside] = values
        for key, value in moments.items():
            optimiser.state[parameter][key][outside] = value


def _mask_frozen_gradients(avatar):
    if avatar.pose.grad is not None:
        avatar.pose.grad *= avatar.pose_mask


def _finite(avatar):
    return all(bool(torch.isfinite(p).all()) for p in avatar.parameters())


def _snapshot(avatar, optimiser):
    return copy.deepcopy(avatar.state_dict()), copy.deepcopy(optimiser.state_dict())


def _restore(avatar, optimiser, snapshot):
    learning_rates = [group["lr"] for group in optimiser.param_groups]
    avatar.load_state_dict(snapshot[0])
    optimiser.load_state_dict(snapshot[1])
    for group, lr in zip(optimiser.param_groups, learning_rates):
        group["lr"] = lr


def _decide_shadows(avatar, state, reporter):
    """Self-shadowing pays off under a dominant light: decide from the fitted ambient ratio."""
    ambient = avatar.ambient.item()
    on = ambient < SHADOW_AMBIENT_THRESHOLD
    state["shadows"].update(auto=True, decided=True, on=on, ambient_at_decision=ambient)
    reporter.log(f"shadows auto: fitted ambient ratio {ambient:.2f} -> self-shadowing {'on' if on else 'off'}")
