"""The Blender extension, with Blender (the bpy module) as the independent reference: the built
zip validates, installs, binds and exports through its buttons and unregisters cleanly; a bound
avatar reproduces the fit at every frame (the depsgraph's mesh against the fit's own posed
surface, the rig's keypoints through the Blender camera); glTF round trip; bad input.

Needs no torch: tools/blender_versions.py runs this file under each Blender the extension
declares, with an avatar fitted beforehand (tests/blender_fixture.py). The worker's tests, which
run the fitting engine, are in test_blender_worker.py."""
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from harp_addon import actions  # noqa: E402
from harp_addon.core import rotations  # noqa: E402
from harp_addon.rig import bone_names  # noqa: E402
from harp_addon.scene import CAPTURE_TO_WORLD, FIRST_FRAME, bind_avatar  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def arm_clip(prepared_avatar):
    return prepared_avatar.clip


@pytest.fixture(scope="module")
def arm_avatar(prepared_avatar):
    return prepared_avatar.avatar


def action_fcurves(action):
    """Every F-curve of an action: in its layers' channel bags from Blender 4.4 on (slotted
    actions), in action.fcurves before."""
    if hasattr(action, "layers"):
        return [curve for layer in action.layers for strip in layer.strips for bag in strip.channelbags
                for curve in bag.fcurves]
    return list(action.fcurves)


def evaluated_vertices(mesh_object):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = mesh_object.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    world = np.array(evaluated.matrix_world)
    evaluated.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3]


def rig_keypoints(bound, data):
    """The 21 keypoints carried by Blender's posed bones (world space)."""
    armature = bound.armature
    world = np.array(armature.matrix_world)
    transforms = np.stack([world @ np.array(armature.pose.bones[name].matrix)
                           @ np.linalg.inv(np.array(armature.pose.bones[name].bone.matrix_local))
                           for name in bone_names(data)])[data.keypoint_joints[:21]]
    return np.einsum("kij,kj->ki", transforms[:, :3, :3], data.keypoints[:21]) + transforms[:, :3, 3]


