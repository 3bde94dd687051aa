"""Build the hand model files from the anatomy: `harp model build` runs `build_models`.

Deterministic: the same code gives byte-identical arrays (tests/test_model_build.py rebuilds
and compares with the files shipped in pipeline/assets/).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..formats import hand_model_file as fmt
from . import anatomy
from .shape_space import SHAPE_PARAMETERS, shape_directions
from .skinning_weights import dense_skinning_weights, prune_weights
from .template_mesh import build_template_meshes
from .uv_atlas import make_atlas


def rest_joints_and_frames(with_forearm):
    """Joint pivots (J, 3) and rest frames (J, 3, 3) in MANO order (+ forearm)."""
    count = 17 if with_forearm else 16
    joints = np.zeros((count, 3))
    frames = np.tile(np.eye(3), (count, 1, 1))
    frames[0] = anatomy.wrist_frame()
    for name, indices in anatomy.FINGER_JOINTS.items():
        chain, chain_frames = anatomy.HAND_FINGERS[name].chain()
        joints[list(indices)] = chain[:3]
        frames[list(indices)] = chain_frames
    if with_forearm:
        joints[16] = (anatomy.WRIST_CENTRE_XZ[0], anatomy.ELBOW_Y, anatomy.WRIST_CENTRE_XZ[1])
        frames[16] = anatomy.forearm_frame()
    return joints, frames


def parents_of(with_forearm):
    parents = np.zeros(17 if with_forearm else 16, dtype=np.int32)
    parents[0] = 16 if with_forearm else -1
    for indices in anatomy.FINGER_JOINTS.values():
        parents[indices[0]], parents[indices[1]], parents[indices[2]] = 0, indices[0], indices[1]
    if with_forearm:
        parents[16] = -1
    return parents


def rest_keypoints(with_forearm):
    """Keypoints (K, 3) in MediaPipe order and the joint carrying each."""
    joints, _ = rest_joints_and_frames(with_forearm)
    points, carriers = [joints[0]], [0]
    for name in anatomy.FINGERS:
        chain, _ = anatomy.HAND_FINGERS[name].chain()
        indices = anatomy.FINGER_JOINTS[name]
        points += [chain[0], chain[1], chain[2], chain[3]]
        carriers += [indices[0], indices[1], indices[2], indices[2]]
    if with_forearm:
        points.append(joints[16])
        carriers.append(16)
    return np.array(points), np.array(carriers, dtype=np.int32)


def joint_parts(with_forearm):
    """Part (PART_NAMES index) of each joint, so shape fields move a digit's joints with it."""
    parts = np.zeros(17 if with_forearm else 16, dtype=np.int8)
    for name, indices in anatomy.FINGER_JOINTS.items():
        parts[list(indices)] = fmt.PART_NAMES.index(name)
    if with_forearm:
        parts[16] = fmt.PART_NAMES.index("forearm")
    return parts


def build_model_data():
    """Both modes of the right hand as HandModelData: {'hand': ..., 'arm': ...}."""
    meshes = build_template_meshes()
    result = {}
    for mode, mesh in meshes.items():
        with_forearm = mode == "arm"
        vertices = mesh.vertices
        weights = dense_skinning_weights(vertices, mesh.parts, with_forearm)
        skin_indices, skin_weights = prune_weights(weights)
        joints, frames = rest_joints_and_frames(with_forearm)
        keypoints, keypoint_joints = rest_keypoints(with_forearm)
        uvs, faces_uv, charts = make_atlas(vertices, mesh.faces)
        result[mode] = fmt.HandModelData(
            side="right", mode=mode,
            vertices=vertices, faces=mesh.faces, uvs=uvs, faces_uv=faces_uv,
            skin_indices=skin_indices, skin_weights=skin_weights,
            joint_names=fmt.JOINT_NAMES + ((fmt.FOREARM_JOINT_NAME,) if with_forearm else ()),
            parents=parents_of(with_forearm), joints=joints, joint_frames=frames,
            joint_shapedirs=shape_directions(joints, joint_parts(with_forearm)),
            joint_limits=anatomy.default_joint_limits(),
            keypoint_names=fmt.KEYPOINT_NAMES + ((fmt.ELBOW_KEYPOINT_NAME,) if with_forearm else ()),
            keypoints=keypoints, keypoint_joints=keypoint_joints,
            keypoint_shapedirs=shape_directions(keypoints, joint_parts(with_forearm)[keypoint_joints]),
            shapedirs=shape_directions(vertices, mesh.parts),
            shape_names=tuple(n for n, _ in SHAPE_PARAMETERS),
            shape_descriptions=tuple(d for _, d in SHAPE_PARAMETERS),
            vertex_parts=mesh.parts, shared_vertex_count=mesh.shared_vertex_count,
            metadata={"uv_charts": int(charts), "builder": "pipeline.handmodel.build"})
    return result


def build_models(out_dir=None):
    """Build and write both modes; returns the written paths."""
    out_dir = Path(out_dir) if out_dir else fmt.shipped_model_folder()
    paths = []
    for mode, data in build_model_data().items():
        paths.append(fmt.save_hand_model(data, out_dir / f"hand_model_{mode}.npz"))
    return paths
