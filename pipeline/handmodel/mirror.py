"""The left hand: an exact mirror image of the right-hand model (numpy; poses in numpy or torch).

Mirroring is the reflection M = diag(-1, 1, 1) of model space. Faces are re-wound so normals
stay outward; each rest frame F becomes M F M (still a rotation), so a joint's local axis-angle
(flexion, twist, deviation) maps to (flexion, -twist, -deviation) and the limits follow.
"""
from __future__ import annotations

import dataclasses

import numpy as np

REFLECTION = np.diag([-1.0, 1.0, 1.0])
AXIS_ANGLE_SIGNS = np.array([1.0, -1.0, -1.0])


def mirror_points(points):
    """Reflect (..., 3) points or directions across the model's x = 0 plane."""
    return points * _like(points, np.array([-1.0, 1.0, 1.0]))


def mirror_axis_angle(axis_angle):
    """Axis-angle vectors (..., 3) of the right hand -> the mirrored left hand's (and back);
    valid for the global orientation (model space) and for local joint rotations alike."""
    return axis_angle * _like(axis_angle, AXIS_ANGLE_SIGNS)


def _like(array, values):
    if hasattr(array, "new_tensor"):  # torch tensor
        return array.new_tensor(values)
    return values


def mirror_model_data(data):
    """HandModelData of the other side (applying it twice gives back the original)."""
    limits = data.joint_limits.copy()
    limits[:, 1:, :] = -data.joint_limits[:, 1:, ::-1]
    frames = REFLECTION @ data.joint_frames @ REFLECTION
    return dataclasses.replace(
        data, side="left" if data.side == "right" else "right",
        vertices=mirror_points(data.vertices), faces=data.faces[:, ::-1].copy(),
        faces_uv=data.faces_uv[:, ::-1].copy(), joints=mirror_points(data.joints),
        joint_frames=frames, joint_limits=limits,
        joint_shapedirs=data.joint_shapedirs * np.array([-1.0, 1.0, 1.0])[:, None],
        keypoints=mirror_points(data.keypoints),
        keypoint_shapedirs=data.keypoint_shapedirs * np.array([-1.0, 1.0, 1.0])[:, None],
        shapedirs=data.shapedirs * np.array([-1.0, 1.0, 1.0])[:, None])