def bind_errors(prepared, scene):
    """(the bound avatar, worst vertex error mm, worst keypoint error px) of a bind of the
    prepared avatar against the fit's own posed surfaces and keypoints (made in torch)."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    surfaces, keypoints = prepared.surfaces, prepared.keypoints
    bound = bind_avatar(prepared.avatar)
    to_capture = np.linalg.inv(CAPTURE_TO_WORLD)
    worst_mm, worst_px = 0.0, 0.0
    for index, frame in enumerate(bound.frames):
        scene.frame_set(int(frame))
        blender = evaluated_vertices(bound.mesh) @ to_capture[:3, :3].T + to_capture[:3, 3]
        worst_mm = max(worst_mm, np.abs(blender - surfaces[index]).max() * 1000)
        fitted_px = (keypoints[index] @ bound.K.T)[:, :2] / keypoints[index][:, 2:]
        for point, expected in zip(rig_keypoints(bound, bound.files.rig), fitted_px):
            view = world_to_camera_view(scene, bound.camera, Vector(point))
            worst_px = max(worst_px, np.abs([view.x * bound.width - expected[0],
                                             (1 - view.y) * bound.height - expected[1]]).max())
    return bound, worst_mm, worst_px


def test_bound_avatar_reproduces_every_fitted_frame(prepared_avatar, arm_avatar, arm_clip, empty_scene):
    bound, worst_mm, worst_px = bind_errors(prepared_avatar, empty_scene)
    info = seq.read_sequence_info(arm_clip)
    assert (bound.width, bound.height) == (info.width, info.height)
    assert len(bound.armature.data.bones) == 17 and bound.armature.data.bones.get("forearm.R")  # arm mode
    print(f"worst vertex error {worst_mm:.2e} mm, worst keypoint {worst_px:.2e} px")
    assert worst_mm < 0.1 and worst_px < 0.5
    # the scene follows the footage; a second bind makes a second hand
    assert empty_scene.camera == bound.camera and empty_scene.render.fps / empty_scene.render.fps_base == \
        pytest.approx(info.fps)
    assert (empty_scene.frame_start, empty_scene.frame_end) == (FIRST_FRAME, FIRST_FRAME + info.frame_count - 1)
    second = bind_avatar(arm_avatar)
    assert second.collection != bound.collection and second.mesh != bound.mesh
    assert {o.name for o in second.collection.objects}.isdisjoint({o.name for o in bound.collection.objects})
    nodes = {node.bl_idname for node in bound.mesh.data.materials[0].node_tree.nodes}
    assert {"ShaderNodeTexImage", "ShaderNodeNormalMap", "ShaderNodeBsdfPrincipled"} <= nodes
    groups = {group.name for group in bound.mesh.vertex_groups}
    assert groups == set(bone_names(bound.files.rig)) and "index1.R" in groups


def test_a_left_hand_binds_as_exactly_as_a_right_one(prepared_left_avatar, empty_scene):
    bound, worst_mm, worst_px = bind_errors(prepared_left_avatar, empty_scene)
    print(f"left hand: worst vertex error {worst_mm:.2e} mm, worst keypoint {worst_px:.2e} px")
    assert bound.files.rig.side == "left"
    assert {bone.name for bone in bound.armature.data.bones} == {f"{name}.L" for name in bound.files.rig.joint_names}
    assert worst_mm < 0.001 and worst_px < 0.01


def test_smoothed_keys_carry_the_smoothed_motion(arm_avatar, empty_scene):
    from pipeline.formats import pose_smoothing, rotations

    files = av.read_avatar_folder(arm_avatar)
    smoothed = pose_smoothing.smooth_poses(files.poses, 5)
    assert np.abs(smoothed.pose - files.poses.pose).max() > 1e-3          # the filter changes this motion
    bound = bind_avatar(arm_avatar, smooth=5)
    names = bone_names(bound.files.rig)[:smoothed.pose.shape[1]]
    worst = 0.0
    for index, frame in enumerate(bound.frames):
        empty_scene.frame_set(int(frame))
        keyed = [np.array(bound.armature.pose.bones[name].rotation_quaternion) for name in names]
        expected = rotations.axis_angle_to_quaternion(smoothed.pose[index])
        worst = max(worst, max(1 - abs(q @ e) for q, e in zip(keyed, expected)))
        root = rotations.axis_angle_to_quaternion(smoothed.global_orient[index])
        assert abs(abs(np.array(bound.armature.rotation_quaternion) @ root) - 1) < 1e-5
        assert np.abs(np.array(bound.armature.location) - smoothed.transl[index]).max() < 1e-5
    assert worst < 1e-5 and bound.collection["harp_smoothing_frames"] == 5
    with pytest.raises(actions.ActionError, match="odd number of frames"):
        actions.bind(arm_avatar, smooth=6)


def test_gltf_round_trip(arm_avatar, tmp_path, empty_scene):
    bound = bind_avatar(arm_avatar)
    path = actions.export(bound, gltf=tmp_path / "hand.glb", blend=tmp_path / "hand.blend")[0]
    frames, bones, fps = len(bound.frames), len(bound.armature.data.bones), empty_scene.render.fps
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = fps
    bpy.ops.import_scene.gltf(filepath=str(path))
    armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    assert len(armatures) == 1 and len(armatures[0].data.bones) == bones
    action = armatures[0].animation_data.action
    start, end = action.frame_range
    keys = max(len(curve.keyframe_points) for curve in action_fcurves(action))
    assert round(end - start) + 1 == frames and keys == frames
    assert (tmp_path / "hand.blend").is_file()


def test_fbx_round_trip(arm_avatar, tmp_path, empty_scene):
    """Blender's FBX importer reads back what the export wrote: the same evaluated mesh at every
    frame, the armature's bones, the textures inside the file."""
    bound = bind_avatar(arm_avatar)
    expected = {}
    for frame in bound.frames:
        empty_scene.frame_set(int(frame))
        expected[int(frame)] = evaluated_vertices(bound.mesh)
    bones = {bone.name for bone in bound.armature.data.bones}
    path = actions.export(bound, fbx=tmp_path / "hand.fbx")[0]
    fps = empty_scene.render.fps
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = fps
    bpy.ops.import_scene.fbx(filepath=str(path), anim_offset=0.0)   # the file's times as written
    armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    assert len(armatures) == 1 and len(meshes) == 1 and meshes[0].parent == armatures[0]
    assert {bone.name for bone in armatures[0].data.bones} == bones
    worst = 0.0
    for frame, vertices in expected.items():
        bpy.context.scene.frame_set(frame)
        worst = max(worst, np.abs(evaluated_vertices(meshes[0]) - vertices).max() * 1000)
    print(f"FBX round trip: worst vertex difference {worst:.2e} mm over {len(expected)} frames")
    assert worst < 0.1
    images = {image.name: image for image in bpy.data.images}
    assert {"albedo.png", "normal.png"} <= set(images)
    for image in images.values():
        image.reload()
        assert image.packed_file is not None and tuple(image.size) == (64, 64) and image.has_data  # size loads it


