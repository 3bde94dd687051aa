"""Pose errors against the ground truth (synthetic clips): Procrustes-aligned and camera-frame
joint and vertex errors (mm) of the initial estimate and of a fit against gt.npz.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .. import metrics
from ..formats import sequence_folder as seq
from ..formats.initial_estimate import read_initial_estimate
from ..handmodel.lbs import HandModel
from .finished_fit import EvaluationError, fitted_avatar, posed_surfaces

POSE_COMPARISON = (
    "joints: the 21 keypoints (MediaPipe order) of the hand model at each estimate's own shape "
    "and pose, against the model at the gt.npz shape and pose (which reproduces gt.npz keypoints3d; "
    "gt_keypoint_check_mm is the largest difference); vertices: the hand model's vertices, no "
    "personal geometry on either side (pose and shape only); surface: the rendered surface, "
    "against gt.npz vertices (with the person's true offsets): the fit's displaced surface at the "
    "unsubdivided vertices, the initial estimate's plain model. procrustes_mm: mean distance after "
    "a per-frame similarity (Procrustes) alignment; camera_mm: in the camera frame, unaligned.")


def point_errors(prediction, target):
    """Per-frame mean distances (mm) between corresponding points (F, N, 3) given in metres:
    after a per-frame Procrustes (similarity) alignment of the prediction, and unaligned."""
    p = torch.as_tensor(prediction, dtype=torch.float64).cpu()
    t = torch.as_tensor(target, dtype=torch.float64).cpu()
    aligned = metrics.procrustes_error(p, t) * 1000
    camera = (p - t).norm(dim=-1).mean(-1) * 1000
    return {"procrustes_mm_mean": float(aligned.mean()), "camera_mm_mean": float(camera.mean()),
            "procrustes_mm": aligned.tolist(), "camera_mm": camera.tolist()}


def base_vertex_index(base, subdivided):
    """(V,) index, in a subdivided model, of each vertex of the model it was made from (the
    subdivision keeps them, reordered, at their exact rest positions)."""
    lookup = {row.tobytes(): i for i, row in enumerate(np.ascontiguousarray(subdivided.vertices))}
    try:
        return np.array([lookup[row.tobytes()] for row in np.ascontiguousarray(base.vertices)])
    except KeyError:
        raise EvaluationError("the fit's model is not a subdivision of the hand model") from None


def _hand(model, betas, pose, global_orient, transl):
    with torch.no_grad():
        out = model(*(torch.as_tensor(np.asarray(a), dtype=torch.float64)
                      for a in (betas, pose, global_orient, transl)))
    return out.keypoints[:, :21], out.vertices


def _estimate_errors(model, params, truth, surface=None):
    joints, vertices = _hand(model, *params)
    result = {"joints": point_errors(joints, truth["joints"])}
    if truth.get("vertices") is not None:
        result["vertices"] = point_errors(vertices, truth["vertices"])
    if truth.get("surface") is not None:
        result["surface"] = point_errors(vertices if surface is None else surface, truth["surface"])
    return result


class PoseScorer:
    """Scores pose estimates of a synthetic sequence against its gt.npz (see POSE_COMPARISON):
    the initial estimate's and an avatar's, on given sequence frames."""

    def __init__(self, sequence, initial=None):
        sequence = Path(sequence)
        info = seq.read_sequence_info(sequence)
        if not info.ground_truth:
            raise EvaluationError(f"the sequence {sequence} has no ground truth")
        self.gt = seq.read_ground_truth(sequence / info.ground_truth)
        self.initial = initial or read_initial_estimate(sequence)
        self.model = HandModel.load(self.initial.mode, self.initial.side, dtype=torch.float64)
        same = (self.gt.mode, self.gt.side) == (self.initial.mode, self.initial.side)
        self.gt_model = self.model if same else HandModel.load(self.gt.mode, self.gt.side, dtype=torch.float64)
        self.same_mode = self.gt.mode == self.initial.mode
        self._base_index = None

    def truth(self, frames):
        """(reference points of `frames`, largest difference (mm) between the model at the true
        parameters and gt.npz keypoints)."""
        gt = self.gt
        joints, vertices = _hand(self.gt_model, gt.betas, gt.pose[frames], gt.global_orient[frames], gt.transl[frames])
        check = float(np.abs(joints.numpy() - gt.keypoints3d[frames]).max() * 1000)
        surface = gt.vertices[frames] if self.same_mode and gt.vertices is not None else None
        return {"joints": joints, "vertices": vertices if self.same_mode else None, "surface": surface}, check

    def initial_errors(self, frames, reference=None):
        initial = self.initial
        reference = reference if reference is not None else self.truth(frames)[0]
        return _estimate_errors(self.model, (initial.betas, initial.pose[frames], initial.global_orient[frames],
                                             initial.transl[frames]), reference)

    def avatar_errors(self, avatar, frames, reference=None):
        """Errors of an Avatar whose per-frame parameters are those of sequence `frames`."""
        reference = reference if reference is not None else self.truth(frames)[0]
        if self._base_index is None:
            self._base_index = base_vertex_index(self.model.data, avatar.model.data)
        with torch.no_grad():
            params = [avatar.betas, avatar.pose * avatar.pose_mask, avatar.global_orient, avatar.transl]
            surface = posed_surfaces(avatar)[:, self._base_index].cpu()
        return _estimate_errors(self.model, [p.detach().cpu().numpy() for p in params], reference, surface)


def evaluate_poses(fit_folder, sequence, device=None, held_out=None):
    """Joint and vertex errors (mm) of the initial estimate and of the fit against gt.npz, on the
    fit's frames (both on the same frames), and on the held-out frames after their pose fit
    when `held_out` (a held_out.HeldOutResult) is given."""
    scorer = PoseScorer(sequence)
    avatar, report = fitted_avatar(fit_folder, sequence, device)
    frames = np.asarray(report["frames"])
    reference, check = scorer.truth(frames)
    result = {"comparison": POSE_COMPARISON, "frames": frames.tolist(), "gt_keypoint_check_mm": check,
              "initial": scorer.initial_errors(frames, reference),
              "fit": scorer.avatar_errors(avatar, frames, reference)}
    if held_out is not None:
        reference, check = scorer.truth(held_out.frames)
        result["held_out"] = {"frames": held_out.frames.tolist(),
                              "initial": scorer.initial_errors(held_out.frames, reference),
                              "fit": scorer.avatar_errors(held_out.avatar, held_out.frames, reference)}
        result["gt_keypoint_check_mm"] = max(result["gt_keypoint_check_mm"], check)
    return result
