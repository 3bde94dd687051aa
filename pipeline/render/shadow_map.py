"""Self-shadowing by shadow mapping, differentiable in geometry and light position.

A depth map of the mesh is rendered from the light: a camera on a sphere of radius 1.5 m
around the hand's centre, looking at it, with a field of view that just holds the mesh. A
surface point is lit by the fraction V of the 3x3 shadow-map texels around its projection whose
depth is beyond its own (soft test sigmoid(1000 * (z_map - (z - 0.008))), metres). Depths in
the map are interpolated differentiably from the occluding faces.
"""
from __future__ import annotations

import torch

from .interpolate import fragments, interpolate
from .rasterize import project, rasterize

LIGHT_DISTANCE = 1.5
SHARPNESS = 1000.0
BIAS = 0.008
EMPTY_DEPTH = 100.0   # depth of texels that see no occluder


def light_camera(light_position, centre, radius, resolution):
    """World-to-light rotation (B, 3, 3), light camera position (B, 3) and K (3, 3)."""
    direction = torch.nn.functional.normalize(light_position - centre, dim=-1)
    eye = centre + LIGHT_DISTANCE * direction
    forward = -direction
    helper = torch.tensor([0.0, 1.0, 0.0], dtype=forward.dtype, device=forward.device).expand_as(forward)
    helper = torch.where((forward * helper).sum(-1, keepdim=True).abs() > 0.95,
                         torch.tensor([1.0, 0.0, 0.0], dtype=forward.dtype, device=forward.device), helper)
    right = torch.nn.functional.normalize(torch.cross(helper, forward, dim=-1), dim=-1)
    down = torch.cross(forward, right, dim=-1)
    rotation = torch.stack([right, down, forward], dim=1)
    half_angle = torch.asin((radius * 1.05 / LIGHT_DISTANCE).clamp(max=0.95))
    focal = (resolution / 2) / torch.tan(half_angle)
    K = torch.zeros(3, 3, dtype=forward.dtype, device=forward.device)
    K[0, 0] = K[1, 1] = focal
    K[0, 2] = K[1, 2] = resolution / 2
    K[2, 2] = 1
    return rotation, eye, K


def light_view(points, light_position, resolution, target=None, radius=None):
    """The shadow camera of shadow_visibility: (rotation (B, 3, 3), eye (B, 3), K (3, 3), the
    mesh in the light's frame (B, V, 3)); the framing (target, radius) carries no gradient."""
    batch = points.shape[0]
    light_position = light_position.expand(batch, 3) if light_position.dim() == 1 else light_position
    with torch.no_grad():
        centre = 0.5 * (points.amin(1) + points.amax(1)) if target is None else target.expand(batch, 3)
        if radius is None:
            radius = (points - centre[:, None]).norm(dim=-1).amax()
        radius = torch.as_tensor(radius, dtype=points.dtype, device=points.device)
    rotation, eye, K = light_camera(light_position, centre, radius, resolution)
    return rotation, eye, K, torch.einsum("bij,bvj->bvi", rotation, points - eye[:, None])


def shadow_visibility(points, faces, surface_points, surface_frame, light_position, resolution=256,
                      target=None, radius=None):
    """Visibility V (N, 1) in [0, 1] of surface points seen from the light.

    points (B, V, 3) mesh vertices and surface_points (N, 3) (frames surface_frame (N,)) in one
    frame of reference (the camera's); light_position (3,) or (B, 3) in that frame. The light
    camera looks at `target` (3,) or (B, 3) and holds a sphere of `radius` (metres); both default
    to the mesh's bounding box, and gradients treat this framing as fixed."""
    batch = points.shape[0]
    rotation, eye, K, in_light = light_view(points, light_position, resolution, target, radius)
    rast = rasterize(in_light, faces, K, resolution, resolution)
    frags = fragments(in_light, faces, K, rast)
    depth_map = torch.full((batch * resolution * resolution,), EMPTY_DEPTH, dtype=points.dtype, device=points.device)
    depth_map = depth_map.index_put((frags.pixel,), interpolate(in_light[..., 2:], frags, faces)[:, 0])
    depth_map = torch.nn.functional.pad(depth_map.view(batch, resolution, resolution), (1, 1, 1, 1), value=EMPTY_DEPTH)
    receiver = torch.einsum("nij,nj->ni", rotation[surface_frame], surface_points - eye[surface_frame])
    texel = project(receiver.unsqueeze(0), K)[0]
    column = torch.floor(texel[:, 0]).long().clamp(-1, resolution) + 1   # +1: padding
    row = torch.floor(texel[:, 1]).long().clamp(-1, resolution) + 1
    visibility = 0.0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            r = (row + dy).clamp(0, resolution + 1)
            c = (column + dx).clamp(0, resolution + 1)
            occluder = depth_map[surface_frame, r, c]
            visibility = visibility + torch.sigmoid(SHARPNESS * (occluder - (receiver[:, 2] - BIAS)))
    return (visibility / 9.0).unsqueeze(1)
