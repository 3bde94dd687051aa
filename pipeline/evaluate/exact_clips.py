"""Tiny sequence folders rendered with the project's own renderer from exact ground truth (no
Blender, well under a second each): for tests and the study's stability sweep, which need a
particular pose, framing or hand size. The hand is the right hand-only model (or hand +
forearm) with the average shape unless `betas` are given, seen from the back with the fingers
up (synth's viewpoint convention), turning a little about its long axis from frame to frame; a
point light near the camera and a mottled skin albedo.

    info = write_clip(folder, FIST)                          # 4 frames, 96 x 96, hand fills the view
    info = write_clip(folder, OPEN, size=128, hand_px=30)    # a hand about 30 px tall
    info = write_clip(folder, OPEN, shift=(0.0, -0.45))      # moved up: the fingers leave the image
"""
from __future__ import annotations

import numpy as np
import torch

from synth.viewpoint import place_hand, view_rotation

from ..formats import environment_light, light_size, specular_lobe
from ..formats import sequence_folder as seq
from ..formats.colour_model import KEY, LINEAR, checked
from ..formats.camera import project
from ..handmodel.lbs import HandModel
from ..render.occlusion import bounce_radiance, hand_lost_light
from ..render.renderer import Appearance, Light, RenderMesh, render

BACKGROUND = (0.25, 0.27, 0.3)
TURN_DEGREES = 12.0      # rotation about the hand's long axis between frames
AMBIENT = 0.6
LIGHT_POSITION = (0.1, -0.2, 0.0)   # the point light, camera frame, metres


def coloured_room():
    """(8, 3) an environment light (formats/environment_light.py) whose colour changes with
    direction: blue light from the camera's left, warm light from below (not where the point
    light is), a little more around the camera's axis. Colour strength 0.038 at AMBIENT."""
    coefficients = np.zeros((environment_light.COEFFICIENTS, 3))
    coefficients[2] = -0.25 * np.array([0.3, 0.6, 1.0])      # Y ~ x: the left (-x) brighter and bluer
    coefficients[0] = 0.15 * np.array([1.0, 0.7, 0.4])       # Y ~ y: from below (+y, OpenCV's down), warm
    coefficients[5] = 0.05                                    # Y ~ 3 z^2 - 1
    return coefficients


def hyperextended_pose():
    """Open hand bent backwards 10 - 20 degrees past the joint limits (a stress case): MCPs 45
    degrees dorsal (limit 30), PIPs 20 (limit 5), DIPs 25 (limit 15), thumb IP 35 (limit 20)."""
    from synth.motions import OPEN

    pose = OPEN.copy()
    for mcp, pip, dip in ((1, 2, 3), (4, 5, 6), (7, 8, 9), (10, 11, 12)):
        pose[mcp, 0], pose[pip, 0], pose[dip, 0] = np.radians([-45, -20, -25])
    pose[15, 0] = np.radians(-35)
    return pose


