"""The fitted motion on the artist's own armature (bpy): keys on their hand bones, nothing else
added to their rig.

A bone map names, for each joint of ours (`wrist`, `index1`, ... and `forearm` in arm mode),
the artist's bone that plays it. BONE_MAPS holds one per rig kind (Mixamo's `mixamorig:` names;
a generated Rigify rig's hand IK control and finger FK controls), for either side; `bone_map()` gives one, a dict or a JSON
file gives any other (unmapped joints are left alone).

Each mapped bone takes our joint's rotation relative to its rest, expressed in the artist's
bone's own rest frame. The two rigs' rest poses are first put in register by one rotation G,
the one that turns our hand's rest frame into theirs (each hand's frame from its bones' heads:
wrist -> middle finger, and the palm's normal from the index and pinky knuckles; G = identity
when the map lacks those bones). With O = (G L_ours)^-1 L_theirs (L: a bone's rest frame in its
armature), their local rotation is O^-1 q O. Where both rigs share one rest pose, however placed,
rolled or scaled (an artist's rig built around the avatar), their bones then follow ours exactly;
otherwise their pose is their own rest pose bent as ours bends.

With `mesh`, a copy of the personalised mesh goes onto their rig too: carried into their rest
hand by the similarity that registers the two (G, the wrist, the wrist -> middle knuckle length),
its vertex groups renamed to the mapped bones, skinned to their armature (Mixamo-style rigs and
bone map files; not yet Rigify, whose deforming bones are not the keyed ones).

The root of the mapped chain (the first mapped bone whose parent is not mapped: the forearm or
the hand) is placed by `place`:
    "follow"   it goes where the capture puts our root, every frame (the hand follows the
               footage; their own parent bones, animated or not, are accounted for)
    "keep"     it keeps their rig's placement and takes only its local rotation
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .core import rotations
from .rig import bone_names

PLACES = ("follow", "keep")
FINGERS = ("index", "middle", "ring", "pinky", "thumb")


class RetargetError(ValueError):
    """The motion cannot go onto that armature (one-line message)."""


def _mixamo(side):
    prefix = f"mixamorig:{'Right' if side == 'right' else 'Left'}"
    names = {"forearm": f"{prefix}ForeArm", "wrist": f"{prefix}Hand"}
    for finger in FINGERS:
        for number in (1, 2, 3):
            names[f"{finger}{number}"] = f"{prefix}Hand{finger.capitalize()}{number}"
    return names


def _rigify(side):
    """A generated Rigify rig: the hand's IK control (the arm is in IK by default: its chain bends
    to reach the hand) and the fingers' FK controls."""
    suffix = ".R" if side == "right" else ".L"
    names = {"wrist": f"hand_ik{suffix}"}
    for finger in FINGERS:
        stem = "thumb" if finger == "thumb" else f"f_{finger}"
        for number in (1, 2, 3):
            names[f"{finger}{number}"] = f"{stem}.0{number}{suffix}"
    return names


BONE_MAPS = {"mixamo": _mixamo, "rigify": _rigify}


def bone_map(kind, side="right"):
    """{our joint name: their bone name} for a rig kind of BONE_MAPS, or read from a JSON file
    (`kind` a path) holding such a dict."""
    if kind in BONE_MAPS:
        return BONE_MAPS[kind](side)
    path = Path(kind)
    if not path.is_file():
        raise RetargetError(f"unknown rig kind {kind!r}: choose {', '.join(BONE_MAPS)} or give a bone map file")
    try:
        mapping = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise RetargetError(f"cannot read the bone map {path}: {error}") from None
    if not isinstance(mapping, dict) or not all(isinstance(v, str) for v in mapping.values()):
        raise RetargetError(f"the bone map {path} is not a JSON object of joint name -> bone name")
    return mapping


def deform_map(kind, side="right", mapping=None):
    """{our joint: their deforming bone} for moving the mesh: the keyed bones themselves. Not for
    Rigify, whose mesh is deformed by DEF- bones that follow the controls through its arm's IK and
    bendy bones: measured there, a mesh moved that way ended 0.13 m (mean) from the fit's."""
    if kind == "rigify":
        raise RetargetError("the mesh cannot go onto a Rigify rig yet: keep it on the avatar's armature")
    return dict(mapping if mapping is not None else bone_map(kind, side))


