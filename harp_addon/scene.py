"""An avatar folder bound into the scene (bpy): a collection with the capture space (an empty),
the footage camera, the armature at the person's rest joints, the personalised mesh skinned to
it (vertex groups from the skin weights, an Armature modifier: plain linear blend skinning), a
skin material (albedo, tangent-space normal map), and rotation keys on the root and every pose
bone at every fitted frame (optionally smoothed over a window of frames: formats/pose_smoothing.py).

Images are loaded by their absolute paths, so a .blend saved anywhere records them relative to
its own folder, whatever the working directory; with `pack` they travel inside it (the albedo,
the normal map and, behind the camera, the footage's first frame as a still).

Coordinates: the fit works in the camera frame (OpenCV: x right, y down, z forward). The capture
space maps it into Blender's world with Z up and the camera looking along +Y
(CAPTURE_TO_WORLD); the camera inside it is placed by pipeline/formats/camera.py, the one
conversion. Moving the empty moves the whole capture. Sequence frame f is scene frame
FIRST_FRAME + f.

Everything is checked before anything is made (formats/avatar_folder.read_avatar_folder), and
a bind that fails halfway removes what it made (removing_on_failure). Binding twice makes a
second hand in its own collection.
"""
from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .core import (avatar_folder, camera, environment_light, light_size, pose_smoothing, rotations, sequence_folder,
                   specular_lobe)
from .rig import build_hand_rig

CAPTURE_TO_WORLD = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
FIRST_FRAME = 1
UV_MAP = "UVMap"           # the rig's UV layer (rig.py)
ENVIRONMENT_IMAGE_SIZE = (64, 32)   # the baked environment light: bands 1 and 2 need no more
TRACKED = ("objects", "meshes", "armatures", "cameras", "lights", "worlds", "materials", "images", "actions",
           "collections")


class BindError(ValueError):
    """An avatar cannot be bound (one-line message)."""


@dataclasses.dataclass
class BoundAvatar:
    collection: bpy.types.Collection
    space: bpy.types.Object          # the capture space: parent of the camera and the armature
    armature: bpy.types.Object
    mesh: bpy.types.Object
    camera: bpy.types.Object
    frames: np.ndarray               # scene frames with keys, one per fitted frame
    K: np.ndarray                    # intrinsics at the scene's resolution
    width: int
    height: int
    files: avatar_folder.AvatarFiles


@contextlib.contextmanager
def removing_on_failure():
    """Removes every datablock (of the TRACKED kinds) made inside the block if the block fails."""
    before = {kind: set(getattr(bpy.data, kind)) for kind in TRACKED}
    try:
        yield
    except BaseException:
        for kind in TRACKED:   # objects first: the data they use is then free to go
            for block in [b for b in getattr(bpy.data, kind) if b not in before[kind]]:
                getattr(bpy.data, kind).remove(block)
        raise


def bind_avatar(folder, sequence=None, scene=None, name=None, pack=False, smooth=0) -> BoundAvatar:
    """Bind the avatar folder `folder` into `scene` (default: the current one). `sequence` is
    its footage (a sequence folder: sets the frame rate and range, the resolution and the
    camera's background); default: the footage the avatar records, when it still exists.
    `pack` packs the images into the .blend; `smooth` (frames, odd, or 0) smooths the keys
    (pose_smoothing.smooth_poses: less jitter, and on synthetic clips closer to the truth)."""
    folder = Path(folder)
    files = avatar_folder.read_avatar_folder(folder)
    try:
        poses = pose_smoothing.smooth_poses(files.poses, smooth)
    except pose_smoothing.SmoothingError as error:
        raise BindError(str(error)) from None
    scene = scene or bpy.context.scene
    footage = _footage(files, sequence)
    width, height, K, moving = _camera_at(files, footage)
    name = name or f"HARP {folder.name}"
    with removing_on_failure():
        collection, space = _capture(scene, name)
        collection["harp_avatar"] = str(folder.resolve())
        camera_object = _camera(name, collection, space, K, width, height, footage, pack, moving)
        rig = build_hand_rig(files.rig, np.zeros(files.rig.shapedirs.shape[-1]), collection=collection, name=name)
        rig.armature.parent = space
        rig.armature.matrix_parent_inverse = Matrix.Identity(4)
        rig.mesh.data.materials.append(_skin_material(name, files, pack))
        _fitted_light(name, collection, space, files, scene)
        frames = FIRST_FRAME + np.asarray(files.poses.frames, dtype=np.int64)
        _keyframes(rig, poses, frames)
        collection["harp_smoothing_frames"] = pose_smoothing.check_window(smooth)
        _scene_settings(scene, camera_object, footage, width, height, frames)
    return BoundAvatar(collection, space, rig.armature, rig.mesh, camera_object, frames, K, width, height, files)


