"""The hand (or hand + forearm) in Blender: mesh with UVs, armature with the model's bones and
its exact skinning weights, personal geometry as a shape key (bpy). One home for the rig: the
add-on binds avatars with it and synth/ renders its clips with it.

Blender reproduces the model's linear blend skinning exactly (see
pipeline/formats/hand_model_file.py): each bone's rest matrix is the joint's rest frame with
its head at the shaped joint pivot, a joint's axis-angle is the pose bone's rotation in that
frame, and the global rotation and translation are the armature object's matrix_world. The
mesh's basis is the shaped template (vertices + shapedirs @ betas); the "personal" shape key
adds the identity's displacements, so muting it gives the model's own surface.

Bones (and their vertex groups) are the model's joint names with Blender's side suffix,
`index1.R` or `index1.L` (bone_names), so that Blender's mirror tools (X-flipped pose paste,
symmetrize) pair a left hand with a right one.
"""
from __future__ import annotations

import dataclasses

import bpy
import numpy as np
from mathutils import Matrix

from .core import rotations

PERSONAL_KEY = "personal"
SIDE_SUFFIX = {"right": ".R", "left": ".L"}
MIN_BONE_LENGTH = 0.01  # metres; bone length only affects how the rig is drawn


@dataclasses.dataclass
class HandRig:
    """The Blender objects of one hand and the arrays needed to read ground truth back."""

    data: object                 # HandModelData (side already applied)
    armature: bpy.types.Object
    mesh: bpy.types.Object
    rest_keypoints: np.ndarray   # (K, 3) shaped rest keypoints (model space)

    @property
    def bone_names(self):
        return bone_names(self.data)

    def set_pose(self, pose, global_orient, transl):
        """pose (16, 3) local axis-angle, global_orient (3,) axis-angle about the wrist, transl (3,)."""
        for j in range(16):
            bone = self.armature.pose.bones[self.bone_names[j]]
            bone.rotation_quaternion = rotations.axis_angle_to_quaternion(pose[j]).tolist()
        world = np.eye(4)
        world[:3, :3] = rotations.axis_angle_to_matrix(global_orient)
        world[:3, 3] = transl
        self.armature.matrix_world = Matrix(world.tolist())
        bpy.context.view_layer.update()

    def bone_transforms(self):
        """(J, 4, 4) rest-to-posed world transform of every bone, from Blender's pose."""
        world = np.array(self.armature.matrix_world)
        return np.stack([world @ np.array(bone.matrix) @ np.linalg.inv(np.array(bone.bone.matrix_local))
                         for bone in (self.armature.pose.bones[name] for name in self.bone_names)])

    def keypoints(self):
        """(K, 3) posed keypoints: each rest keypoint carried by its joint's transform."""
        carriers = self.bone_transforms()[self.data.keypoint_joints]
        return np.einsum("kij,kj->ki", carriers[:, :3, :3], self.rest_keypoints) + carriers[:, :3, 3]

    def evaluated_vertices(self, personal=True):
        """(V, 3) Blender's evaluated (skinned) vertex positions in world space, with or
        without the personal displacements."""
        key = self.mesh.data.shape_keys.key_blocks.get(PERSONAL_KEY) if self.mesh.data.shape_keys else None
        if key is not None and not personal:
            key.value = 0.0
            bpy.context.view_layer.update()
        depsgraph = bpy.context.evaluated_depsgraph_get()
        evaluated = self.mesh.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        world = np.array(evaluated.matrix_world)
        evaluated.to_mesh_clear()
        if key is not None and not personal:
            key.value = 1.0
            bpy.context.view_layer.update()
        co = co.reshape(-1, 3).astype(np.float64)
        return co @ world[:3, :3].T + world[:3, 3]


def bone_names(data):
    """The Blender bone of each joint of `data` (HandModelData): its name and the side's suffix."""
    return [f"{name}{SIDE_SUFFIX[data.side]}" for name in data.joint_names]