def test_harp_blend(arm_avatar, tmp_path, capsys):
    from pipeline.cli import main

    assert main(["blend", str(arm_avatar), "--out", str(tmp_path / "scene.blend"), "--gltf",
                 str(tmp_path / "hand.glb"), "--fbx", str(tmp_path / "hand.fbx"), "--smooth", "5"]) == 0
    for name in ("scene.blend", "hand.glb", "hand.fbx"):
        assert (tmp_path / name).stat().st_size > 10000, name
    assert main(["blend", str(tmp_path / "missing"), "--out", str(tmp_path / "x.blend")]) == 1
    assert "avatar folder not found" in capsys.readouterr().err
    assert main(["blend", str(arm_avatar), "--out", str(tmp_path / "y.blend"), "--smooth", "4"]) == 1
    assert "odd number of frames" in capsys.readouterr().err and not (tmp_path / "y.blend").exists()


@pytest.mark.parametrize("damage, message", [
    ("poses", "missing"), ("albedo", "damaged"), ("version", "version 1; this program reads version 2"),
    ("rig", "rig.npz")])
def test_bad_avatar_folders_leave_nothing_behind(arm_avatar, tmp_path, empty_scene, damage, message):
    folder = tmp_path / "avatar"
    shutil.copytree(arm_avatar, folder)
    if damage == "poses":
        (folder / av.POSES_FILE).unlink()
    elif damage == "albedo":
        data = (folder / av.ALBEDO_FILE).read_bytes()
        (folder / av.ALBEDO_FILE).write_bytes(data[:len(data) // 2])
    elif damage == "version":
        description = json.loads((folder / av.AVATAR_FILE).read_text())
        (folder / av.AVATAR_FILE).write_text(json.dumps({**description, "version": 1}))
    else:
        (folder / av.RIG_FILE).write_bytes(b"not a zip")
    before = {kind: len(getattr(bpy.data, kind)) for kind in ("objects", "meshes", "materials", "images", "actions",
                                                              "collections", "armatures", "cameras")}
    with pytest.raises(actions.ActionError, match=message) as error:
        actions.bind(folder)
    assert "\n" not in str(error.value)
    after = {kind: len(getattr(bpy.data, kind)) for kind in before}
    assert after == before


def test_a_bind_that_fails_halfway_removes_what_it_made(arm_avatar, empty_scene, monkeypatch):
    from harp_addon import scene

    def broken(*args):
        raise RuntimeError("keyframes failed")

    monkeypatch.setattr(scene, "_keyframes", broken)
    before = {kind: len(getattr(bpy.data, kind)) for kind in scene.TRACKED}
    with pytest.raises(RuntimeError):
        scene.bind_avatar(arm_avatar)
    assert {kind: len(getattr(bpy.data, kind)) for kind in scene.TRACKED} == before


# ----------------------------------------------------------------------------- the extension

EXTENSION = "bl_ext.user_default.harp_avatar"


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory):
    from pipeline.addon_build import build_addon

    return build_addon(tmp_path_factory.mktemp("dist"))


def run_installed(zip_path, folder, body):
    """Run `body` (Python) in a fresh Blender process that has installed and enabled the
    extension zip, in a user folder of its own; returns its stdout."""
    script = textwrap.dedent(f"""
        import sys, bpy, addon_utils
        bpy.ops.extensions.package_install_files(filepath={str(zip_path)!r}, repo="user_default",
                                                 enable_on_install=True)
        name = {EXTENSION!r}
        """) + textwrap.dedent(body)
    environment = {**os.environ, "BLENDER_USER_RESOURCES": str(folder / "blender")}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            env=environment, cwd=folder)
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout


