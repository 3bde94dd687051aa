"""Fit the hand model to per-frame 2D keypoints: the initial estimate of `harp init`.

HARP (appendix C.2) fits its template to a pose estimator's meshes, rigid first, then pose and
shape, re-running a fit whose residual stays above 1 cm, then smooths over time. Here the
estimator gives 2D keypoints (MediaPipe or a file) and, from MediaPipe, metric 3D landmarks:

1. rigid, per frame: the average flat hand's palm keypoints (wrist, thumb base, four knuckles)
   are rotated by each of a fixed set of rotations (plus the rotation that aligns them with
   MediaPipe's 3D landmarks), the translation follows in closed form from the projection
   equations (depth from the hand's size and K), and the rotation with the smallest 2D residual
   is refined by Adam;
2. pose and shape: per-frame rotation, translation and finger joint rotations and one shape for
   the clip, by Adam over all frames at once: robust 2D reprojection, MediaPipe's metric
   landmarks rotated onto the estimate (their articulation, not their orientation), joint-limit
   prior, small pose and shape priors. Each frame is fitted twice side by side, from the rigid
   result and from it with the palm turned over (the 2D palm is nearly planar, so both can fit
   it), and the better kept;
3. a pass over the clip with a temporal smoothness term; a frame whose residual stays high is
   fitted again from its nearest better neighbour's pose and from its palm flip, the better
   result kept;
4. smoothing: the same with a stronger temporal term (and another restart check).

Poses are HandModel's (local axis-angles; global_orient about the wrist; transl the wrist's
position in the camera frame, metres). The wrist joint (pose[:, 0]) stays 0: keypoints do not
see the forearm, so in arm mode the forearm starts in line with the hand.

The model's keypoints stand for the landmarks; with `landmark_offsets`, MediaPipe's landmarks
are compared with the keypoints moved to where MediaPipe puts them (landmark_offsets.py).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from ..formats.initial_estimate import InitialEstimate
from ..handmodel.joint_limits import joint_limit_penalty
from ..handmodel.lbs import HandModel
from ..handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..render.rasterize import project
from .landmark_offsets import on_mediapipe_landmarks

PALM = [0, 1, 5, 9, 13, 17]        # keypoints that move little with the fingers
UNIT_M = 0.1                       # 3D distances in units of 10 cm (as HARP's anchor term)


@dataclasses.dataclass
class InitialFitSettings:
    rigid_candidates: int = 512     # rotations tried per frame in the rigid stage
    rigid_steps: int = 100
    pose_steps: int = 300
    restart_steps: int = 150
    smooth_steps: int = 100
    learning_rate: float = 0.02     # Adam, radians (rotations) and betas
    translation_lr_scale: float = 0.1   # translation steps in metres: learning_rate times this
    huber_delta: float = 0.03       # robust 2D term: fraction of the hand's size in the image
    undetected_weight: float = 0.2  # weight of interpolated frames' 2D keypoints
    weight_2d: float = 1.0
    weight_3d: float = 0.1          # MediaPipe landmarks, rotated onto the estimate (squared, 10 cm units)
    weight_joint_limits: float = 1.0
    weight_pose: float = 0.03       # squared radians, keeps unseen joints near the flat hand
    flexion_prior_scale: float = 0.1  # pose prior on flexion (local x) relative to twist/deviation
    weight_shape: float = 1e-3      # squared betas
    weight_temporal: float = 0.3    # squared frame-to-frame keypoint motion (10 cm units)
    smooth_temporal: float = 1.0    # temporal weight of the last pass
    restart_factor: float = 2.0     # restart frames with residual > factor * median ...
    restart_min_fraction: float = 0.05  # ... and > this fraction of the hand's size in pixels
    seed: int = 0
    # the 2D keypoints (and 3D landmarks) taken for MediaPipe's landmarks and compared where they
    # sit on the model (landmark_offsets.py), not for its keypoints: off by default, measured
    # (docs/initialisation.md): the phone-like clip's avatar gains, the demo's loses
    landmark_offsets: bool = False


def model_keypoints(model: HandModel, betas, pose):
    """(B, 21, 3) keypoints in the model frame (global_orient 0, transl 0): the posed keypoints
    of HandModel.forward without the vertices (the fit needs no mesh)."""
    _, joints, keypoints = model.shaped(betas)
    zero = torch.zeros(pose.shape[0], 3, dtype=pose.dtype)
    carriers = model.bone_transforms(joints, pose, zero, zero)[:, model.keypoint_joints]
    return ((carriers[..., :3] @ keypoints[..., None])[..., 0] + carriers[..., 3])[:, :21]


def solve_translation(points, pixels, K):
    """Translations t (B, 3) minimising the algebraic projection error of points + t.

    points (B, N, 3) camera-frame positions before translation, pixels (B, N, 2), K (3, 3).
    Each point gives fx (x + tx) - (u - cx)(z + tz) = 0 and fy (y + ty) - (v - cy)(z + tz) = 0,
    linear in t; solved by least squares (normal equations)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    du, dv = pixels[..., 0] - cx, pixels[..., 1] - cy
    zeros, fxs, fys = torch.zeros_like(du), torch.full_like(du, float(fx)), torch.full_like(du, float(fy))
    rows = torch.cat([torch.stack([fxs, zeros, -du], -1), torch.stack([zeros, fys, -dv], -1)], dim=1)
    rhs = torch.cat([du * points[..., 2] - fx * points[..., 0], dv * points[..., 2] - fy * points[..., 1]], dim=1)
    normal = rows.transpose(1, 2) @ rows
    return torch.linalg.solve(normal, (rows.transpose(1, 2) @ rhs[..., None]))[..., 0]