def build_hand_rig(data, betas, personal_offsets=None, collection=None, name="hand"):
    """Create the armature and skinned mesh of `data` (HandModelData) with shape `betas` (S,)
    and optional rest-space personal offsets (V, 3) in metres. Returns a HandRig."""
    collection = collection or bpy.context.scene.collection
    betas = np.asarray(betas, dtype=np.float64)
    vertices = data.vertices + data.shapedirs @ betas
    joints = data.joints + data.joint_shapedirs @ betas
    keypoints = data.keypoints + data.keypoint_shapedirs @ betas

    armature = _build_armature(data, joints, keypoints, collection, name)
    mesh_object = _build_mesh(data, vertices, personal_offsets, collection, name)
    for j, bone_name in enumerate(bone_names(data)):
        group = mesh_object.vertex_groups.new(name=bone_name)
        rows, slots = np.nonzero((data.skin_indices == j) & (data.skin_weights > 0))
        for vertex, slot in zip(rows.tolist(), slots.tolist()):
            group.add([vertex], float(data.skin_weights[vertex, slot]), "REPLACE")
    modifier = mesh_object.modifiers.new("skin", "ARMATURE")
    modifier.object = armature
    modifier.use_vertex_groups = True
    modifier.use_bone_envelopes = False
    modifier.use_deform_preserve_volume = False  # plain linear blend skinning
    mesh_object.parent = armature
    mesh_object.matrix_parent_inverse = Matrix.Identity(4)
    mesh_object.matrix_basis = Matrix.Identity(4)
    return HandRig(data=data, armature=armature, mesh=mesh_object, rest_keypoints=keypoints)


def _build_mesh(data, vertices, personal_offsets, collection, name):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices.tolist(), [], data.faces.tolist())
    uv_layer = mesh.uv_layers.new(name="UVMap")
    uv_layer.data.foreach_set("uv", data.uvs[data.faces_uv].reshape(-1).astype(np.float32))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), dtype=bool))
    mesh.validate()
    mesh.update()
    mesh_object = bpy.data.objects.new(name, mesh)
    collection.objects.link(mesh_object)
    if personal_offsets is not None:
        mesh_object.shape_key_add(name="Basis", from_mix=False)
        key = mesh_object.shape_key_add(name=PERSONAL_KEY, from_mix=False)
        key.data.foreach_set("co", (vertices + personal_offsets).reshape(-1).astype(np.float32))
        key.value = 1.0
    return mesh_object


def _build_armature(data, joints, keypoints, collection, name):
    armature_data = bpy.data.armatures.new(f"{name}_armature")
    armature = bpy.data.objects.new(f"{name}_armature", armature_data)
    collection.objects.link(armature)
    view_layer = bpy.context.view_layer
    previous = view_layer.objects.active
    view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    lengths = _bone_lengths(data, joints, keypoints)
    bones = []
    for j, bone_name in enumerate(bone_names(data)):
        bone = armature_data.edit_bones.new(bone_name)
        bone.head, bone.tail = (0.0, 0.0, 0.0), (0.0, float(lengths[j]), 0.0)
        rest = np.eye(4)
        rest[:3, :3] = data.joint_frames[j]
        rest[:3, 3] = joints[j]
        bone.matrix = Matrix(rest.tolist())
        bone.use_deform = True
        bones.append(bone)
    for j, parent in enumerate(data.parents):
        if parent >= 0:
            bones[j].parent = bones[parent]
            bones[j].use_connect = False
    bpy.ops.object.mode_set(mode="OBJECT")
    view_layer.objects.active = previous
    for bone in armature.pose.bones:
        bone.rotation_mode = "QUATERNION"
    return armature


def _bone_lengths(data, joints, keypoints):
    """Distance from each joint to its first child (or to the keypoints it carries)."""
    lengths = np.full(len(joints), 0.03)
    for j in range(len(joints)):
        children = [c for c, p in enumerate(data.parents) if p == j]
        targets = [joints[c] for c in children] or [keypoints[k] for k in np.nonzero(data.keypoint_joints == j)[0]]
        if targets:
            lengths[j] = max(MIN_BONE_LENGTH, min(np.linalg.norm(t - joints[j]) for t in targets))
    return lengths