def save_bone_map(mapping, path):
    """Write a bone map as the JSON file bone_map() reads (for the artist to edit); returns the path."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(mapping, indent=1) + "\n")
    except OSError as error:
        raise RetargetError(f"cannot write the bone map {path}: {error.strerror or error}") from None
    return path


@dataclasses.dataclass
class Retargeted:
    armature: bpy.types.Object       # the artist's armature
    action: bpy.types.Action         # the keys put on it
    bones: dict                      # {our joint: their bone} keyed
    root: str                        # our joint at the root of the mapped chain
    mesh: bpy.types.Object | None = None   # the personalised mesh on their rig, when asked


def _mesh_onto(bound, target, deform, similarity):
    """A copy of the bound avatar's personalised mesh skinned to `target`: carried into their
    rest hand by `similarity` (_rest_similarity), its vertex groups renamed by `deform` ({our
    joint: their deforming bone}; groups of joints it leaves out are dropped). Returns it."""
    ours = dict(zip(bound.files.rig.joint_names, bone_names(bound.files.rig)))
    scale, rotation, shift = similarity
    mesh = bound.mesh.copy()
    mesh.data = bound.mesh.data.copy()
    mesh.animation_data_clear()
    if mesh.data.shape_keys is not None:
        mesh.shape_key_clear()
    count = len(mesh.data.vertices)
    points = np.empty(3 * count)
    mesh.data.vertices.foreach_get("co", points)
    points = scale * points.reshape(-1, 3) @ rotation.T + shift
    mesh.data.vertices.foreach_set("co", points.ravel())
    mesh.data.update()
    renamed = {ours[joint]: bone for joint, bone in deform.items()}
    for group in list(mesh.vertex_groups):
        if group.name in renamed:
            group.name = renamed[group.name]
        else:
            mesh.vertex_groups.remove(group)
    for modifier in mesh.modifiers:
        if modifier.type == "ARMATURE":
            modifier.object = target
    target.users_collection[0].objects.link(mesh)
    mesh.parent = target
    mesh.matrix_parent_inverse = Matrix.Identity(4)
    mesh.matrix_basis = Matrix.Identity(4)
    mesh.name = f"{bound.mesh.name} on {target.name}"
    return mesh


def _rest_similarity(our_armature, their_armature, ours, deform):
    """(scale, (3, 3) rotation, (3,) shift) from our armature's rest space to theirs: the
    registering rotation, the wrist onto their wrist, the wrist -> middle knuckle length."""
    if not all(joint in deform for joint in ("wrist", "index1", "middle1", "pinky1")):
        raise RetargetError("moving the mesh needs the wrist and the index, middle and pinky knuckles in the map")
    register = _hand_register(our_armature, their_armature,
                              {joint: (ours[joint], bone) for joint, bone in deform.items()})
    heads = [{joint: np.array(armature.data.bones[names[joint]].head_local) for joint in ("wrist", "middle1")}
             for armature, names in ((our_armature, ours), (their_armature, deform))]
    scale = (np.linalg.norm(heads[1]["middle1"] - heads[1]["wrist"]) /
             max(np.linalg.norm(heads[0]["middle1"] - heads[0]["wrist"]), 1e-12))
    return scale, register, heads[1]["wrist"] - scale * register @ heads[0]["wrist"]


def retarget_motion(bound, target, mapping, place="follow", scene=None, deform=None) -> Retargeted:
    """Key the motion of `bound` (a scene.BoundAvatar) onto the armature object `target` at
    every bound frame, bone by bone as `mapping` ({our joint name: their bone name}) says.
    Nothing but an action with those keys is added to `target`, and, with `deform` ({our joint:
    their deforming bone}), a copy of the personalised mesh skinned to it (_mesh_onto)."""
    scene = scene or bpy.context.scene
    if target is None or target.type != "ARMATURE":
        raise RetargetError("pick an armature to put the motion on")
    if target == bound.armature:
        raise RetargetError("that is the avatar's own armature: pick the rig the motion should go onto")
    if place not in PLACES:
        raise RetargetError(f"unknown placement {place!r}: choose {' or '.join(PLACES)}")
    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    unknown = sorted(set(mapping) - set(ours))
    if unknown:
        raise RetargetError(f"the bone map names joints this avatar does not have: {', '.join(unknown)}")
    missing = sorted(name for name in mapping.values() if name not in target.data.bones)
    if missing:
        raise RetargetError(f"{target.name} has no bone {missing[0]!r}"
                            + (f" (nor {len(missing) - 1} more of the map's)" if len(missing) > 1 else ""))
    if not mapping:
        raise RetargetError("the bone map is empty")
    similarity = None
    if deform is not None:
        absent = sorted(name for name in deform.values() if name not in target.data.bones)
        if absent:
            raise RetargetError(f"{target.name} has no deforming bone {absent[0]!r} for the mesh")
        similarity = _rest_similarity(bound.armature, target, ours, deform)
    order = [j for j, name in enumerate(data.joint_names) if name in mapping]
    order.sort(key=lambda j: _depth(data.parents, j))
    root = next(j for j in order if data.parents[j] < 0 or data.joint_names[data.parents[j]] not in mapping)
    register = _hand_register(bound.armature, target, {name: (ours[name], theirs) for name, theirs in mapping.items()})
    offsets = {j: _rest_offset(bound.armature.data.bones[ours[data.joint_names[j]]],
                               target.data.bones[mapping[data.joint_names[j]]], register) for j in order}

    action = bpy.data.actions.new(f"{target.name} HARP motion")
    target.animation_data_create()
    previous_action = target.animation_data.action
    target.animation_data.action = action
    previous_frame = scene.frame_current
    rotation_modes = {}
    try:
        for j in order:
            pose_bone = target.pose.bones[mapping[data.joint_names[j]]]
            rotation_modes[pose_bone.name] = pose_bone.rotation_mode
            pose_bone.rotation_mode = "QUATERNION"
        last = {}
        for frame in bound.frames:
            scene.frame_set(int(frame))
            for j in order:
                name = data.joint_names[j]
                theirs = target.pose.bones[mapping[name]]
                our_bone = bound.armature.pose.bones[ours[name]]
                if j == root and place == "follow":
                    _place_root(theirs, target, our_bone, bound.armature, offsets[j])
                    theirs.keyframe_insert("location", frame=int(frame))
                else:
                    local = np.array(our_bone.matrix_basis)[:3, :3]
                    offset = offsets[j]
                    theirs.rotation_quaternion = Matrix((offset.T @ local @ offset).tolist()).to_quaternion()
                quaternion = np.array(theirs.rotation_quaternion)
                if name in last and quaternion @ last[name] < 0:       # the short way round between keys
                    quaternion = -quaternion
                    theirs.rotation_quaternion = quaternion.tolist()
                last[name] = quaternion
                theirs.keyframe_insert("rotation_quaternion", frame=int(frame))
            bpy.context.view_layer.update()
    except BaseException:
        target.animation_data.action = previous_action
        bpy.data.actions.remove(action)
        for name, mode in rotation_modes.items():
            target.pose.bones[name].rotation_mode = mode
        raise
    finally:
        scene.frame_set(previous_frame)
    mesh = _mesh_onto(bound, target, deform, similarity) if deform is not None else None
    return Retargeted(target, action, {data.joint_names[j]: mapping[data.joint_names[j]] for j in order},
                      data.joint_names[root], mesh)


def _depth(parents, joint):
    depth = 0
    while parents[joint] >= 0:
        joint, depth = parents[joint], depth + 1
    return depth


def _rest_offset(our_bone, their_bone, register):
    """(3, 3) their bone's rest frame seen in ours, once our rest is turned by `register` (G)."""
    ours = register @ _orthonormal(np.array(our_bone.matrix_local)[:3, :3])
    theirs = _orthonormal(np.array(their_bone.matrix_local)[:3, :3])
    return _orthonormal(ours.T @ theirs)


