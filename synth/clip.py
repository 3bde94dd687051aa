"""One synthetic clip from settings to a finished sequence folder (bpy).

Steps: person (shape, personal geometry, albedo) -> Blender scene (rig, skin material, camera,
lights, mask scene) -> motion placed in front of the camera -> per frame: pose, render colour
and mask, read back Blender's evaluated vertices and bone transforms -> gt.npz and
sequence.json through pipeline/formats/sequence_folder.py (sequence.json is written last, so
an interrupted clip is recognisably incomplete).
"""
from __future__ import annotations

import dataclasses
import shutil
import sys
import time

import bpy
import numpy as np
from mathutils import Matrix

from harp_addon.rig import build_hand_rig
from pipeline.formats import camera as camera_convention
from pipeline.formats import hand_model_file as model_file
from pipeline.formats import sequence_folder as seq
from pipeline.handmodel import mirror

from . import SynthError
from .appearance import make_appearance
from .identity import make_identity, personal_offsets
from .lighting import setup_lighting
from .material import skin_material
from .motions import make_motion
from .passes import configure_cycles, make_mask_scene, render_still, silenced
from .viewpoint import camera_intrinsics, fit_distance, place_hand, view_rotation

FOREARM_PART = model_file.PART_NAMES.index("forearm")
GENERATOR = "harp-avatar synth"


def load_right_model(settings):
    """The right-hand model data of the requested mode (one-line error if it is missing)."""
    try:
        return model_file.load_hand_model(model_file.model_path(settings.mode, settings.model_folder))
    except model_file.HandModelFileError as error:
        raise SynthError(str(error)) from None


def prepare_output(settings):
    """Create the output folder; with --overwrite remove the files of an earlier clip."""
    out = settings.out
    if settings.overwrite and out.is_dir():
        for name in ("rgb", "mask"):
            if (out / name).is_dir():
                shutil.rmtree(out / name)
        for name in (seq.SEQUENCE_FILE, seq.GT_FILE, seq.GT_ALBEDO_FILE):
            (out / name).unlink(missing_ok=True)
    (out / "rgb").mkdir(parents=True, exist_ok=True)
    (out / "mask").mkdir(parents=True, exist_ok=True)


def hand_pivot_and_radius(data, betas):
    """Pivot (3,) on the hand's long axis halfway along the hand, and the radius (metres) of
    the sphere about it that holds the hand (forearm excluded)."""
    shaped = data.vertices + data.shapedirs @ betas
    hand = shaped[data.vertex_parts != FOREARM_PART]
    pivot = np.array([0.0, 0.5 * (hand[:, 1].min() + hand[:, 1].max()), 0.0])
    return pivot, float(np.linalg.norm(hand - pivot, axis=1).max())


@dataclasses.dataclass
class Person:
    data: object          # HandModelData of the requested side and mode
    identity: object      # identity.Identity
    offsets: np.ndarray   # (V, 3) rest-space personal displacements of `data`
    appearance: object    # appearance.Appearance


def make_person(settings, right=None, with_appearance=True):
    """The person of `settings`, built on the right hand and mirrored for a left one (so both
    sides of one identity share shape, personal geometry and albedo image)."""
    right = right if right is not None else load_right_model(settings)
    identity = make_identity(settings.identity, settings.skin_tone, settings.size, settings.betas, settings.features)
    offsets = personal_offsets(right, identity)
    appearance = make_appearance(right, identity, settings.texture_size) if with_appearance else None
    data = right
    if settings.side == "left":
        data, offsets = mirror.mirror_model_data(right), mirror.mirror_points(offsets)
    return Person(data=data, identity=identity, offsets=offsets, appearance=appearance)