def test_extension_builds_validates_installs_and_unregisters_without_trace(extension_zip, tmp_path):
    out = run_installed(extension_zip, tmp_path, f"""
        assert hasattr(bpy.types.Scene, "harp") and hasattr(bpy.types, "HARP_PT_panel"), "not registered"
        assert bpy.context.preferences.addons[name].preferences.engine_python == {sys.executable!r}
        for _ in range(2):
            addon_utils.disable(name, default_set=True)
            assert not hasattr(bpy.types.Scene, "harp") and not hasattr(bpy.types, "HARP_PT_panel")
            assert not hasattr(bpy.types, "HARP_OT_fit") and name not in bpy.context.preferences.addons
            addon_utils.enable(name, default_set=True)
            assert hasattr(bpy.types.Scene, "harp") and hasattr(bpy.types, "HARP_OT_fit")
        module = sys.modules[name + ".core"]
        assert module.avatar_folder.__name__ == name + ".vendor.formats.avatar_folder"
        assert "torch" not in sys.modules and "cv2" not in sys.modules
        print("installed and cycled")
        """)
    assert "installed and cycled" in out


def test_the_installed_buttons_bind_and_export_and_fail_in_one_line(extension_zip, arm_avatar, tmp_path):
    """Bind, Motion onto rig and Export through the installed extension's operators (Export packs
    the images by default); an unexpected exception in Bind is one reported line and leaves no
    datablock."""
    out = run_installed(extension_zip, tmp_path, f"""
        import json
        settings = bpy.context.scene.harp
        settings.avatar = {str(arm_avatar)!r}
        assert bpy.ops.harp.bind() == {{"FINISHED"}}
        settings.gltf, settings.blend = {str(tmp_path / "hand.glb")!r}, {str(tmp_path / "hand.blend")!r}
        assert bpy.ops.harp.export() == {{"FINISHED"}}
        session_packed = [image.name for image in bpy.data.images if image.packed_file]
        try:
            bpy.ops.harp.retarget()
            no_rig = None
        except RuntimeError as error:
            no_rig = str(error)
        ours = next(o for o in bpy.data.objects if o.type == "ARMATURE")
        artist = ours.copy()
        artist.data = ours.data.copy()
        artist.animation_data_clear()
        bpy.context.scene.collection.objects.link(artist)
        for joint, bone in sys.modules[name + ".retarget"].bone_map("mixamo", "right").items():
            artist.data.bones[joint + ".R"].name = bone
        settings.retarget_rig = artist
        retargeted = bpy.ops.harp.retarget() == {{"FINISHED"}} and artist.animation_data.action is not None

        def broken(*args):
            raise KeyError("keyframes broke")

        sys.modules[name + ".scene"]._keyframes = broken
        kinds = sys.modules[name + ".scene"].TRACKED
        before = {{kind: len(getattr(bpy.data, kind)) for kind in kinds}}
        try:
            bpy.ops.harp.bind()
            reported = None
        except RuntimeError as error:      # in background mode an operator's error report is raised
            reported = str(error)
        after = {{kind: len(getattr(bpy.data, kind)) for kind in kinds}}
        bpy.ops.wm.open_mainfile(filepath={str(tmp_path / "hand.blend")!r})
        images = {{image.name: image.packed_file is not None for image in bpy.data.images
                  if image.source in ("FILE", "SEQUENCE")}}
        print("RESULT", json.dumps(dict(session_packed=session_packed, reported=reported,
                                        unchanged=before == after, images=images, no_rig=no_rig,
                                        retargeted=retargeted)))
        """)
    result = json.loads(out.split("RESULT", 1)[1])
    assert (tmp_path / "hand.glb").stat().st_size > 10000
    assert result["images"] == {"albedo.png": True, "normal.png": True, "000000.png": True}
    assert result["session_packed"] == []          # packed for the exported copy only
    assert result["reported"].strip() == ("Error: Bind avatar failed: KeyError: 'keyframes broke' "
                                          "(details in the system console)")
    assert result["unchanged"]
    assert result["no_rig"].strip() == "Error: pick an armature to put the motion on" and result["retargeted"]