def kabsch(source, target):
    """Rotations (B, 3, 3) that best map centred source (B, N, 3) onto centred target (B, N, 3)."""
    source = source - source.mean(1, keepdim=True)
    target = target - target.mean(1, keepdim=True)
    u, _, vh = torch.linalg.svd(target.transpose(1, 2) @ source)
    d = torch.sign(torch.linalg.det(u @ vh))
    fix = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return u @ fix @ vh


def random_rotations(count, generator, dtype=torch.float64):
    """(count, 3, 3) rotations uniformly distributed (random unit quaternions)."""
    q = torch.randn(count, 4, generator=generator, dtype=dtype)
    w, x, y, z = (q / q.norm(dim=1, keepdim=True)).unbind(1)
    return torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], 1).reshape(count, 3, 3)


def palm_flip(rotation):
    """The rotation with the hand turned 180 degrees about its long axis (model y, wrist to fingers)."""
    flip = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=rotation.dtype))
    return rotation @ flip


def _reprojection(points, pixels, K):
    """(B, N) pixel distances of camera-frame points (B, N, 3) to pixels (B, N, 2)."""
    return (project(points, K) - pixels).norm(dim=-1)


def rigid_initialisation(model, pixels, K, world=None, settings=None):
    """Per-frame rotation (F, 3, 3) and translation (F, 3) of the average flat hand from 2D
    keypoints (F, 21, 2) and optionally MediaPipe's world landmarks (F, 21, 3)."""
    settings = settings or InitialFitSettings()
    dtype = torch.float64
    frames = pixels.shape[0]
    generator = torch.Generator().manual_seed(settings.seed)
    rest = model_keypoints(model, torch.zeros(model.num_betas, dtype=dtype), torch.zeros(1, 16, 3, dtype=dtype))[0]
    palm = rest[PALM]
    candidates = random_rotations(settings.rigid_candidates, generator)
    candidates = candidates.expand(frames, -1, -1, -1)
    if world is not None:
        aligned = kabsch(palm.expand(frames, -1, -1), world[:, PALM])
        candidates = torch.cat([aligned[:, None], palm_flip(aligned)[:, None], candidates], dim=1)
    count = candidates.shape[1]
    rotated = torch.einsum("fcij,nj->fcni", candidates, palm).reshape(frames * count, len(PALM), 3)
    targets = pixels[:, PALM].repeat_interleave(count, dim=0)
    transl = solve_translation(rotated, targets, K)
    placed = rotated + transl[:, None]
    error = _reprojection(placed, targets, K).mean(-1)
    error = torch.where(placed[..., 2].min(-1).values > 0.02, error, torch.full_like(error, float("inf")))
    best = error.reshape(frames, count).argmin(1)
    rotation = candidates[torch.arange(frames), best]
    transl = transl.reshape(frames, count, 3)[torch.arange(frames), best]
    # refine on the palm keypoints
    delta = torch.zeros(frames, 3, dtype=dtype, requires_grad=True)
    shift = torch.zeros(frames, 3, dtype=dtype, requires_grad=True)
    optimiser = torch.optim.Adam([{"params": [delta], "lr": settings.learning_rate},
                                  {"params": [shift], "lr": settings.learning_rate * settings.translation_lr_scale}])
    scale = _hand_size_px(pixels)
    for _ in range(settings.rigid_steps):
        optimiser.zero_grad()
        points = palm @ (axis_angle_to_matrix(delta) @ rotation).transpose(1, 2) + (transl + shift)[:, None]
        loss = (_reprojection(points, pixels[:, PALM], K) / scale).square().mean()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        return axis_angle_to_matrix(delta) @ rotation, transl + shift


