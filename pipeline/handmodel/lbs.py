"""The hand model in torch: template + shape blend shapes + joints + linear blend skinning.

    model = HandModel.load("hand")                 # or "arm"; side="left" mirrors it
    out = model(betas, pose, global_orient, transl)
    out.vertices (B, V, 3), out.joints (B, J, 3), out.keypoints (B, K, 3)

betas (S,) or (B, S); pose (B, 16, 3) axis-angle per joint in the joint's rest frame (see
formats/hand_model_file.py); global_orient (B, 3) axis-angle in model space about the wrist;
transl (B, 3) the wrist's position. Works batched on any device, in float32 or float64.
"""
from __future__ import annotations

import dataclasses

import torch

from ..formats import hand_model_file as fmt
from .rotations import axis_angle_to_matrix


# the keypoints (MediaPipe order) whose spread HandModel.size measures, by part of the hand
SIZE_KEYPOINTS = {"hand": list(range(len(fmt.KEYPOINT_NAMES))),
                  "palm": [fmt.KEYPOINT_NAMES.index(name) for name in fmt.PALM_KEYPOINT_NAMES]}


@dataclasses.dataclass
class HandOutput:
    vertices: torch.Tensor        # (B, V, 3)
    joints: torch.Tensor          # (B, J, 3) posed joint pivots (the forearm's is the elbow)
    keypoints: torch.Tensor       # (B, K, 3) MediaPipe order (+ elbow)
    bone_transforms: torch.Tensor  # (B, J, 3, 4) rest space -> posed space per bone


def load_model_data(mode="hand", side="right", subdivided=False, folder=None):
    """HandModelData of a model (default: the shipped one), mirrored for the left side,
    optionally subdivided."""
    from .mirror import mirror_model_data
    from .subdivision import subdivide_model_data

    data = fmt.load_hand_model(fmt.model_path(mode, folder))
    if side == "left":
        data = mirror_model_data(data)
    elif side != "right":
        raise fmt.HandModelFileError(f"unknown hand side {side!r}; choose 'right' or 'left'")
    return subdivide_model_data(data) if subdivided else data


