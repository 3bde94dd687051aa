"""The hand-model export: everything another program needs to rebuild and pose our hand model.

This module is the single home of the format. It needs only numpy, so `synth/` and
`harp_addon/` (which run inside Blender's Python, without torch) read the same file the
PyTorch core reads. One `.npz` file holds one mode (hand-only or hand+forearm) of one side.

Conventions (see DESIGN.md):
- metres, right-handed model space with the wrist joint at the origin:
  +x towards the thumb side (radial), +y towards the fingertips (distal), +z out of the palm;
- joints in MANO order (0 wrist, 1-3 index, 4-6 middle, 7-9 pinky, 10-12 ring, 13-15 thumb),
  plus 16 "forearm" (elbow -> wrist) in hand+forearm mode; 21 keypoints in MediaPipe order,
  plus 21 "elbow" in hand+forearm mode;
- each joint has a rest frame (columns: local x = flexion axis, local y = along the bone,
  local z = x cross y, towards the palm side of the bone), the same convention as a Blender
  bone's rest matrix; a joint's pose is an axis-angle vector in that local frame, so its
  components are (flexion, twist, deviation) and the limits are given per component.
- posing (linear blend skinning, see pipeline/handmodel/lbs.py):
    v(beta)   = vertices + shapedirs @ beta,   joints(beta) = joints + joint_shapedirs @ beta
    R_j       = frame_j @ exp(pose_j) @ frame_j^T              (rest-space rotation of joint j)
    A_j       = A_parent(j) @ [R_j | (I - R_j) joints_j(beta)] (A_root = [R_global | transl])
    v_posed   = sum_j weight_j * A_j v(beta)
  The forearm bone (hand+forearm mode) has no rotation of its own: A_forearm = A_root.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .npz_file import read_npz, write_npz

FORMAT_NAME = "harp-hand-model"
FORMAT_VERSION = 1

MODES = ("hand", "arm")
SIDES = ("right", "left")

JOINT_NAMES = (
    "wrist",
    "index1", "index2", "index3",
    "middle1", "middle2", "middle3",
    "pinky1", "pinky2", "pinky3",
    "ring1", "ring2", "ring3",
    "thumb1", "thumb2", "thumb3",
)
FOREARM_JOINT_NAME = "forearm"
NUM_POSE_JOINTS = 16  # articulated joints that take an axis-angle each

KEYPOINT_NAMES = (
    "wrist",
    "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)
ELBOW_KEYPOINT_NAME = "elbow"
# the palm's keypoints: the wrist, the thumb's base and the four knuckles (what the fingers' lengths leave in place)
PALM_KEYPOINT_NAMES = ("wrist", "thumb_cmc", "index_mcp", "middle_mcp", "ring_mcp", "pinky_mcp")

PART_NAMES = ("palm", "thumb", "index", "middle", "ring", "pinky", "forearm", "wrist_cap")


class HandModelFileError(ValueError):
    """A hand-model file is missing, unreadable or inconsistent."""


@dataclasses.dataclass
class HandModelData:
    """Arrays of one hand-model mode, as stored in the export file (all numpy)."""

    side: str
    mode: str
    vertices: np.ndarray          # (V, 3) float64, rest template at beta = 0
    faces: np.ndarray             # (F, 3) int32, counter-clockwise seen from outside
    uvs: np.ndarray               # (U, 2) float64 in [0, 1], v up (OpenGL/Blender convention)
    faces_uv: np.ndarray          # (F, 3) int32 indices into uvs
    skin_indices: np.ndarray      # (V, 4) int32 joint indices (unused slots hold 0 with weight 0)
    skin_weights: np.ndarray      # (V, 4) float64, each row sums to 1
    joint_names: tuple
    parents: np.ndarray           # (J,) int32, -1 for the root
    joints: np.ndarray            # (J, 3) rest joint positions (pivots) at beta = 0
    joint_frames: np.ndarray      # (J, 3, 3) rest frames, columns = local axes
    joint_shapedirs: np.ndarray   # (J, 3, S)
    joint_limits: np.ndarray      # (16, 3, 2) radians, [lower, upper] per local component
    keypoint_names: tuple
    keypoints: np.ndarray         # (K, 3) rest keypoints at beta = 0
    keypoint_joints: np.ndarray   # (K,) int32, the joint whose transform carries the keypoint
    keypoint_shapedirs: np.ndarray  # (K, 3, S)
    shapedirs: np.ndarray         # (V, 3, S) metres per unit of beta
    shape_names: tuple
    shape_descriptions: tuple
    vertex_parts: np.ndarray      # (V,) int8 index into PART_NAMES
    shared_vertex_count: int      # leading vertices identical in both modes
    metadata: dict = dataclasses.field(default_factory=dict)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.joints.shape[0])

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[2])

    def dense_weights(self) -> np.ndarray:
        """(V, J) skinning weight matrix."""
        dense = np.zeros((self.num_vertices, self.num_joints))
        np.add.at(dense, (np.arange(self.num_vertices)[:, None], self.skin_indices), self.skin_weights)
        return dense

    def validate(self) -> None:
        """Raise HandModelFileError with a clear message if the arrays disagree."""
        problems = []
        V, J = self.vertices.shape[0], self.joints.shape[0]
        S = self.shapedirs.shape[2] if self.shapedirs.ndim == 3 else -1
        K = self.keypoints.shape[0]

        def expect(name, array, shape):
            if array.shape != shape:
                problems.append(f"{name} has shape {array.shape}, expected {shape}")

        if self.side not in SIDES:
            problems.append(f"side {self.side!r} is not one of {SIDES}")
        if self.mode not in MODES:
            problems.append(f"mode {self.mode!r} is not one of {MODES}")
        expect("vertices", self.vertices, (V, 3))
        F = self.faces.shape[0]
        expect("faces", self.faces, (F, 3))
        expect("faces_uv", self.faces_uv, (F, 3))
        expect("uvs", self.uvs, (self.uvs.shape[0], 2))
        expect("skin_indices", self.skin_indices, (V, 4))
        expect("skin_weights", self.skin_weights, (V, 4))
        expect("parents", self.parents, (J,))
        expect("joint_frames", self.joint_frames, (J, 3, 3))
        expect("joint_shapedirs", self.joint_shapedirs, (J, 3, S))
        expect("joint_limits", self.joint_limits, (NUM_POSE_JOINTS, 3, 2))
        expect("keypoint_joints", self.keypoint_joints, (K,))
        expect("keypoint_shapedirs", self.keypoint_shapedirs, (K, 3, S))
        expect("shapedirs", self.shapedirs, (V, 3, S))
        expect("vertex_parts", self.vertex_parts, (V,))
        if len(self.joint_names) != J:
            problems.append(f"{len(self.joint_names)} joint names for {J} joints")
        if len(self.keypoint_names) != K:
            problems.append(f"{len(self.keypoint_names)} keypoint names for {K} keypoints")
        if len(self.shape_names) != S or len(self.shape_descriptions) != S:
            problems.append("shape names/descriptions do not match the number of shape directions")
        if not problems:
            if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= V):
                problems.append("faces index vertices that do not exist")
            if self.faces_uv.size and (self.faces_uv.min() < 0 or self.faces_uv.max() >= len(self.uvs)):
                problems.append("faces_uv index UVs that do not exist")
            if self.skin_indices.min() < 0 or self.skin_indices.max() >= J:
                problems.append("skin_indices name joints that do not exist")
            if not np.allclose(self.skin_weights.sum(1), 1.0, atol=1e-6):
                problems.append("skin weights do not sum to 1 on every vertex")
            if (self.skin_weights < 0).any():
                problems.append("negative skin weights")
            for j, p in enumerate(self.parents):
                if p >= J or (p >= 0 and p == j):
                    problems.append(f"joint {j} has an invalid parent {p}")
            for name, array in (("vertices", self.vertices), ("shapedirs", self.shapedirs),
                                ("joints", self.joints), ("uvs", self.uvs)):
                if not np.isfinite(array).all():
                    problems.append(f"{name} contains NaN or Inf")
            if not 0 <= self.shared_vertex_count <= V:
                problems.append("shared_vertex_count is out of range")
        if problems:
            raise HandModelFileError("invalid hand model: " + "; ".join(problems))


_ARRAY_FIELDS = [f.name for f in dataclasses.fields(HandModelData)
                 if f.name not in ("side", "mode", "joint_names", "keypoint_names", "shape_names",
                                   "shape_descriptions", "shared_vertex_count", "metadata")]


def save_hand_model(data: HandModelData, path) -> Path:
    """Write one mode of the model to `path` (.npz). Validates first."""
    data.validate()
    header = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "side": data.side, "mode": data.mode,
        "joint_names": list(data.joint_names), "keypoint_names": list(data.keypoint_names),
        "shape_names": list(data.shape_names), "shape_descriptions": list(data.shape_descriptions),
        "shared_vertex_count": int(data.shared_vertex_count), "metadata": data.metadata,
    }
    return write_npz(path, header, {name: np.ascontiguousarray(getattr(data, name)) for name in _ARRAY_FIELDS})


def load_hand_model(path) -> HandModelData:
    """Read and validate a hand-model file written by `save_hand_model`."""
    header, arrays = read_npz(path, FORMAT_NAME, FORMAT_VERSION, HandModelFileError, required=_ARRAY_FIELDS,
                              what="hand model file")
    try:
        data = HandModelData(
            side=header["side"], mode=header["mode"],
            joint_names=tuple(header["joint_names"]), keypoint_names=tuple(header["keypoint_names"]),
            shape_names=tuple(header["shape_names"]), shape_descriptions=tuple(header["shape_descriptions"]),
            shared_vertex_count=int(header["shared_vertex_count"]), metadata=header.get("metadata", {}),
            **arrays)
    except KeyError as error:
        raise HandModelFileError(f"cannot read hand model file {path}: its header lacks {error}") from None
    data.validate()
    return data


def shipped_model_folder() -> Path:
    """The folder of the model files that come with the installed harp-avatar package (found
    through the package, not through the source tree's layout)."""
    from importlib.resources import files

    try:
        return Path(str(files("pipeline") / "assets"))
    except ModuleNotFoundError:
        raise HandModelFileError("the shipped hand model comes with the harp-avatar package, which is not installed "
                                 "here; give a folder of model files") from None


def model_path(mode: str = "hand", folder=None) -> Path:
    """Path of a right-hand model file in `folder` (default: the model shipped with the
    package; the left hand is made by mirroring)."""
    if mode not in MODES:
        raise HandModelFileError(f"unknown model mode {mode!r}; choose one of {MODES}")
    return Path(folder or shipped_model_folder()) / f"hand_model_{mode}.npz"
