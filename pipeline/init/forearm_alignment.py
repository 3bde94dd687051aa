"""The initial forearm turned to the masks (hand + forearm mode).

The initial fit places the hand from its 21 keypoints, which say nothing of the forearm: it
leaves the model's forearm where the wrist's rest pose puts it, often straight down while the
person's forearm leaves the picture at an angle. The fit's silhouette term pulls a forearm only
where its outline already nearly lies on the mask's, and at its learning rate turns it a few
degrees per hundred steps. So here, per frame, the forearm is turned in the image about the
wrist to where the mask takes it (fit/forearm_mask.py): the arm's orientation turns about the
camera ray through the wrist, the wrist joint turns back by as much, and the hand stays exactly
where its keypoints put it. Frames whose mask shows no forearm take the turn of their nearest
neighbours in time (interpolated).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..fit.forearm_mask import MIDDLE_KNUCKLE, forearm_targets
from ..formats.hand_model_file import ELBOW_KEYPOINT_NAME
from ..handmodel.lbs import HandModel
from ..handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..render.rasterize import project

ROUNDS = 2          # the turn about the wrist's ray is exact at the wrist's depth; a second round corrects the rest


def signed_angles(vectors, targets):
    """(N,) angle (radians) turning each 2D pixel vector (N, 2) onto its target (N, 2), positive
    from +x towards +y (clockwise on the screen, whose y points down)."""
    cross = vectors[:, 0] * targets[:, 1] - vectors[:, 1] * targets[:, 0]
    return np.arctan2(cross, (vectors * targets).sum(1))


def turn_forearm(model, betas, pose, orient, transl, angles):
    """(pose, global_orient, transl) with each frame's forearm turned by `angles` (F,) radians
    about the camera ray through its wrist (in the image: about the wrist, positive clockwise on
    the screen), the wrist joint turned back by as much: the hand's keypoints do not move."""
    with torch.no_grad():
        wrist = model(betas, pose, orient, transl).keypoints[:, 0]
        ray = torch.nn.functional.normalize(wrist, dim=-1)
        old = axis_angle_to_matrix(orient)
        new = axis_angle_to_matrix(ray * angles[:, None]) @ old
        pose = pose.clone()
        pose[:, 0] = matrix_to_axis_angle(new.transpose(1, 2) @ old @ axis_angle_to_matrix(pose[:, 0]))
        orient = matrix_to_axis_angle(new)
        moved = model(betas, pose, orient, transl).keypoints[:, 0]
    return pose, orient, transl + (wrist - moved)


def align_forearms(estimate, masks, frame_K, model=None):
    """(InitialEstimate with each frame's forearm turned to its mask, {"frames": turned frames,
    "median_degrees": median absolute turn}) for a hand + forearm estimate; masks (F, H, W) bool,
    frame_K (F, 3, 3). A hand-only estimate, or masks that show no forearm, come back unchanged."""
    if estimate.mode != "arm":
        return estimate, {"frames": 0, "median_degrees": 0.0}
    dtype = torch.float64
    model = model or HandModel.load("arm", estimate.side, dtype=dtype)
    elbow = model.data.keypoint_names.index(ELBOW_KEYPOINT_NAME)
    betas, pose, orient, transl = (torch.as_tensor(np.asarray(a), dtype=dtype) for a in
                                   (estimate.betas, estimate.pose, estimate.global_orient, estimate.transl))
    K = torch.as_tensor(np.asarray(frame_K), dtype=dtype)
    total = np.zeros(len(pose))
    with torch.no_grad():
        before = model(betas, pose, orient, transl).keypoints
        pixels = project(before[:, [0, MIDDLE_KNUCKLE]], K).numpy()
        targets, found = forearm_targets(np.asarray(masks, bool), pixels[:, 0], pixels[:, 1])
        if not found.any():
            return estimate, {"frames": 0, "median_degrees": 0.0}
        for _ in range(ROUNDS):
            keypoints = model(betas, pose, orient, transl).keypoints
            points = project(keypoints[:, [0, elbow]], K).numpy()
            turn = np.zeros(len(pose))
            turn[found] = signed_angles(points[found, 1] - points[found, 0], targets[found])
            turn = np.interp(np.arange(len(pose)), np.flatnonzero(found), turn[found])
            total += turn
            pose, orient, transl = turn_forearm(model, betas, pose, orient, transl, torch.as_tensor(turn, dtype=dtype))
    turned = dataclasses.replace(estimate, pose=pose.numpy(), global_orient=orient.numpy(), transl=transl.numpy())
    return turned, {"frames": int(found.sum()), "median_degrees": float(np.degrees(np.median(np.abs(total))))}