def footage_camera(sequence, scene=None, name=None):
    """A capture space with the camera of an imported sequence folder and its frames behind
    it; sets the scene's frame rate, range and resolution. Returns the camera object."""
    scene = scene or bpy.context.scene
    try:
        info = sequence_folder.read_sequence_info(sequence)
    except ValueError as error:
        raise BindError(str(error)) from None
    footage = Path(sequence).resolve(), info
    name = name or f"HARP footage {footage[0].name}"
    with removing_on_failure():
        collection, space = _capture(scene, name)
        camera_object = _camera(name, collection, space, np.asarray(info.K, dtype=np.float64), info.width,
                                info.height, footage, pack=False, moving=_footage_principal_points(info))
        _scene_settings(scene, camera_object, footage, info.width, info.height,
                        np.array([FIRST_FRAME]))
    return camera_object


def _capture(scene, name):
    """A new collection in the scene holding the capture space (an empty at CAPTURE_TO_WORLD)."""
    collection = bpy.data.collections.new(name)
    scene.collection.children.link(collection)
    space = bpy.data.objects.new(f"{name} capture", None)
    collection.objects.link(space)
    space.matrix_world = Matrix(CAPTURE_TO_WORLD.tolist())
    return collection, space


def _footage(files, sequence):
    """(sequence folder, SequenceInfo) of the avatar's footage, or None."""
    if sequence is None:
        sequence = files.description.get("footage", {}).get("sequence")
        if sequence is None or not (Path(sequence) / sequence_folder.SEQUENCE_FILE).is_file():
            return None
    try:
        return Path(sequence).resolve(), sequence_folder.read_sequence_info(sequence)
    except ValueError as error:
        raise BindError(f"footage: {error}") from None


def _footage_principal_points(info):
    """(frames, (F, 2) principal points) of a sequence whose crop follows the hand, else None."""
    if info.principal_points is None:
        return None
    return FIRST_FRAME + np.arange(info.frame_count), np.asarray(info.principal_points, dtype=np.float64)


def _camera_at(files, footage):
    """(width, height, K, moving) of the scene: the footage's size when known, else the fitted
    images'; K is the fit's, scaled to that size; moving: (frames, principal points) where the
    crop follows the hand (every footage frame's, else every fitted frame's), or None."""
    entry = files.description.get("camera")
    if not entry:
        raise BindError("avatar.json has no camera")
    K, width, height = np.array(entry["K"], dtype=np.float64), int(entry["width"]), int(entry["height"])
    moving = None
    if entry.get("principal_points") is not None:
        moving = (FIRST_FRAME + np.asarray(files.poses.frames, dtype=np.int64),
                  np.asarray(entry["principal_points"], dtype=np.float64))
    if footage is not None:
        info = footage[1]
        scale = info.width / width
        if abs(info.height / height - scale) > 0.02:
            raise BindError(f"the footage is {info.width}x{info.height}, the avatar was fitted to {width}x{height} "
                            "images of another shape")
        K[:2] *= scale
        width, height = info.width, info.height
        moving = _footage_principal_points(info)
    return width, height, K, moving


def _camera(name, collection, space, K, width, height, footage, pack, moving=None):
    """The capture's camera (K); with `moving` (frames, principal points), its lens shift keyed
    at each frame (constant between keys), as each frame's own crop was cut."""
    data = bpy.data.cameras.new(f"{name} camera")
    for key, value in camera.blender_camera_settings(K, width, height).items():
        setattr(data, key, value)
    if moving is not None:
        _shift_keyframes(data, K, width, height, *moving)
    data.clip_start, data.clip_end = 0.01, 100.0
    camera_object = bpy.data.objects.new(f"{name} camera", data)
    collection.objects.link(camera_object)
    camera_object.parent = space
    camera_object.matrix_parent_inverse = Matrix.Identity(4)
    camera_object.matrix_basis = Matrix(camera.blender_camera_matrix_world(np.eye(3), np.zeros(3)).tolist())
    if footage is not None and footage[1].frames.get("kind", "images") == "images":
        image = _image(sequence_folder.frame_path(footage[0], footage[1], 0), "sRGB", pack, source="SEQUENCE")
        background = data.background_images.new()
        background.image = image
        background.image_user.frame_duration = footage[1].frame_count
        background.image_user.frame_start = FIRST_FRAME
        background.image_user.use_auto_refresh = True
        background.alpha, background.display_depth = 1.0, "BACK"
        data.show_background_images = True
    return camera_object