def test_the_addon_binds_without_torch(arm_avatar, tmp_path):
    """Blender's own Python has no torch: the add-on's modules never import it (nor OpenCV)."""
    script = textwrap.dedent(f"""
        import sys
        sys.modules["torch"] = None     # any import of torch now fails
        sys.modules["cv2"] = None
        import bpy
        from harp_addon import actions
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bound = actions.bind({str(arm_avatar)!r})
        actions.export(bound, gltf={str(tmp_path / 'hand.glb')!r})
        print("bound", len(bound.frames), flush=True)
        import os
        os._exit(0)     # bpy 4.2 and 4.5 crash in the interpreter's teardown once their glTF exporter has run
        """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            cwd=ROOT)
    assert result.returncode == 0 and "bound 4" in result.stdout, result.stderr[-2000:]


def mixamo_style_rig(bound, rng, scene):
    """An artist's rig with Mixamo's bone names, built around the bound avatar's rest pose as a
    rig made for that hand would be, but nothing like ours in its details: in centimetres with the
    object scaled by 0.01 (as a Mixamo import), turned and moved in the world, every bone rolled
    and tilted at random, an upper-arm bone above the forearm and a tip bone after each finger.
    Returns (armature object, Q: our armature space -> theirs, 4 x 4)."""
    from mathutils import Matrix

    from harp_addon.retarget import bone_map

    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    names = bone_map("mixamo", data.side)
    turn = rotations.axis_angle_to_matrix(rng.normal(0, 1.0, 3))
    Q = np.eye(4)
    Q[:3, :3], Q[:3, 3] = 100.0 * turn, rng.normal(0, 20.0, 3)
    armature_data = bpy.data.armatures.new("artist")
    armature = bpy.data.objects.new("artist", armature_data)
    scene.collection.objects.link(armature)
    world = np.eye(4)
    world[:3, :3] = 0.01 * rotations.axis_angle_to_matrix(np.array([np.pi / 2, 0, 0]))
    world[:3, 3] = (1.0, -2.0, 0.5)
    armature.matrix_world = Matrix(world.tolist())
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    bones = {}
    shoulder = armature_data.edit_bones.new("mixamorig:RightArm" if data.side == "right" else "mixamorig:LeftArm")
    shoulder.head, shoulder.tail = (0.0, 0.0, 0.0), (0.0, 10.0, 0.0)
    for joint, name in names.items():
        rest = np.array(bound.armature.data.bones[ours[joint]].matrix_local)
        frame = turn @ rest[:3, :3] @ rotations.axis_angle_to_matrix(rng.normal(0, 0.6, 3))
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = frame, (Q @ np.append(rest[:3, 3], 1.0))[:3]
        bone = armature_data.edit_bones.new(name)
        bone.head, bone.tail = (0.0, 0.0, 0.0), (0.0, 2.0, 0.0)
        bone.matrix = Matrix(matrix.tolist())
        bones[joint] = bone
    for j, joint in enumerate(data.joint_names):
        parent = data.parents[j]
        if joint in bones:
            bones[joint].parent = bones[data.joint_names[parent]] if parent >= 0 else shoulder
            if joint.endswith("3"):
                tip = armature_data.edit_bones.new(names[joint][:-1] + "4")
                tip.head = bones[joint].tail
                tip.tail = bones[joint].tail + 0.3 * (bones[joint].tail - bones[joint].head)
                tip.parent = bones[joint]
    bpy.ops.object.mode_set(mode="OBJECT")
    return armature, Q


def carried_points(armature, bone_name, points):
    """(N, 3) world positions of `points` (N, 3, the bone's rest, in its armature's space) carried
    by the bone's posed transform."""
    pose_bone = armature.pose.bones[bone_name]
    transform = np.array(armature.matrix_world) @ np.array(pose_bone.matrix) @ np.linalg.inv(
        np.array(pose_bone.bone.matrix_local))
    return points @ transform[:3, :3].T + transform[:3, 3]


