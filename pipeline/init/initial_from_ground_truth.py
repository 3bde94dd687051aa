"""`--init gt-noise`: the ground truth of a synthetic clip with controlled noise, for pose
refinement experiments (HARP's "initial estimate" of known quality)."""
from __future__ import annotations

import numpy as np
import torch

from ..formats.initial_estimate import InitialEstimate
from ..handmodel.lbs import HandModel


def _random_rotations(generator, count, degrees):
    """(count, 3) axis-angles of random axes and exactly `degrees` each."""
    axes = generator.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * np.radians(degrees)


def compose_axis_angle(first, second):
    """Axis-angle of R(first) @ R(second) (both (N, 3))."""
    from ..handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle

    a = axis_angle_to_matrix(torch.as_tensor(first, dtype=torch.float64))
    b = axis_angle_to_matrix(torch.as_tensor(second, dtype=torch.float64))
    return matrix_to_axis_angle(a @ b).numpy()


def ground_truth_with_noise(gt, joint_degrees=10.0, translation_m=0.01, orient_degrees=0.0, seed=0,
                            keep_shape=True):
    """InitialEstimate from GroundTruth: every joint rotated by `joint_degrees` about a random
    axis, the wrist moved by `translation_m` in a random direction, the global orientation by
    `orient_degrees`; the true shape is kept unless `keep_shape` is False (average hand)."""
    generator = np.random.default_rng(seed)
    frames = gt.frame_count
    pose = compose_axis_angle(gt.pose.reshape(-1, 3),
                              _random_rotations(generator, frames * 16, joint_degrees)).reshape(frames, 16, 3)
    if gt.mode == "hand":
        pose[:, 0] = gt.pose[:, 0]   # the wrist is not a free joint without a forearm
    orient = gt.global_orient.copy()
    if orient_degrees > 0:
        orient = compose_axis_angle(_random_rotations(generator, frames, orient_degrees), orient)
    direction = generator.normal(size=(frames, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    transl = gt.transl + translation_m * direction
    betas = gt.betas.copy() if keep_shape else np.zeros_like(gt.betas)
    model = HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    with torch.no_grad():
        keypoints = model(torch.as_tensor(betas), torch.as_tensor(pose), torch.as_tensor(orient),
                          torch.as_tensor(transl)).keypoints[:, :21].numpy()
    return InitialEstimate(source="gt-noise", mode=gt.mode, side=gt.side, betas=betas, pose=pose,
                           global_orient=orient, transl=transl, keypoints3d=keypoints,
                           residual_px=np.zeros(frames), detected=np.ones(frames, dtype=bool),
                           metadata={"joint_degrees": joint_degrees, "translation_m": translation_m,
                                     "orient_degrees": orient_degrees, "seed": seed})