def _shift_keyframes(data, K, width, height, frames, principal_points):
    """Key the camera data's lens shift at `frames` to each principal point (F, 2)."""
    shifts = []
    for point in principal_points:
        frame_K = np.array(K, dtype=np.float64)
        frame_K[:2, 2] = point
        settings = camera.blender_camera_settings(frame_K, width, height)
        shifts.append((settings["shift_x"], settings["shift_y"]))
    shifts = np.asarray(shifts)
    data.shift_x, data.shift_y = shifts[0]
    action = bpy.data.actions.new(f"{data.name} crop")
    data.animation_data_create()
    data.animation_data.action = action
    for index, path in enumerate(("shift_x", "shift_y")):
        curve = _fcurve(action, data, path, 0)
        curve.keyframe_points.add(len(frames))
        curve.keyframe_points.foreach_set("co", np.stack([frames, shifts[:, index]], 1).ravel().astype(np.float32))
        curve.keyframe_points.foreach_set("interpolation", np.full(len(frames), _CONSTANT, dtype=np.int32))
        curve.update()


def _node_tree(block):
    """The shader nodes of a new material or world: before Blender 5.0 they have none until
    use_nodes is set (from 5.0 they always have them, and use_nodes is deprecated)."""
    if block.node_tree is None:
        block.use_nodes = True
    return block.node_tree


def _skin_material(name, files, pack):
    material = bpy.data.materials.new(f"{name} skin")
    tree = _node_tree(material)
    nodes, links = tree.nodes, tree.links
    shader = next(node for node in nodes if node.bl_idname == "ShaderNodeBsdfPrincipled")
    albedo = nodes.new("ShaderNodeTexImage")
    albedo.image = _image(files.albedo, "sRGB", pack)
    normal_image = nodes.new("ShaderNodeTexImage")
    normal_image.image = _image(files.normal_map, "Non-Color", pack)
    normal_map = nodes.new("ShaderNodeNormalMap")
    normal_map.space, normal_map.uv_map = "TANGENT", UV_MAP
    links.new(albedo.outputs["Color"], shader.inputs["Base Color"])
    links.new(normal_image.outputs["Color"], normal_map.inputs["Color"])
    links.new(normal_map.outputs["Normal"], shader.inputs["Normal"])
    set_specular_lobe(shader, files.description.get("light", {}))
    albedo.location, normal_image.location, normal_map.location = (-600, 300), (-600, -100), (-300, -100)
    return material


def set_specular_lobe(shader, light):
    """Give a Principled BSDF the sheen of the fit's `light` (avatar.json's): its lobe's roughness
    and level on single-scattering GGX, the lobe the fit renders (formats/specular_lobe.py); a fit
    that found none is matte; a folder from before the lobe keeps a satin skin."""
    shader.distribution = "GGX"
    for name, value in specular_lobe.principled_inputs(light).items():
        shader.inputs[name].default_value = value


