"""Frames the alignment left off their silhouette, started again from their neighbours.

The initial keypoints can put a frame's hand the wrong way round: seen edge-on, palm and back
give the detector the same picture, and it may flip the hand about its long axis. The alignment
then holds the flipped hand, pulled there by its keypoint anchor, and the silhouette term alone
cannot turn it back over (the phone-like clip's frame 8: IoU 0.56 at the end of every fit while
its neighbours reached 0.91-0.97). After the alignment, each fitted frame whose silhouette IoU is
below LOST_IOU, and at least LOST_MARGIN below the clip's median, gets the pose its nearest
well-aligned neighbours interpolate (pose_interpolation.py); where that covers its mask better
by at least GAIN, it is kept, and the frame's keypoint anchor moves to the new pose's keypoints
(else the anchor would pull the hand back over). The later stages refine it as any other frame.

A frame still off its silhouette after the stages (restarted or not) paints its colours onto the
wrong texels: the albedo solve leaves out the frames that `frames_off_their_silhouettes` finds
by the same rule, on the final surface (fitting._after_the_stages).
"""
from __future__ import annotations

import numpy as np
import torch

from .. import metrics
from ..render.renderer import render
from .energy_terms import at_anchor_size
from .pose_interpolation import interpolated_poses

LOST_IOU = 0.8          # a frame below this silhouette IoU after the alignment...
LOST_MARGIN = 0.1       # ...and this far below the clip's median is taken as lost
GAIN = 0.05             # the neighbours' pose is kept where it raises the IoU by at least this
POSE = ("global_orient", "transl", "pose")


@torch.no_grad()
def alignment_ious(problem, frames=None, batch_size=8) -> torch.Tensor:
    """(F,) the silhouette IoU of the alignment's mesh (the unsubdivided model) against each
    fitted frame's mask, or of `frames` (indices into the fitted frames)."""
    return silhouette_ious(problem, frames, batch_size, coarse=True)


@torch.no_grad()
def silhouette_ious(problem, frames=None, batch_size=8, coarse=False) -> torch.Tensor:
    """(F,) the silhouette IoU of the avatar's surface (displaced; the unsubdivided model's with
    `coarse`) against each fitted frame's mask, or of `frames` (indices into the fitted frames)."""
    avatar, clip = problem.avatar, problem.clip
    chosen = torch.arange(len(problem.frames), device=clip.masks.device) if frames is None else \
        torch.as_tensor(frames, dtype=torch.long, device=clip.masks.device)
    ious = []
    for batch in chosen.split(batch_size):
        vertices, _ = avatar.posed_coarse(batch) if coarse else avatar.posed(batch)
        alpha = render(vertices, avatar.coarse_mesh if coarse else avatar.mesh, clip.K[batch], clip.height,
                       clip.width, outputs=("alpha",), antialiased=False)["alpha"]
        ious.append(metrics.silhouette_iou(alpha, clip.masks[batch]))
    return torch.cat(ious) if ious else torch.zeros(0, dtype=torch.float64)


def lost(ious: np.ndarray) -> np.ndarray:
    """Indices of the frames taken as lost among frames of silhouette IoUs `ious`: under
    LOST_IOU and at least LOST_MARGIN under their median (none of fewer than 3 frames)."""
    ious = np.asarray(ious, dtype=np.float64)
    if len(ious) < 3:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero((ious < LOST_IOU) & (ious < np.median(ious) - LOST_MARGIN))


@torch.no_grad()
def frames_off_their_silhouettes(problem) -> dict:
    """The fitted frames the avatar's final surface leaves off their silhouettes (the rule of
    `lost`): {"indices": into the fitted frames, "frames": the sequence frames, "ious": theirs}."""
    ious = silhouette_ious(problem).cpu().numpy()
    off = lost(ious)
    return {"indices": [int(i) for i in off], "frames": [int(problem.frames[i]) for i in off],
            "ious": [round(float(ious[i]), 4) for i in off]}


def frames_kept(left_out: dict, count: int):
    """The indices of `count` fitted frames without those `left_out` lists (a
    frames_off_their_silhouettes result); None where it lists none (every frame)."""
    dropped = set(left_out["indices"])
    return [index for index in range(count) if index not in dropped] if dropped else None


@torch.no_grad()
def restart_lost_frames(problem) -> dict:
    """Start the lost frames (module docstring) again from their neighbours, in place; returns
    {"frames": the sequence frames restarted, "iou_before", "iou_after", "tried": the sequence
    frames found lost}."""
    avatar = problem.avatar
    ious = alignment_ious(problem).cpu().numpy()
    off = lost(ious)
    kept = np.setdiff1d(np.arange(len(ious)), off)
    result = {"frames": [], "iou_before": [], "iou_after": [],
              "tried": [int(problem.frames[i]) for i in off]}
    if len(off) == 0 or len(kept) == 0:
        return result
    sequence_frames = np.asarray(problem.frames)
    good = {name: getattr(avatar, name)[torch.as_tensor(kept, device=avatar.pose.device)] for name in POSE}
    start = interpolated_poses(good, sequence_frames[kept], sequence_frames[off])
    index = torch.as_tensor(off, device=avatar.pose.device)
    before = {name: getattr(avatar, name)[index].clone() for name in POSE}
    for name in POSE:
        getattr(avatar, name)[index] = start[name].to(getattr(avatar, name).dtype)
    after = alignment_ious(problem, off).cpu().numpy()
    better = after >= ious[off] + GAIN
    kept_own = torch.as_tensor(~better, device=index.device)
    for name in POSE:       # where the neighbours' pose is no better, the frame keeps its own
        getattr(avatar, name)[index[kept_own]] = before[name][kept_own]
    _anchor_where_they_are(problem, index[~kept_own])
    result.update(frames=[int(sequence_frames[i]) for i in off[better]],
                  iou_before=[round(float(v), 4) for v in ious[off][better]],
                  iou_after=[round(float(v), 4) for v in after[better]])
    return result


@torch.no_grad()
def anchor_restarted(problem, restarted: dict):
    """On a resumed fit: the anchor of the frames restart_lost_frames restarted, at their current
    keypoints (the problem was built again, its anchors at the initial keypoints)."""
    fitted = np.asarray(problem.frames)
    _anchor_where_they_are(problem, torch.as_tensor(np.flatnonzero(np.isin(fitted, restarted.get("frames", []))),
                                                    device=problem.avatar.pose.device))


def _anchor_where_they_are(problem, index):
    """The keypoint anchor of the fitted frames `index` moved to their poses' keypoints now (at the
    initial estimate's size where the anchor is blind to the size, settings.anchor_size "free")."""
    if len(index):
        _, keypoints = problem.avatar.posed(index)
        keypoints = at_anchor_size(problem, keypoints[:, :21])
        problem.anchor_keypoints[index] = keypoints.to(problem.anchor_keypoints.dtype)
