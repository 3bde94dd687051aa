"""Self-shadowing by shadow mapping, differentiable in geometry and light position.

A depth map of the mesh is rendered from the light: a camera on a sphere of radius 1.5 m
around the hand's centre, looking at it, with a field of view that just holds the mesh. A
surface point is lit by the share V of the shadow-map texels around its projection whose depth
is beyond its own (soft test sigmoid(1000 * (z_map - (z - 0.008))), metres): the test over a
3x3-texel box, interpolated bilinearly between the texel centres around the point (filter_taps),
so that V varies continuously as the point moves instead of in texel-sized steps (a shadow's
edge in a render is a ramp, not a staircase). Depths in the map are interpolated differentiably
from the occluding faces.
"""
from __future__ import annotations

import torch

from .interpolate import fragments, interpolate
from .rasterize import project, rasterize

LIGHT_DISTANCE = 1.5
SHARPNESS = 1000.0
BIAS = 0.008
EMPTY_DEPTH = 100.0   # depth of texels that see no occluder


def filter_taps(texel):
    """The texels each point's shadow test reads, and their weights: texel (N, 2) the points'
    positions in the shadow map (column, row in pixels; texel centres at +0.5). Returns the first
    of the 4 x 4 texels around each point (N, 2) (column, row; long, unclamped) and their weights
    (N, 16) (row by row), which sum to 1: the 3x3 box around the texel centre just before the
    point and the one just after, blended by the point's place between them (per axis
    (1 - f) / 3, 1 / 3, 1 / 3, f / 3). At a texel's centre this is that texel's 3x3 box.

    The weights carry no gradient, as the texels chosen do not: the map's occluders are
    rasterised, so their edges in it do not move with the geometry or the light, and a gradient
    through the receiver's place alone says that a hand moved as a whole, or a light moved, slides
    its shadows across it (a fit with it drove the light 0.8 m away on the phone-like clip)."""
    texel = texel.detach() - 0.5
    first = torch.floor(texel)
    fraction = texel - first
    third = torch.full_like(fraction, 1.0 / 3.0)
    per_axis = torch.stack([(1 - fraction) / 3, third, third, fraction / 3], dim=-1)   # (N, 2, 4)
    weights = per_axis[:, 1, :, None] * per_axis[:, 0, None, :]                         # (N, 4 rows, 4 columns)
    return first.long() - 1, weights.reshape(-1, 16)


def facing_frame(forward):
    """(right, down) unit (..., 3) completing the unit directions `forward` (..., 3) to a right-handed
    frame: right perpendicular to the y axis where it can be (the x axis where forward is within
    18 degrees of y)."""
    helper = torch.tensor([0.0, 1.0, 0.0], dtype=forward.dtype, device=forward.device).expand_as(forward)
    helper = torch.where((forward * helper).sum(-1, keepdim=True).abs() > 0.95,
                         torch.tensor([1.0, 0.0, 0.0], dtype=forward.dtype, device=forward.device), helper)
    right = torch.nn.functional.normalize(torch.cross(helper, forward, dim=-1), dim=-1)
    return right, torch.cross(forward, right, dim=-1)


def shadow_target(points, target=None):
    """(B, 3) what the shadow camera looks at: `target` ((3,) or (B, 3)), else each frame's mesh
    centre (its bounding box's); no gradient."""
    with torch.no_grad():
        if target is not None:
            return target.to(points.dtype).expand(points.shape[0], 3)
        return 0.5 * (points.amin(1) + points.amax(1))


def light_camera(light_position, centre, radius, resolution):
    """World-to-light rotation (B, 3, 3), light camera position (B, 3) and K (3, 3)."""
    direction = torch.nn.functional.normalize(light_position - centre, dim=-1)
    eye = centre + LIGHT_DISTANCE * direction
    forward = -direction
    right, down = facing_frame(forward)
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
    centre = shadow_target(points, target)
    with torch.no_grad():
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
    first, weights = filter_taps(texel)
    visibility = 0.0
    for dy in range(4):
        for dx in range(4):
            r = (first[:, 1] + dy).clamp(-1, resolution) + 1   # +1: padding
            c = (first[:, 0] + dx).clamp(-1, resolution) + 1
            occluder = depth_map[surface_frame, r, c]
            soft = torch.sigmoid(SHARPNESS * (occluder - (receiver[:, 2] - BIAS)))
            visibility = visibility + weights[:, 4 * dy + dx] * soft
    return visibility.unsqueeze(1)