def _hand_register(our_armature, their_armature, pairs):
    """(3, 3) G: our armature's directions -> theirs, turning our rest hand onto theirs;
    `pairs` {joint: (our bone, their bone)}. The identity when the map lacks the wrist, the index,
    middle or pinky knuckle."""
    needed = ("wrist", "index1", "middle1", "pinky1")
    if not all(name in pairs for name in needed):
        return np.eye(3)
    frames = []
    for side, armature in enumerate((our_armature, their_armature)):
        heads = {name: np.array(armature.data.bones[pairs[name][side]].head_local) for name in needed}
        frames.append(_hand_frame(heads))
    if any(frame is None for frame in frames):
        return np.eye(3)
    return frames[1] @ frames[0].T


def _hand_frame(heads):
    """(3, 3) columns: across the palm, wrist -> middle knuckle, the palm's normal; None when
    the knuckles are in a line."""
    along = heads["middle1"] - heads["wrist"]
    normal = np.cross(heads["index1"] - heads["wrist"], heads["pinky1"] - heads["wrist"])
    along_norm, normal_norm = np.linalg.norm(along), np.linalg.norm(normal)
    if along_norm < 1e-9 or normal_norm < 1e-9:
        return None
    y = along / along_norm
    z = normal - (normal @ y) * y
    if np.linalg.norm(z) < 1e-9:
        return None
    z /= np.linalg.norm(z)
    return np.stack([np.cross(y, z), y, z], axis=1)


def _orthonormal(matrix):
    u, _, vt = np.linalg.svd(matrix)
    return u @ vt


def _place_root(theirs, target, our_bone, our_armature, offset):
    """Pose their root bone so that its world frame is ours carried by the offset, its head at
    our bone's head: their own parents' pose at this frame is accounted for by pose_bone.matrix."""
    our_world = np.array(our_armature.matrix_world) @ np.array(our_bone.matrix)
    wanted = our_world.copy()
    wanted[:3, :3] = _orthonormal(our_world[:3, :3]) @ offset
    armature_space = np.linalg.inv(np.array(target.matrix_world)) @ wanted
    armature_space[:3, :3] = _orthonormal(armature_space[:3, :3])
    theirs.matrix = Matrix(armature_space.tolist())
    bpy.context.view_layer.update()