def mottled_albedo(size=128, seed=0):
    """(3, size, size) skin albedo in [0, 1] with smooth blotches (something for the
    photometric term to fit)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:size, 0:size] / size
    blotches = sum(np.sin(2 * np.pi * (f1 * u + f2 * v) + phase)
                   for f1, f2, phase in rng.uniform([1, 1, 0], [6, 6, 2 * np.pi], (6, 3))) / 6
    skin = np.array([0.85, 0.66, 0.56])[:, None, None]
    return np.clip(skin * (1 + 0.25 * blotches[None]), 0, 1)


def posed_box(model, pose, betas):
    """(centre (3,), height) of the bounding box of the hand posed in `pose`, in model space
    (metres): the pivot the clip turns the hand about and its height in the front view."""
    with torch.no_grad():
        vertices = model(torch.as_tensor(betas), torch.as_tensor(pose[None])).vertices[0].numpy()
    low, high = vertices.min(0), vertices.max(0)
    return 0.5 * (low + high), float(high[1] - low[1])


def write_clip(folder, pose, frames=4, size=96, focal=None, hand_px=None, shift=(0.0, 0.0), azimuth=0.0, betas=None,
               turn_degrees=TURN_DEGREES, mode="hand", environment=None, specular=None, shadows=False,
               light_position=LIGHT_POSITION, colour_model=LINEAR, occlusion=False, ambient=AMBIENT,
               angular_radius=0.0):
    """Render `frames` frames of the hand in `pose` ((16, 3) or (F, 16, 3) axis-angle, radians,
    right hand) into the sequence folder `folder` with its exact ground truth (gt.npz,
    gt_albedo.png). The hand (its bounding box in frame 0's pose, centred) is 80% of the image
    tall, or `hand_px` pixels; `shift` moves it by fractions of the image (x right, y down; one
    (x, y) or one per frame);
    `azimuth` (degrees) turns the view about the hand's long axis (90: from the thumb side);
    `mode` "arm" renders the hand with its forearm (framed as a whole); `betas` (one number: every
    shape coefficient) default to the average hand; `environment` (8, 3) adds an environment light
    (formats/environment_light.py) to the point light and ambient; `specular` (roughness, level)
    gives the skin a specular lobe (formats/specular_lobe.py); `shadows` draws the point light's
    self-shadows (at `light_position`, camera frame, metres); `colour_model` (formats/colour_model.py)
    shades in linear light (as a camera sees) or the albedo's values as they are; `occlusion` holds the
    room light back where the hand is in its own way (render/occlusion.py; FitSettings.occlusion);
    `angular_radius` (radians) gives the point light a size (render/area_light.py: soft shadows, 64
    points of it). Returns the SequenceInfo."""
    model = HandModel.load(mode, "right", dtype=torch.float64)
    betas = np.broadcast_to(np.asarray(0.0 if betas is None else betas, dtype=np.float64), (model.num_betas,)).copy()
    pose = np.broadcast_to(np.asarray(pose, dtype=np.float64), (frames, 16, 3)).copy()
    if mode == "hand":
        pose[:, 0] = 0  # no wrist joint without a forearm
    focal = focal or 2000.0 * size / 448
    K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    pivot, height_m = posed_box(model, pose[0], betas)
    distance = focal * height_m / (hand_px or 0.8 * size)
    turns = np.zeros((frames, 3))
    turns[:, 1] = np.radians(turn_degrees) * (np.arange(frames) - (frames - 1) / 2)
    global_orient, transl = place_hand(view_rotation(azimuth, 0.0), turns, pivot, distance)
    shift = np.broadcast_to(np.asarray(shift, dtype=np.float64), (frames, 2))     # one, or one per frame
    transl = transl + distance / focal * size * np.concatenate([shift, np.zeros((frames, 1))], axis=1)

    with torch.no_grad():
        out = model(torch.as_tensor(betas), torch.as_tensor(pose), torch.as_tensor(global_orient),
                    torch.as_tensor(transl))
        albedo = mottled_albedo()
        mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
        light = Light(torch.tensor(light_position, dtype=torch.float64), torch.tensor(ambient, dtype=torch.float64),
                      shadows=shadows,
                      environment=None if environment is None else torch.as_tensor(environment, dtype=torch.float64),
                      specular=None if specular is None else tuple(torch.tensor(float(v), dtype=torch.float64)
                                                                   for v in specular),
                      linear=checked(colour_model) == LINEAR,
                      occlusion=hand_lost_light(out.vertices, model.data) if occlusion else None,
                      bounce=bounce_radiance(torch.as_tensor(albedo), ambient, checked(colour_model) == LINEAR)
                      if occlusion else None, angular_radius=angular_radius, samples=64)
        images = render(out.vertices, mesh, torch.as_tensor(K), size, size, outputs=("rgb", "alpha"),
                        appearance=Appearance(torch.as_tensor(albedo)), light=light,
                        background=torch.tensor(BACKGROUND, dtype=torch.float64))
    info = seq.SequenceInfo(fps=30.0, width=size, height=size, frame_count=frames, hand_side="right", K=K,
                            ground_truth=seq.GT_FILE, albedo=seq.GT_ALBEDO_FILE,
                            metadata={"generator": "pipeline/evaluate/exact_clips.py", "distance_m": distance})
    for index in range(frames):
        seq.write_png(seq.frame_path(folder, info, index), _to_uint8(images["rgb"][index].numpy()))
        seq.write_png(seq.mask_path(folder, info, index), np.where(images["alpha"][index, ..., 0].numpy() >= 0.5,
                                                                   255, 0).astype(np.uint8))
    keypoints3d = out.keypoints[:, :21].numpy()
    keypoints2d = project(keypoints3d.reshape(-1, 3), K)[0].reshape(frames, 21, 2)
    seq.write_ground_truth(folder / seq.GT_FILE, seq.GroundTruth(
        mode=mode, side="right", betas=betas, global_orient=global_orient, transl=transl, pose=pose,
        keypoints3d=keypoints3d, keypoints2d=keypoints2d, vertices=out.vertices.numpy(),
        light={"preset": "pipeline/evaluate/exact_clips.py", "position": list(light_position), "ambient": ambient,
               "shadows": shadows,
               "environment": environment_light.to_description(environment),
               specular_lobe.KEY: specular_lobe.to_description(*(specular or (None, None))),
               KEY: colour_model, "occlusion": bool(occlusion),
               light_size.KEY: light_size.to_description(angular_radius)}))
    seq.write_png(folder / seq.GT_ALBEDO_FILE, _to_uint8(albedo.transpose(1, 2, 0)))
    seq.write_sequence_info(folder, info)
    return info


def fraction_outside(folder):
    """Share of the hand's silhouette (all frames) that falls outside the image: the ground-truth
    vertices rendered on a canvas three times the image's size."""
    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    model = HandModel.load(gt.mode, "right", dtype=torch.float64)
    K = np.array(info.K, dtype=np.float64)
    K[0, 2] += info.width
    K[1, 2] += info.height
    with torch.no_grad():
        alpha = render(torch.as_tensor(gt.vertices, dtype=torch.float64), RenderMesh.from_model_data(model.data),
                       torch.as_tensor(K), 3 * info.height, 3 * info.width, antialiased=False)["alpha"][..., 0]
    inside = alpha[:, info.height:2 * info.height, info.width:2 * info.width].sum()
    return float(1 - inside / alpha.sum())


def _to_uint8(image):
    return (np.clip(image, 0, 1) * 255).round().astype(np.uint8)