def render_clip(settings, log=print):
    """Render the clip described by `settings` (options.ClipSettings). Returns a summary dict."""
    started = time.perf_counter()
    right = load_right_model(settings)
    prepare_output(settings)
    F = settings.frame_count

    person = make_person(settings, right)
    data, identity, offsets, appearance = person.data, person.identity, person.offsets, person.appearance
    betas = identity.betas
    albedo_path = seq.write_png(settings.out / seq.GT_ALBEDO_FILE, appearance.albedo)

    # motion and camera
    motion = make_motion(settings.motion, F, settings.fps, right.joint_limits, settings.mode, settings.seed)
    pose, rotation = motion.pose, motion.rotation
    if settings.side == "left":
        pose, rotation = mirror.mirror_axis_angle(pose), mirror.mirror_axis_angle(rotation)
    K = camera_intrinsics(settings.width, settings.height, settings.focal, settings.fov)
    pivot, radius = hand_pivot_and_radius(data, betas)
    distance = settings.distance or fit_distance(K, settings.width, settings.height, radius)
    global_orient, transl = place_hand(view_rotation(settings.azimuth, settings.elevation), rotation, pivot, distance)
    setup_seconds = time.perf_counter() - started

    # the Blender scene
    scene = new_scene(settings, K)
    hand_collection = bpy.data.collections.new("hand")
    scene.collection.children.link(hand_collection)
    rig = build_hand_rig(data, betas, offsets, collection=hand_collection)
    rig.mesh.data.materials.append(skin_material(albedo_path, appearance.roughness, identity.skin_tone,
                                                 subsurface=settings.subsurface, specular_level=settings.specular_level))
    light = setup_lighting(scene, settings.lighting, settings.background, target=[0.0, 0.0, distance],
                           seed=settings.seed)
    mask_scene = make_mask_scene(scene, hand_collection, scene.camera, settings.mask_engine)
    build_seconds = time.perf_counter() - started - setup_seconds

    info = seq.SequenceInfo(fps=settings.fps, width=settings.width, height=settings.height, frame_count=F,
                            hand_side=settings.side, K=K, ground_truth=seq.GT_FILE, albedo=seq.GT_ALBEDO_FILE)
    keypoints3d = np.zeros((F, 21, 3))
    vertices = np.zeros((F, data.num_vertices, 3), dtype=np.float32) if settings.save_vertices else None
    frame_seconds = []
    for index in range(F):
        tick = time.perf_counter()
        rig.set_pose(pose[index], global_orient[index], transl[index])
        keypoints3d[index] = rig.keypoints()[:21]
        if vertices is not None:
            vertices[index] = rig.evaluated_vertices(personal=True)
        scene.cycles.seed = settings.seed * 7919 + index
        render_still(scene, seq.frame_path(settings.out, info, index), quiet=not settings.verbose)
        render_still(mask_scene, seq.mask_path(settings.out, info, index), quiet=not settings.verbose)
        frame_seconds.append(time.perf_counter() - tick)
        log(f"frame {index + 1}/{F}: {frame_seconds[-1]:.2f} s")

    keypoints2d = camera_convention.project(keypoints3d.reshape(-1, 3), K)[0].reshape(F, 21, 2)
    gt = seq.GroundTruth(mode=settings.mode, side=settings.side, betas=betas, global_orient=global_orient,
                         transl=transl, pose=pose, keypoints3d=keypoints3d, keypoints2d=keypoints2d,
                         vertices=vertices, personal_offsets=offsets, light=light)
    seq.write_ground_truth(settings.out / seq.GT_FILE, gt)
    total = time.perf_counter() - started
    info.metadata = {
        "generator": GENERATOR, "settings": settings.to_json(), "identity": identity.to_json(),
        "camera": {"R": np.eye(3).tolist(), "t": [0.0, 0.0, 0.0], "distance_m": distance,
                   "azimuth_deg": settings.azimuth, "elevation_deg": settings.elevation},
        "timing_s": {"setup": round(setup_seconds, 3), "scene": round(build_seconds, 3),
                     "frames": round(float(np.sum(frame_seconds)), 3), "total": round(total, 3)},
        "blender": bpy.app.version_string,
    }
    seq.write_sequence_info(settings.out, info)
    return {"out": str(settings.out), "frames": F, "seconds": total,
            "seconds_per_frame": float(np.mean(frame_seconds))}


def new_scene(settings, K):
    """An empty scene with Cycles settings and the camera at the world origin (OpenCV frame)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = settings.width, settings.height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    with silenced(not settings.verbose):  # Cycles probes for GPUs and says so
        configure_cycles(scene, settings.samples, settings.denoise)
    if settings.threads:                  # several renders sharing the machine (synth/dataset.py --jobs)
        scene.render.threads_mode = "FIXED"
        scene.render.threads = settings.threads
    camera_data = bpy.data.cameras.new("camera")
    for key, value in camera_convention.blender_camera_settings(K, settings.width, settings.height).items():
        setattr(camera_data, key, value)
    camera_data.clip_start, camera_data.clip_end = 0.01, 1000.0
    camera = bpy.data.objects.new("camera", camera_data)
    camera.matrix_world = Matrix(camera_convention.blender_camera_matrix_world(np.eye(3), np.zeros(3)).tolist())
    scene.collection.objects.link(camera)
    scene.camera = camera
    return scene


def render_clip_from_args(args, log):
    """One clip of render.py's arguments `args` (an executor's cell: synth/dataset.py --jobs)."""
    from synth.options import parse_clip_args

    summary = render_clip(parse_clip_args(list(args)), log=log)
    return {"frames": summary["frames"], "seconds": summary["seconds"]}


def log_to_stderr(message):
    print(message, file=sys.stderr, flush=True)
