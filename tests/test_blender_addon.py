"""The Blender extension, with Blender (the bpy module) as the independent reference: the built
zip validates, installs and unregisters cleanly; a bound avatar reproduces the fit at every
frame (the depsgraph's mesh against the torch model, the rig's keypoints through the Blender
camera); glTF round trip; the worker round trip (progress, cancel, resume, bind); bad input."""
import json
import os
import shutil
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch

from synth_clips import ROOT, render_tiny_clip

bpy = pytest.importorskip("bpy")

from harp_addon import actions, engine, jobs  # noqa: E402
from harp_addon.scene import CAPTURE_TO_WORLD, FIRST_FRAME, bind_avatar  # noqa: E402
from pipeline.evaluate.finished_fit import fitted_avatar, posed_surfaces  # noqa: E402
from pipeline.fit import fit  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402

FIT = dict(progress="none", max_steps=12, texture_size=64, batch_size=2, resolution=96, device="cpu")
pytestmark = [pytest.mark.blender, pytest.mark.usefixtures("one_torch_thread")]


@pytest.fixture(scope="module")
def arm_clip(tmp_path_factory):
    return render_tiny_clip(tmp_path_factory.mktemp("arm") / "clip", frames=4, mode="arm")


@pytest.fixture(scope="module")
def arm_avatar(arm_clip, tmp_path_factory):
    out = tmp_path_factory.mktemp("avatar") / "avatar"
    fit(arm_clip, out, **FIT)
    return out


@pytest.fixture
def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


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
                           for name in data.joint_names])[data.keypoint_joints[:21]]
    return np.einsum("kij,kj->ki", transforms[:, :3, :3], data.keypoints[:21]) + transforms[:, :3, 3]


def test_bound_avatar_reproduces_every_fitted_frame(arm_avatar, arm_clip, empty_scene):
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    avatar, _ = fitted_avatar(arm_avatar, arm_clip, "cpu")
    surfaces = posed_surfaces(avatar).double().numpy()
    with torch.no_grad():
        _, keypoints = avatar.posed(torch.arange(avatar.pose.shape[0]))
    keypoints = keypoints[:, :21].double().numpy()
    bound = bind_avatar(arm_avatar)
    info = seq.read_sequence_info(arm_clip)
    assert (bound.width, bound.height) == (info.width, info.height)
    assert len(bound.armature.data.bones) == 17 and bound.armature.data.bones.get("forearm")  # arm mode
    to_capture = np.linalg.inv(CAPTURE_TO_WORLD)
    worst_mm, worst_px = 0.0, 0.0
    for index, frame in enumerate(bound.frames):
        empty_scene.frame_set(int(frame))
        blender = evaluated_vertices(bound.mesh) @ to_capture[:3, :3].T + to_capture[:3, 3]
        worst_mm = max(worst_mm, np.abs(blender - surfaces[index]).max() * 1000)
        fitted_px = (keypoints[index] @ bound.K.T)[:, :2] / keypoints[index][:, 2:]
        for point, expected in zip(rig_keypoints(bound, bound.files.rig), fitted_px):
            view = world_to_camera_view(empty_scene, bound.camera, Vector(point))
            worst_px = max(worst_px, np.abs([view.x * bound.width - expected[0],
                                             (1 - view.y) * bound.height - expected[1]]).max())
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
    assert groups == set(bound.files.rig.joint_names)


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
    keys = max(len(curve.keyframe_points) for layer in action.layers for strip in layer.strips
               for bag in strip.channelbags for curve in bag.fcurves)
    assert round(end - start) + 1 == frames and keys == frames
    assert (tmp_path / "hand.blend").is_file()


def test_harp_blend(arm_avatar, tmp_path, capsys):
    from pipeline.cli import main

    assert main(["blend", str(arm_avatar), "--out", str(tmp_path / "scene.blend"), "--gltf",
                 str(tmp_path / "hand.glb")]) == 0
    assert (tmp_path / "scene.blend").stat().st_size > 10000 and (tmp_path / "hand.glb").stat().st_size > 10000
    assert main(["blend", str(tmp_path / "missing"), "--out", str(tmp_path / "x.blend")]) == 1
    assert "avatar folder not found" in capsys.readouterr().err


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