def _fitted_light(name, collection, space, files, scene):
    """The fit's light as Blender lights: a sun from the direction of the fitted point light
    (seen from the hand), as strong as the fit's diffuse share (1 - ambient; a sun of strength
    pi (1 - a) lights a surface facing it like the fit's shading does), casting shadows only when
    the fit shadowed the hand (avatar.json's light.shadows), and, when the scene has
    no world yet, a world of the ambient share and the environment light (_fitted_world)."""
    light = files.description.get("light", {})
    ambient = float(light.get("ambient", 0.6))
    centre = np.asarray(files.poses.transl, dtype=np.float64).mean(0)
    towards = centre - np.asarray(light.get("position", centre + [0.0, -0.3, -0.3]), dtype=np.float64)
    towards /= max(np.linalg.norm(towards), 1e-9)
    z = -towards                                     # a sun shines along its local -Z
    x = np.cross([0.0, -1.0, 0.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
    matrix = np.eye(4)
    matrix[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    matrix[:3, 3] = centre - 0.3 * towards
    data = bpy.data.lights.new(f"{name} light", "SUN")
    data.energy = float(np.pi * (1 - ambient))
    # the hand shadows itself from this light only where the fit decided it does: a fit without
    # self-shadowing lit the far side of a finger from a light behind the hand (docs/blender.md)
    data.use_shadow = bool(light.get("shadows", False))
    data.angle = light_size.sun_angle(light)     # a fitted light with a size: a sun that wide, soft shadows as the fit's
    sun = bpy.data.objects.new(f"{name} light", data)
    collection.objects.link(sun)
    sun.parent = space
    sun.matrix_parent_inverse = Matrix.Identity(4)
    sun.matrix_basis = Matrix(matrix.tolist())
    if scene.world is None:
        scene.world = _fitted_world(name, ambient, environment_light.from_description(light))
    return sun


def _fitted_world(name, ambient, environment):
    """A world that lights the skin as the fit's ambient ratio and environment light do: a plain
    one of the ambient share, or, with an environment light, its radiance baked into a small
    equirectangular image (formats/environment_light.py) in the capture space's orientation."""
    world = bpy.data.worlds.new(f"{name} ambient")
    tree = _node_tree(world)
    background = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeBackground")
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = ambient
    if environment is None:
        return world
    width, height = ENVIRONMENT_IMAGE_SIZE
    radiance = environment_light.equirectangular_radiance(environment, ambient, width, height,
                                                          to_camera=CAPTURE_TO_WORLD[:3, :3].T)
    image = bpy.data.images.new(f"{name} environment", width, height, alpha=False, float_buffer=True)
    pixels = np.concatenate([radiance, np.ones((height, width, 1), np.float32)], axis=-1)
    image.pixels.foreach_set(pixels.reshape(-1))
    image.pack()          # a generated image is kept in the .blend only packed
    texture = tree.nodes.new("ShaderNodeTexEnvironment")
    texture.image, texture.location = image, (-300, 300)
    tree.links.new(texture.outputs["Color"], background.inputs["Color"])
    background.inputs["Strength"].default_value = 1.0
    return world


def _image(path, colour_space, pack, source="FILE"):
    """The image at `path`, loaded by its absolute path (a relative one would be read against
    the working directory but saved against the .blend's folder); packed with `pack`. A packed
    SEQUENCE is a still of its first frame: Blender reads a sequence's frames from files only."""
    path = Path(path).resolve()
    image = bpy.data.images.load(str(path), check_existing=False)
    if image.size[0] == 0 or image.size[1] == 0:
        raise BindError(f"Blender cannot read {path}")
    image.colorspace_settings.name = colour_space
    if pack:
        try:
            image.pack()
        except RuntimeError as error:
            raise BindError(f"cannot pack {path}: {str(error).strip()}") from None
    elif image.source != source:
        image.source = source
    return image


def _keyframes(rig, poses, frames):
    """Root location and rotation and every pose bone's rotation at every fitted frame (linear
    between them; quaternion signs kept continuous so no key turns the long way round)."""
    armature = rig.armature
    armature.rotation_mode = "QUATERNION"
    action = bpy.data.actions.new(f"{armature.name} motion")
    armature.animation_data_create()
    armature.animation_data.action = action
    channels = {"location": np.asarray(poses.transl),
                "rotation_quaternion": _continuous(rotations.axis_angle_to_quaternion(poses.global_orient))}
    for j, bone in enumerate(rig.bone_names[:len(poses.pose[0])]):
        channels[f'pose.bones["{bone}"].rotation_quaternion'] = _continuous(
            rotations.axis_angle_to_quaternion(poses.pose[:, j]))
    for path, values in channels.items():
        for index in range(values.shape[1]):
            curve = _fcurve(action, armature, path, index)
            curve.keyframe_points.add(len(frames))
            curve.keyframe_points.foreach_set("co", np.stack([frames, values[:, index]], 1).ravel().astype(np.float32))
            curve.keyframe_points.foreach_set("interpolation", np.full(len(frames), _LINEAR, dtype=np.int32))
            curve.update()


def _fcurve(action, owner, path, index):
    """A new F-curve of `action` animating `owner` (4.4 brought slotted actions, 5.0 dropped the
    slot-unaware action.fcurves)."""
    if hasattr(action, "fcurve_ensure_for_datablock"):
        return action.fcurve_ensure_for_datablock(owner, path, index=index)
    return action.fcurves.new(path, index=index)


_LINEAR = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value
_CONSTANT = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["CONSTANT"].value


def _continuous(quaternions):
    """(F, 4) quaternions with signs flipped where needed so consecutive ones agree."""
    return pose_smoothing.continuous_quaternions(quaternions)


def _scene_settings(scene, camera_object, footage, width, height, frames):
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    scene.camera = camera_object
    if footage is not None:
        info = footage[1]
        scene.render.fps, scene.render.fps_base = max(1, round(info.fps)), max(1, round(info.fps)) / info.fps
        scene.frame_start, scene.frame_end = FIRST_FRAME, FIRST_FRAME + info.frame_count - 1
    else:
        scene.frame_start, scene.frame_end = int(frames.min()), int(frames.max())
    scene.frame_set(int(frames[0]))