@pytest.mark.parametrize("prepared_name", ["prepared_avatar", "prepared_left_avatar"])
def test_the_motion_goes_onto_a_mixamo_style_rig(prepared_name, request, empty_scene):
    from harp_addon.retarget import bone_map, retarget_motion

    prepared = request.getfixturevalue(prepared_name)
    bound = bind_avatar(prepared.avatar)
    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    artist, Q = mixamo_style_rig(bound, np.random.default_rng(3), empty_scene)
    before = ({bone.name: tuple(bone.head_local) for bone in artist.data.bones},
              sum(len(bone.constraints) for bone in artist.pose.bones), len(artist.modifiers))
    mapping = bone_map("mixamo", data.side)
    result = retarget_motion(bound, artist, mapping)
    assert result.root == "forearm" and set(result.bones) == set(mapping)
    after = ({bone.name: tuple(bone.head_local) for bone in artist.data.bones},
             sum(len(bone.constraints) for bone in artist.pose.bones), len(artist.modifiers))
    assert after == before                                    # nothing added to their rig but keys
    keyed = {curve.data_path.split('"')[1] for curve in action_fcurves(result.action)}
    assert keyed == set(mapping.values())
    tips = {finger: np.nonzero(np.array(data.keypoint_joints[:21]) == data.joint_names.index(f"{finger}3"))[0]
            for finger in ("thumb", "index", "middle", "ring", "pinky")}
    errors = []
    for frame in bound.frames:
        empty_scene.frame_set(int(frame))
        for finger, keypoints in tips.items():
            rest = np.array(data.keypoints)[keypoints]     # our rig's rest fingertip (its shape is baked in)
            ours_world = carried_points(bound.armature, ours[f"{finger}3"], rest)
            theirs_rest = rest @ Q[:3, :3].T + Q[:3, 3]
            theirs_world = carried_points(artist, mapping[f"{finger}3"], theirs_rest)
            errors.append(np.linalg.norm(theirs_world - ours_world, axis=1).max() * 1000)
    print(f"{data.side} hand on a Mixamo-style rig: fingertips {np.mean(errors):.2e} mm mean, "
          f"{np.max(errors):.2e} mm worst")
    assert np.max(errors) < 0.01


def test_kept_placement_moves_only_the_hand_within_its_rig(prepared_avatar, empty_scene):
    from harp_addon.retarget import bone_map, retarget_motion

    bound = bind_avatar(prepared_avatar.avatar)
    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    artist, Q = mixamo_style_rig(bound, np.random.default_rng(4), empty_scene)
    mapping = bone_map("mixamo", data.side)
    result = retarget_motion(bound, artist, mapping, place="keep")
    paths = {curve.data_path for curve in action_fcurves(result.action)}
    assert not any(path.endswith("location") for path in paths)
    tips = [data.keypoint_joints[k] for k in (4, 8, 12, 16, 20)]       # the five fingertips' joints
    worst = 0.0
    for frame in bound.frames:
        empty_scene.frame_set(int(frame))
        ours_points, theirs_points = [], []
        for keypoint, joint in zip((4, 8, 12, 16, 20), tips):
            rest = np.array(data.keypoints)[[keypoint]]
            ours_points.append(carried_points(bound.armature, ours[data.joint_names[joint]], rest)[0])
            theirs_points.append(carried_points(artist, mapping[data.joint_names[joint]],
                                                rest @ Q[:3, :3].T + Q[:3, 3])[0])
        # the hand's shape at this frame: the distances between its fingertips, in metres in both rigs
        distances = [np.linalg.norm(np.array(p)[:, None] - np.array(p)[None], axis=-1)
                     for p in (ours_points, theirs_points)]
        worst = max(worst, np.abs(distances[0] - distances[1]).max() * 1000)
    assert worst < 0.01