def _hand_size_px(pixels):
    """Clip-wide hand size in pixels: median diagonal of the keypoints' bounding boxes."""
    diagonal = (pixels.amax(1) - pixels.amin(1)).norm(dim=-1)
    return diagonal.median().clamp(min=1.0)


class _ClipFit:
    """Parameters and energy of the pose-and-shape stage for a batch of frame hypotheses."""

    def __init__(self, model, pixels, K, weights, world, rotation, transl, pose, betas, settings, frame_index):
        self.model, self.pixels, self.K, self.weights, self.world = model, pixels, K, weights, world
        self.settings, self.frame_index = settings, frame_index
        self.rotation0 = rotation
        self.delta = torch.zeros(len(rotation), 3, dtype=rotation.dtype, requires_grad=True)
        self.transl = transl.clone().requires_grad_(True)
        self.pose = pose[:, 1:].clone().requires_grad_(True)
        self.betas = betas.clone().requires_grad_(True)
        self.scale = _hand_size_px(pixels)

    def parameter_groups(self, shape=True):
        """Adam groups: rotations in radians, translation in metres, shape in betas."""
        lr = self.settings.learning_rate
        groups = [{"params": [self.delta, self.pose], "lr": lr},
                  {"params": [self.transl], "lr": lr * self.settings.translation_lr_scale}]
        return groups + ([{"params": [self.betas], "lr": lr}] if shape else [])

    def full_pose(self):
        return torch.cat([torch.zeros_like(self.pose[:, :1]), self.pose], dim=1)

    def rotation(self):
        return axis_angle_to_matrix(self.delta) @ self.rotation0

    def keypoints(self):
        """(B, 21, 3) camera-frame keypoints."""
        local = model_keypoints(self.model, self.betas, self.full_pose())
        return local @ self.rotation().transpose(1, 2) + self.transl[:, None]

    def residual_px(self):
        with torch.no_grad():
            return _reprojection(self.keypoints(), self.pixels, self.K).mean(-1)

    def energy(self, temporal_weight):
        """(B,) per-hypothesis energy and the clip-wide temporal + shape terms (scalar)."""
        s = self.settings
        points = self.keypoints()
        distance = _reprojection(points, self.pixels, self.K) / self.scale
        delta = s.huber_delta
        robust = torch.where(distance < delta, 0.5 * distance ** 2, delta * (distance - 0.5 * delta)) / delta
        per_frame = s.weight_2d * self.weights * robust.mean(-1)
        if self.world is not None and s.weight_3d > 0:
            # MediaPipe's landmarks carry the articulation well and the orientation poorly
            # (measured 5 - 25 degrees off): compare after rotating them onto the estimate
            relative = (points - points.mean(1, keepdim=True)) / UNIT_M
            target = (self.world - self.world.mean(1, keepdim=True)) / UNIT_M
            with torch.no_grad():
                target = target @ kabsch(target, relative).transpose(1, 2)
            per_frame = per_frame + s.weight_3d * self.weights * (relative - target).square().sum(-1).mean(-1)
        per_frame = per_frame + s.weight_joint_limits * joint_limit_penalty(self.full_pose(), self.model.joint_limits)
        axes = torch.tensor([s.flexion_prior_scale, 1.0, 1.0], dtype=self.pose.dtype)
        per_frame = per_frame + s.weight_pose * (axes * self.pose.square()).sum((-1, -2))
        per_frame = per_frame + 10.0 * torch.relu(0.05 - points[..., 2]).sum(-1)  # stay in front of the camera
        shared = s.weight_shape * self.betas.square().sum()
        if temporal_weight > 0 and self.frame_index is not None:
            # consecutive frames of the clip (hypotheses with consecutive frame indices)
            order = torch.argsort(self.frame_index)
            index = self.frame_index[order]
            step = (index[1:] - index[:-1]) == 1
            if step.any():
                motion = (points[order][1:] - points[order][:-1]) / UNIT_M
                shared = shared + temporal_weight * motion.square().sum(-1).mean(-1)[step].sum() / len(order)
        return per_frame, shared

    def optimise(self, steps, temporal_weight, shape=True, progress=None, stage=""):
        optimiser = torch.optim.Adam(self.parameter_groups(shape))
        for step in range(steps):
            optimiser.zero_grad()
            per_frame, shared = self.energy(temporal_weight)
            loss = per_frame.mean() + shared
            loss.backward()
            optimiser.step()
            if progress is not None:
                progress.update(stage, step, float(loss.detach()))

    def state(self):
        """Detached (rotation, transl, full pose) of every hypothesis."""
        with torch.no_grad():
            return self.rotation().clone(), self.transl.detach().clone(), self.full_pose().clone()


