"""`harp render AVATAR`: the fitted avatar in new poses, views and lights (a PNG)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from .formats import avatar_folder as av
from .formats import colour_model, environment_light, light_size, specular_lobe
from .formats import hand_model_file as fmt
from .handmodel.lbs import HandModel
from .handmodel.poses import NAMED_POSES
from .handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from .render.occlusion import bounce_radiance, hand_lost_light
from .render.renderer import Appearance, Light, RenderMesh, render


def load_avatar(folder, device=None):
    """(HandModel of the personalised rig, Appearance, AvatarFiles) of an avatar folder."""
    files = av.read_avatar_folder(folder)
    albedo, normal = (cv2.imread(str(path), cv2.IMREAD_COLOR) for path in (files.albedo, files.normal_map))
    if albedo is None or normal is None:
        raise av.AvatarFolderError(f"{folder} lacks a readable {av.ALBEDO_FILE} or {av.NORMAL_FILE}")
    albedo = torch.as_tensor(albedo[:, :, ::-1] / 255.0, dtype=torch.float32, device=device).permute(2, 0, 1)
    normal = torch.as_tensor(av.decode_normal_map(normal[:, :, ::-1]), dtype=torch.float32, device=device).permute(2, 0, 1)
    return HandModel(files.rig, device=device), Appearance(albedo.contiguous(), normal.contiguous()), files


def view_orientation(azimuth_deg, elevation_deg):
    """Global orientation showing the palm to the camera (fingers up), turned about the image's
    vertical axis by the azimuth and tilted by the elevation."""
    facing = torch.tensor([np.pi, 0.0, 0.0], dtype=torch.float32)
    turn = torch.tensor([0.0, np.radians(azimuth_deg), 0.0], dtype=torch.float32)
    tilt = torch.tensor([np.radians(elevation_deg), 0.0, 0.0], dtype=torch.float32)
    matrix = axis_angle_to_matrix(tilt) @ axis_angle_to_matrix(turn) @ axis_angle_to_matrix(facing)
    return matrix_to_axis_angle(matrix)


def render_avatar(folder, out, pose="rest", frame=None, azimuth=0.0, elevation=0.0, light=None, size=512,
                  shadows=None, background=(0.2, 0.2, 0.2)):
    """Render the avatar to `out` (PNG): a named pose (or the fitted pose of `frame`), seen from
    azimuth/elevation (degrees), lit by its fitted light or `light` (camera frame, metres)."""
    model, appearance, files = load_avatar(folder)
    if frame is not None:
        if not 0 <= frame < len(files.poses):
            raise av.AvatarFolderError(f"frame {frame} is not in the avatar (it has {len(files.poses)})")
        joint_pose = torch.as_tensor(files.poses.pose[frame], dtype=torch.float32)
    else:
        if pose not in NAMED_POSES:
            raise ValueError(f"unknown pose {pose!r}; choose one of {sorted(NAMED_POSES)}")
        joint_pose = torch.as_tensor(NAMED_POSES[pose], dtype=torch.float32)
        if model.side == "left":
            from .handmodel.mirror import mirror_axis_angle
            joint_pose = mirror_axis_angle(joint_pose)
    orient = view_orientation(azimuth, elevation)[None]
    with torch.no_grad():
        rest = model(pose=joint_pose[None], global_orient=orient).vertices
        hand = rest[:, torch.as_tensor(model.data.vertex_parts != fmt.PART_NAMES.index("forearm"))]
        centre = 0.5 * (hand.amin(1) + hand.amax(1))          # frame the hand; a forearm may leave the picture
        extent = (hand.amax(1) - hand.amin(1))[0, :2].max().item()
        focal = 2.0 * size
        distance = focal * extent / (0.8 * size)
        vertices = rest - centre + torch.tensor([0.0, 0.0, distance])
        K = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
        light_position = torch.tensor(light if light is not None else [0.3 * distance, -0.4 * distance, 0.2 * distance],
                                      dtype=torch.float32)
        fitted = files.description.get("light", {})
        ambient = torch.tensor(float(fitted.get("ambient", 0.6)))
        use_shadows = fitted.get("shadows", False) if shadows is None else shadows
        environment = environment_light.from_description(fitted)
        if environment is not None:   # the fitted room, fixed to the camera as the light is: the hand turns in it
            environment = torch.as_tensor(environment, dtype=torch.float32)
        lobe = specular_lobe.from_description(fitted)
        specular = None if lobe is None else tuple(torch.tensor(value) for value in lobe)
        mesh = RenderMesh.from_model_data(model.data)
        occlusion = hand_lost_light(vertices, model.data) if fitted.get("occlusion", False) else None
        images = render(vertices, mesh, K, size, size, outputs=("rgb",),
                        appearance=appearance,
                        light=Light(light_position, ambient, shadows=use_shadows, environment=environment,
                                    specular=specular, linear=colour_model.is_linear(fitted), occlusion=occlusion,
                                    angular_radius=light_size.from_description(fitted),
                                    bounce=None if occlusion is None else bounce_radiance(
                                        appearance.albedo, ambient, colour_model.is_linear(fitted))),
                        background=torch.tensor(background))
    image = (images["rgb"][0].clamp(0, 1).numpy() * 255).round().astype(np.uint8)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), image[:, :, ::-1]):
        raise OSError(f"could not write {out}")
    return out