def test_a_rig_that_cannot_take_the_motion_is_one_line(prepared_avatar, empty_scene, tmp_path):
    from harp_addon.retarget import RetargetError, bone_map, retarget_motion

    bound = bind_avatar(prepared_avatar.avatar)
    artist, _ = mixamo_style_rig(bound, np.random.default_rng(5), empty_scene)
    with pytest.raises(RetargetError, match="has no bone 'mixamorig:LeftForeArm' \\(nor 16 more"):
        retarget_motion(bound, artist, bone_map("mixamo", "left"))
    with pytest.raises(RetargetError, match="the avatar's own armature"):
        retarget_motion(bound, bound.armature, bone_map("mixamo", "right"))
    with pytest.raises(RetargetError, match="pick an armature"):
        retarget_motion(bound, bound.mesh, bone_map("mixamo", "right"))
    with pytest.raises(RetargetError, match="joints this avatar does not have: elbow"):
        retarget_motion(bound, artist, {"elbow": "mixamorig:RightArm"})
    written = actions.write_bone_map("rigify", "left", tmp_path / "maps" / "rigify.json")
    assert bone_map(str(written)) == bone_map("rigify", "left")          # the file reads back as the map
    with pytest.raises(actions.ActionError, match="choose a bone map file"):
        actions.write_bone_map("mixamo", "right", "")
    (tmp_path / "map.json").write_text("[1, 2]")
    with pytest.raises(RetargetError, match="not a JSON object"):
        bone_map(str(tmp_path / "map.json"))
    with pytest.raises(RetargetError, match="unknown rig kind"):
        bone_map("auto-rig-pro")
    assert artist.animation_data is None or artist.animation_data.action is None   # nothing left behind


def test_the_motion_goes_onto_a_generated_rigify_rig(prepared_avatar, empty_scene):
    from harp_addon.retarget import bone_map, retarget_motion
    from rigify_fixture import fitted_rigify_rig

    bound = bind_avatar(prepared_avatar.avatar)
    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    rig = fitted_rigify_rig(bound)
    bones_before = len(rig.data.bones)
    result = retarget_motion(bound, rig, bone_map("rigify", "right"))
    assert result.root == "wrist" and len(rig.data.bones) == bones_before
    assert {curve.data_path.split('"')[1] for curve in action_fcurves(result.action)} == set(result.bones.values())
    errors = []
    for frame in bound.frames:
        empty_scene.frame_set(int(frame))
        for finger, stem, tip in (("index", "f_index", 8), ("middle", "f_middle", 12), ("ring", "f_ring", 16),
                                  ("pinky", "f_pinky", 20), ("thumb", "thumb", 4)):
            rest = np.array(data.keypoints)[[tip]]
            ours_world = carried_points(bound.armature, ours[f"{finger}3"], rest)
            theirs_world = carried_points(rig, f"DEF-{stem}.03.R", rest)    # the bones that deform their mesh
            errors.append(np.linalg.norm(theirs_world - ours_world) * 1000)
    print(f"Rigify rig: fingertips {np.mean(errors):.3f} mm mean, {np.max(errors):.3f} mm worst")
    assert np.mean(errors) < 0.5 and np.max(errors) < 1.0


def test_the_personalised_mesh_can_go_onto_the_artists_rig(prepared_avatar, empty_scene):
    from harp_addon.retarget import RetargetError, bone_map, deform_map, retarget_motion

    bound = bind_avatar(prepared_avatar.avatar)
    data = bound.files.rig
    artist, _ = mixamo_style_rig(bound, np.random.default_rng(6), empty_scene)
    mapping = bone_map("mixamo", data.side)
    result = retarget_motion(bound, artist, mapping, deform=deform_map("mixamo", data.side))
    assert result.mesh.parent == artist and {group.name for group in result.mesh.vertex_groups} == set(mapping.values())
    worst = 0.0
    for frame in bound.frames:
        empty_scene.frame_set(int(frame))
        worst = max(worst, np.abs(evaluated_vertices(result.mesh) - evaluated_vertices(bound.mesh)).max() * 1000)
    print(f"the mesh on the artist's rig: worst vertex {worst:.2e} mm from the bound avatar's")
    assert worst < 0.01
    with pytest.raises(RetargetError, match="cannot go onto a Rigify rig yet"):
        deform_map("rigify", "right")


def test_the_panel_leaves_the_room_light_and_the_sheen_to_the_preset_unless_chosen():
    """Preview fits HARP's light alone and Fast decides both: the panel's default passes neither
    option to `harp fit`, so the preset decides; a choice made in the panel is passed on."""
    from harp_addon import operators, properties

    assert properties.ENVIRONMENTS[0][0] == properties.SPECULARS[0][0] == "preset"
    assert operators._unless_preset("preset") is None
    assert [operators._unless_preset(choice) for choice in ("auto", "on", "off")] == ["auto", "on", "off"]