def fit_initial_estimate(keypoints, K, mode="hand", side="right", settings=None, model=None, log=None,
                         progress=None):
    """InitialEstimate from Keypoints2D (formats/keypoint_file.py) and K (3, 3) pixels;
    `progress` (fit/progress.Progress of planned_steps(settings), or None) counts the steps."""
    settings = settings or InitialFitSettings()
    log = log or (lambda message: None)
    dtype = torch.float64
    start = time.perf_counter()
    model = model or HandModel.load(mode, side, dtype=dtype)
    hand = model      # the model's own keypoints: what init.npz holds and the fit anchors to
    if settings.landmark_offsets:      # the keypoints are MediaPipe's landmarks: compared where it puts them
        model = on_mediapipe_landmarks(model)
    pixels = torch.as_tensor(keypoints.points, dtype=dtype)
    frames = pixels.shape[0]
    K = torch.as_tensor(np.asarray(K), dtype=dtype)
    world = None if keypoints.world is None else torch.as_tensor(keypoints.world, dtype=dtype)
    detected = torch.as_tensor(keypoints.detected)
    weights = torch.where(detected, 1.0, settings.undetected_weight).to(dtype)
    betas = torch.zeros(model.num_betas, dtype=dtype)

    # 1. rigid
    rotation, transl = rigid_initialisation(model, pixels, K, world, settings)
    log(f"rigid stage: {time.perf_counter() - start:.1f} s")

    # 2. pose and shape, from the rigid result and from its palm flip side by side
    flipped = palm_flip(rotation)
    flipped_transl = solve_translation(model_keypoints(model, betas, torch.zeros(1, 16, 3, dtype=dtype))[:, PALM]
                                       @ flipped.transpose(1, 2), pixels[:, PALM], K)
    two = lambda a, b: torch.cat([a, b], dim=0)
    index = torch.arange(frames)
    fit = _ClipFit(model, two(pixels, pixels), K, two(weights, weights), None if world is None else two(world, world),
                   two(rotation, flipped), two(transl, flipped_transl), torch.zeros(2 * frames, 16, 3, dtype=dtype),
                   betas, settings, None)
    fit.optimise(settings.pose_steps, temporal_weight=0.0, progress=progress, stage="pose and shape")
    with torch.no_grad():
        per_frame, _ = fit.energy(0.0)
    first_better = per_frame[:frames] <= per_frame[frames:]
    chosen = torch.where(first_better, index, index + frames)
    rotations, transls, poses = (value[chosen] for value in fit.state())
    betas = fit.betas.detach().clone()
    log(f"pose and shape stage: {time.perf_counter() - start:.1f} s, palm flipped in {int((~first_better).sum())} frames")

    # 3. and 4. clip fit with temporal smoothness; restart frames whose residual stays high
    fit = _ClipFit(model, pixels, K, weights, world, rotations, transls, poses, betas, settings, index)
    restarted, threshold = [], 0.0
    for temporal_weight, steps in ((settings.weight_temporal, settings.pose_steps // 2),
                                   (settings.smooth_temporal, settings.smooth_steps)):
        fit.optimise(steps, temporal_weight=temporal_weight, progress=progress, stage="whole clip")
        residual = fit.residual_px()
        threshold = max(settings.restart_factor * float(residual.median()),
                        settings.restart_min_fraction * float(_hand_size_px(pixels)))
        high = torch.nonzero(residual > threshold).flatten()
        if len(high):
            if progress is not None:
                progress.extend(settings.restart_steps)
            fit = _restart(fit, high, residual, settings, progress)
            restarted = sorted(set(restarted) | set(high.tolist()))
            log(f"restarted frames {high.tolist()} (residual above {threshold:.1f} px)")
    rotations, transls, poses = fit.state()
    betas = fit.betas.detach()
    residual = fit.residual_px()
    global_orient = matrix_to_axis_angle(rotations)
    with torch.no_grad():
        posed = hand(betas, poses, global_orient, transls).keypoints[:, :21]
    seconds = time.perf_counter() - start
    log(f"initial fit of {frames} frames: {seconds:.1f} s, residual median {float(residual.median()):.1f} px")
    return InitialEstimate(
        source=keypoints.source, mode=model.mode, side=model.side, betas=betas.numpy(), pose=poses.numpy(),
        global_orient=global_orient.numpy(), transl=transls.numpy(), keypoints3d=posed.numpy(),
        residual_px=residual.numpy(), detected=np.asarray(keypoints.detected, dtype=bool),
        metadata={"keypoints": keypoints.summary(),
                  "landmarks": "MediaPipe's, offset on the model" if model is not hand else "the model's keypoints",
                  "restarted_frames": restarted, "restart_threshold_px": threshold, "seconds": seconds,
                  "settings": dataclasses.asdict(settings)})


def planned_steps(settings):
    """Optimiser steps of fit_initial_estimate without restarts (each restart adds restart_steps)."""
    return settings.pose_steps + settings.pose_steps // 2 + settings.smooth_steps


def _restart(fit, frames, residual, settings, progress=None):
    """Re-fit `frames` (indices) from the nearest better neighbour's pose and from their palm flip
    (shape fixed, no temporal term); keep per frame whichever ends with the lowest residual."""
    rotation, transl, pose = fit.state()
    good = torch.nonzero(residual <= residual[frames].min()).flatten()
    candidates = [(rotation[frames], transl[frames], pose[frames])]
    flipped = palm_flip(rotation[frames])
    candidates.append((flipped, transl[frames], pose[frames]))
    if len(good):
        nearest = good[(good[None, :] - frames[:, None]).abs().argmin(1)]
        candidates.append((rotation[nearest], transl[nearest], pose[nearest]))
    count = len(candidates)
    stack = lambda k: torch.cat([c[k] for c in candidates], dim=0)
    repeat = lambda t: None if t is None else t[frames].repeat(count, *([1] * (t.dim() - 1)))
    trial = _ClipFit(fit.model, repeat(fit.pixels), fit.K, repeat(fit.weights), repeat(fit.world),
                     stack(0), stack(1), stack(2), fit.betas.detach(), settings, None)
    trial.optimise(settings.restart_steps, temporal_weight=0.0, shape=False, progress=progress, stage="restarts")
    with torch.no_grad():
        per_frame, _ = trial.energy(0.0)
    best = per_frame.reshape(count, len(frames)).argmin(0) * len(frames) + torch.arange(len(frames))
    new_rotation, new_transl, new_pose = (value[best] for value in trial.state())
    rotation[frames], transl[frames], pose[frames] = new_rotation, new_transl, new_pose
    return _ClipFit(fit.model, fit.pixels, fit.K, fit.weights, fit.world, rotation, transl, pose,
                    fit.betas.detach(), settings, fit.frame_index)