# ----------------------------------------------------------------------------- the worker

@pytest.fixture(scope="module")
def exact_clip(tmp_path_factory):
    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.init import initialise_sequence
    from synth.motions import RELAXED

    folder = tmp_path_factory.mktemp("exact") / "clip"
    write_clip(folder, RELAXED, frames=4, size=96)
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


def test_worker_round_trip_progress_cancel_resume_bind(exact_clip, tmp_path, empty_scene):
    out = tmp_path / "avatar"
    running = actions.start_fit("test", exact_clip, out, python=sys.executable, extra=["--max-steps", "60"])
    progress = []
    while running.job.active and not progress:
        progress += [event for event in running.job.poll() if event.kind == "progress"]
        time.sleep(0.05)    # as Blender's timer would: a busy loop here starves the worker
    actions.cancel("test")
    assert running.job.wait(timeout=240) == "cancelled", list(running.job.errors)
    assert progress and (out / "checkpoint.pt").is_file() and not (out / av.AVATAR_FILE).exists()
    assert "checkpoint saved" in actions.status_line(running)
    resumed = actions.start_fit("test", exact_clip, out, python=sys.executable, resume=True,
                                extra=["--max-steps", "60"])
    events = []
    while resumed.job.active:
        events += [event for event in resumed.job.poll() if event.kind == "progress"]
        time.sleep(0.05)
    assert resumed.job.state == "finished", list(resumed.job.errors)
    done = [event.done for event in events]
    assert done == sorted(done) and events[-1].done == events[-1].total
    assert any("resum" in line or "fitting" in line for line in resumed.job.log)
    bound = actions.bind(out)
    assert len(bound.frames) == 4


def test_worker_problems_are_one_line(exact_clip, tmp_path):
    with pytest.raises(actions.ActionError, match="no Python at /nowhere/python"):
        actions.start_fit("bad", exact_clip, tmp_path / "a", python="/nowhere/python")
    crash = jobs.Job([[sys.executable, "-c", textwrap.dedent("""
        import json, sys
        print(json.dumps({"event": "progress", "stage": "geometry", "step": 1, "loss": 0.5, "done": 1, "total": 9,
                          "seconds_left": 8.0}), flush=True)
        raise RuntimeError("the worker broke mid-fit")""")]], "fit").start()
    assert crash.wait(timeout=60) == "failed"
    assert crash.progress.done == 1 and "RuntimeError: the worker broke mid-fit" in crash.status_line()
    assert engine.check_engine("/nowhere/python").message == "no Python at /nowhere/python"
    status = engine.check_engine(sys.executable)
    assert status.ok and status.torch == torch.__version__ and "cpu" in status.device


def test_progress_lines():
    event = jobs.parse_progress_line('{"event": "progress", "stage": "align", "step": 3, "loss": 0.25, "done": 3, '
                                     '"total": 30, "seconds_left": 81.0}\n')
    assert (event.kind, event.stage, event.done, event.total, event.loss) == ("progress", "align", 3, 30, 0.25)
    assert jobs.parse_progress_line('{"event": "log", "message": "shadows auto"}').message == "shadows auto"
    assert jobs.parse_progress_line("plain text").kind == "log" and jobs.parse_progress_line("  ") is None


# ----------------------------------------------------------------------------- the extension

def test_extension_builds_validates_installs_and_unregisters_without_trace(tmp_path):
    from pipeline.addon_build import build_addon

    zip_path = build_addon(tmp_path / "dist")
    script = textwrap.dedent(f"""
        import sys, bpy, addon_utils
        bpy.ops.extensions.package_install_files(filepath={str(zip_path)!r}, repo="user_default",
                                                 enable_on_install=True)
        name = "bl_ext.user_default.harp_avatar"
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
    environment = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "blender")}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            env=environment, cwd=tmp_path)
    assert result.returncode == 0 and "installed and cycled" in result.stdout, result.stderr[-2000:]


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
        print("bound", len(bound.frames))
        """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            cwd=ROOT)
    assert result.returncode == 0 and "bound 4" in result.stdout, result.stderr[-2000:]