class HandModel(torch.nn.Module):
    """Posable hand (or hand + forearm); holds the model arrays as buffers."""

    def __init__(self, data: fmt.HandModelData, dtype=torch.float32, device=None):
        super().__init__()
        self.data = data
        self.mode, self.side = data.mode, data.side
        self.parents = [int(p) for p in data.parents]
        self.order = _topological_order(self.parents)

        def buffer(name, array, kind=dtype):
            self.register_buffer(name, torch.as_tensor(array, dtype=kind, device=device), persistent=False)

        buffer("v_template", data.vertices)
        buffer("shapedirs", data.shapedirs)
        buffer("weights", data.dense_weights())
        buffer("joints_template", data.joints)
        buffer("joint_shapedirs", data.joint_shapedirs)
        buffer("joint_frames", data.joint_frames)
        buffer("keypoints_template", data.keypoints)
        buffer("keypoint_shapedirs", data.keypoint_shapedirs)
        buffer("joint_limits", data.joint_limits)
        buffer("faces", data.faces, torch.long)
        buffer("keypoint_joints", data.keypoint_joints, torch.long)

    @classmethod
    def load(cls, mode="hand", side="right", subdivided=False, dtype=torch.float32, device=None, folder=None):
        return cls(load_model_data(mode, side, subdivided, folder), dtype=dtype, device=device)

    @property
    def num_betas(self):
        return self.shapedirs.shape[-1]

    def shaped(self, betas):
        """Rest vertices, joints and keypoints for shape betas (S,) or (B, S)."""
        betas = betas.to(self.v_template.dtype)
        vertices = self.v_template + torch.einsum("vcs,...s->...vc", self.shapedirs, betas)
        joints = self.joints_template + torch.einsum("jcs,...s->...jc", self.joint_shapedirs, betas)
        keypoints = self.keypoints_template + torch.einsum("kcs,...s->...kc", self.keypoint_shapedirs, betas)
        return vertices, joints, keypoints

    def size(self, betas, part="hand"):
        """The hand's overall size for shape betas (S,) or (B, S): the RMS distance (metres) of its
        rest keypoints from their centroid, over the 21 hand keypoints (part "hand": wrist, knuckles,
        joints and tips; no elbow) or the palm's six (part "palm": fmt.PALM_KEYPOINT_NAMES, which
        the fingers' lengths leave in place)."""
        index = SIZE_KEYPOINTS[part]          # the keypoints alone: the fit weighs this in every step
        keypoints = self.keypoints_template[index] + torch.einsum(
            "kcs,...s->...kc", self.keypoint_shapedirs[index], betas.to(self.v_template.dtype))
        return (keypoints - keypoints.mean(-2, keepdim=True)).square().sum(-1).mean(-1).sqrt()

    def bone_transforms(self, joints, pose, global_orient, transl):
        """(B, J, 3, 4) posed-from-rest affine transform of every bone.

        joints (J, 3) or (B, J, 3) shaped rest pivots."""
        batch = pose.shape[0]
        rotations = self.joint_frames[:16] @ axis_angle_to_matrix(pose) @ self.joint_frames[:16].transpose(-1, -2)
        joints = joints.expand(batch, -1, -1) if joints.dim() == 2 else joints
        root_rotation = axis_angle_to_matrix(global_orient)
        world_rotation = [None] * len(self.parents)
        world_translation = [None] * len(self.parents)
        for j in self.order:
            if j < 16:
                local_rotation = rotations[:, j]
                local_translation = joints[:, j] - (local_rotation @ joints[:, j, :, None])[..., 0]
            else:  # the forearm bone has no rotation of its own
                local_rotation = None
                local_translation = None
            parent = self.parents[j]
            if parent < 0:
                parent_rotation, parent_translation = root_rotation, transl
            else:
                parent_rotation, parent_translation = world_rotation[parent], world_translation[parent]
            if local_rotation is None:
                world_rotation[j], world_translation[j] = parent_rotation, parent_translation
            else:
                world_rotation[j] = parent_rotation @ local_rotation
                world_translation[j] = (parent_rotation @ local_translation[..., None])[..., 0] + parent_translation
        rotation = torch.stack(world_rotation, dim=1)
        translation = torch.stack(world_translation, dim=1)
        return torch.cat([rotation, translation[..., None]], dim=-1)

    def forward(self, betas=None, pose=None, global_orient=None, transl=None, rest_vertices=None):
        """Posed vertices, joints and keypoints (HandOutput) of B frames. `rest_vertices` (V, 3)
        replace the shaped template as the surface that is skinned (e.g. with personal offsets);
        joints and keypoints always follow `betas`."""
        dtype, device = self.v_template.dtype, self.v_template.device
        batch = next((t.shape[0] for t in (pose, global_orient, transl) if t is not None),
                     betas.shape[0] if betas is not None and betas.dim() == 2 else 1)
        if betas is None:
            betas = torch.zeros(self.num_betas, dtype=dtype, device=device)
        if pose is None:
            pose = torch.zeros(batch, 16, 3, dtype=dtype, device=device)
        if global_orient is None:
            global_orient = torch.zeros(batch, 3, dtype=dtype, device=device)
        if transl is None:
            transl = torch.zeros(batch, 3, dtype=dtype, device=device)
        pose = pose.to(dtype).reshape(batch, 16, 3)
        global_orient, transl = global_orient.to(dtype), transl.to(dtype)
        vertices, joints, keypoints = self.shaped(betas)
        if rest_vertices is not None:
            vertices = rest_vertices.to(dtype)
        transforms = self.bone_transforms(joints, pose, global_orient, transl)
        blended = torch.einsum("vj,bjk->bvk", self.weights, transforms.reshape(batch, -1, 12)).reshape(batch, -1, 3, 4)
        posed = _Blend.apply(blended, vertices)
        posed_joints = _apply(transforms, joints.expand(batch, -1, -1))
        carriers = transforms[:, self.keypoint_joints]
        posed_keypoints = _apply(carriers, keypoints.expand(batch, -1, -1))
        return HandOutput(posed, posed_joints, posed_keypoints, transforms)


class _Blend(torch.autograd.Function):
    """(B, V, 3) rest points (V, 3) (or each frame's, (B, V, 3)) moved by each frame's blended
    affine transform of each vertex (B, V, 3, 4): A v + t. Autograd's record of the broadcast
    product allocated several (B, V, 3, 4) tensors per pass; this forward is three fused
    multiply-adds, the backward d/dA = g v^T, d/dt = g, d/dv = the sum over frames of A^T g."""

    @staticmethod
    def forward(ctx, blended, vertices):
        ctx.save_for_backward(blended, vertices)
        x, y, z = (vertices[..., k, None] for k in range(3))
        return torch.addcmul(torch.addcmul(torch.addcmul(blended[..., 3], blended[..., 0], x),
                                           blended[..., 1], y), blended[..., 2], z)

    @staticmethod
    def backward(ctx, grad):
        blended, vertices = ctx.saved_tensors
        homogeneous = torch.cat([vertices, vertices.new_ones(*vertices.shape[:-1], 1)], -1)   # (..., V, 4)
        grad_blended = grad[..., None] * homogeneous[..., None, :] if ctx.needs_input_grad[0] else None
        grad_vertices = None
        if ctx.needs_input_grad[1]:
            grad_vertices = torch.einsum("bvi,bvij->" + ("vj" if vertices.dim() == 2 else "bvj"), grad, blended[..., :3])
        return grad_blended, grad_vertices


def _apply(transforms, points):
    """Apply (B, N, 3, 4) affine transforms to (B, N, 3) points."""
    return (transforms[..., :3] @ points[..., None])[..., 0] + transforms[..., 3]


def _topological_order(parents):
    order, placed = [], set()
    while len(order) < len(parents):
        for j, p in enumerate(parents):
            if j not in placed and (p < 0 or p in placed):
                order.append(j)
                placed.add(j)
    return order
