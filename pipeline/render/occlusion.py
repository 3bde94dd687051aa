"""The room light's self-occlusion: the share of the ambient and environment light that each
vertex does not get because the hand itself stands between it and the room.

A world lights a Lambertian point with irradiance / pi = (1/pi) int L(w) max(0, n . w) dw over
every direction w; for the fit's room, L = a + sum_k c_k R_k (formats/environment_light.py), this
is a + sum_k c_k Y_k(n) when nothing is in the way, as the renderer shades without occlusion.
Between the fingers, under a bent thumb, in a palm closing, part of the sphere is the hand
itself, and what the point loses of the room's light is

    a O_0 + sum_k c_k O_k,   O_0 = (1/pi) int_blocked max(0, n . w) dw,
                             O_k = (1/pi) int_blocked max(0, n . w) R_k(w) dw

(O_0: the cosine-weighted blocked share, 0 in the open, 1 fully enclosed). Along a blocked
direction the point sees the hand's own skin, which sends light back (a path tracer finds it: a
pale skin returns most of what it blocks); with a `bounce` b (per colour, bounce_radiance: the
hand's mean albedo under its mean shading) seen in every blocked direction the loss is
a O_0 + sum_k c_k O_k - b O_0. The integrals are sums
over DIRECTIONS directions spread evenly over the sphere (weight 4 pi / D each); a direction is
blocked at a vertex where a depth map of the mesh seen from far along it holds a surface nearer
than the vertex (by a slope-scaled bias of a few texels, so that a surface never blocks itself).
Only the blocked share is summed, so a vertex with nothing in the way gets exactly the unoccluded
shading, whatever the number of directions.

The result is per vertex and carries no gradient (visibility is a step function of the
geometry): fits take it as a fixed factor of each frame's pose (fit/avatar.py).
"""
from __future__ import annotations

import functools

import torch

from ..formats.colour_model import srgb_to_linear
from ..formats.environment_light import radiance_basis, sphere_directions
from ..formats.hand_model_file import PART_NAMES
from ..handmodel.subdivision import unsubdivided_faces
from .rasterize import project, rasterize
from .shadow_map import light_view
from .shading import vertex_normals

DIRECTIONS = 64          # directions of the quadrature over the sphere
RESOLUTION = 128         # depth map texels across the mesh's bounding sphere
TERMS = 9                # O_0 (the ambient's) and O_1..O_8 (the environment's harmonics)
NORMAL_OFFSET = 1e-3     # metres: each vertex is tested a millimetre out of its surface
SLOPE_BIAS = 1.5         # texels of depth bias, times 1 + tan(angle between normal and direction)
MAX_SLOPE = 4.0          # tan clamped there (grazing directions weigh little: cosine-weighted)


@functools.lru_cache(maxsize=8)
def _quadrature(dtype, device, count):
    """(D, 3) directions and (D, 9) their rows [1, R_1..R_8] times the weight 4 pi / D / pi."""
    directions = torch.as_tensor(sphere_directions(count), dtype=dtype, device=device)
    rows = torch.stack([torch.ones_like(directions[:, 0])]
                       + radiance_basis(directions[:, 0], directions[:, 1], directions[:, 2]), dim=1)
    return directions, rows * (4.0 / count)


@torch.no_grad()
def blocked_directions(points, faces, directions, resolution=RESOLUTION, focus=None, chunk=16, occluders=None):
    """(B, V, D) bool: direction d (unit, camera frame) is blocked at vertex v of frame b by the
    mesh itself. points (B, V, 3) in the camera frame, faces (F, 3). The depth maps hold the
    vertices `focus` ((V,) bool, default all: the hand without its forearm keeps the texels small)
    and draw the faces `occluders` (default `faces`: a coarser surface over the same points draws
    faster); a vertex outside a map is taken as open in its direction."""
    occluders = faces if occluders is None else occluders
    batch, count = points.shape[0], points.shape[1]
    normals = vertex_normals(points, faces)
    receivers = points + NORMAL_OFFSET * normals
    held = points if focus is None else points[:, focus.to(points.device)]
    centre = 0.5 * (held.amin(1) + held.amax(1))                                      # (B, 3)
    radius = (held - centre[:, None]).norm(dim=-1).amax(1)                            # (B,)
    blocked = torch.zeros(batch, count, len(directions), dtype=torch.bool, device=points.device)
    for start in range(0, len(directions), chunk):
        part = directions[start:start + chunk]                                        # (d, 3)
        d = len(part)
        # every frame seen from each direction of the chunk: (d * B) views, direction-major
        view_points = points.repeat(d, 1, 1)
        view_centre = centre.repeat(d, 1)
        eyes = view_centre + 1.5 * part.repeat_interleave(batch, 0)
        rotation, eye, K, in_view = light_view(view_points, eyes, resolution, target=view_centre,
                                               radius=radius.amax())
        depth = rasterize(in_view, occluders, K, resolution, resolution).depth         # (dB, R, R)
        receiver = torch.einsum("bij,bvj->bvi", rotation, receivers.repeat(d, 1, 1) - eye[:, None])
        texel = project(receiver, K)
        inside = ((texel >= 0) & (texel < resolution)).all(-1)
        column = torch.floor(texel[..., 0]).long().clamp(0, resolution - 1)
        row = torch.floor(texel[..., 1]).long().clamp(0, resolution - 1)
        nearest = depth.view(d * batch, -1).gather(1, row * resolution + column)      # (dB, V)
        nearest = torch.where(inside, nearest, torch.full_like(nearest, float("inf")))
        cosine = (normals.repeat(d, 1, 1) * part.repeat_interleave(batch, 0)[:, None]).sum(-1)
        slope = (torch.sqrt((1 - cosine ** 2).clamp(min=0)) / cosine.clamp(min=1e-3)).clamp(max=MAX_SLOPE)
        texel_size = receiver[..., 2] / K[0, 0]                                        # metres per texel there
        bias = SLOPE_BIAS * texel_size * (1 + slope)
        hidden = nearest < receiver[..., 2] - bias
        blocked[:, :, start:start + d] = hidden.view(d, batch, count).permute(1, 2, 0)
    return blocked


@torch.no_grad()
def lost_light(points, faces, focus=None, directions=DIRECTIONS, resolution=RESOLUTION, occluders=None):
    """(B, V, 9) per vertex: [O_0, O_1..O_8] (module docstring), the room light a vertex of the
    posed mesh points (B, V, 3) (camera frame) does not get for the hand in the way; `focus`
    and `occluders` as blocked_directions'."""
    unit, rows = _quadrature(points.dtype, points.device, directions)
    blocked = blocked_directions(points, faces, unit, resolution, focus, occluders=occluders)  # (B, V, D)
    normals = vertex_normals(points, faces)
    cosine = (normals @ unit.T).clamp(min=0)                                           # (B, V, D)
    return (blocked.to(points.dtype) * cosine) @ rows


def hand_lost_light(points, data, faces=None):
    """lost_light of a posed hand model's mesh: points (B, V, 3), `data` its HandModelData (faces:
    its mesh's, default data.faces), the depth maps framing the hand without its forearm
    (hand_focus) and drawing the unsubdivided surface where the mesh is a subdivided one (a
    quarter of the faces to draw; the vertices it leaves out lie within a fraction of a
    millimetre of it, under the depth test's bias). Every user of the room light's occlusion
    measures it here, so the fit, `harp render` and the evaluation see the same."""
    faces = torch.as_tensor(data.faces if faces is None else faces, dtype=torch.long, device=points.device)
    occluders = unsubdivided_faces(faces) if data.metadata.get("subdivided", 0) else None
    return lost_light(points, faces, hand_focus(data.vertex_parts, points.device), occluders=occluders)


def hand_focus(vertex_parts, device=None):
    """(V,) bool: the vertices not on the forearm, what the depth maps frame (blocked_directions),
    or None where the mesh has no forearm."""
    focus = torch.as_tensor(vertex_parts != PART_NAMES.index("forearm"), device=device)
    return None if bool(focus.all()) else focus


def bounce_radiance(albedo, ambient, linear):
    """(3,) the light the hand's skin sends back along a blocked direction, in the shading's
    units: its mean albedo (decoded in linear light, `linear`; albedo (3, H, W)) under its mean
    shading, the ambient a and a quarter of the point light's share (the mean of max(0, n . l)
    over a sphere is 1/4): mean(albedo) (a + (1 - a) / 4). No gradient."""
    albedo = albedo.detach().clamp(0, 1)
    mean = (srgb_to_linear(albedo) if linear else albedo).mean((1, 2))
    ambient = torch.as_tensor(ambient, dtype=mean.dtype, device=mean.device).detach()
    return mean * (ambient + (1 - ambient) / 4)


def lost_shading(lost, ambient, environment=None, bounce=None):
    """(N, C) the shading factor a point loses to occlusion, a O_0 + sum_k c_k O_k - b O_0, of its
    interpolated `lost` (N, 9) under the ambient ratio a (scalar), the environment's coefficients
    (8, C) or None, and the skin's `bounce` b ((C,), bounce_radiance) or None."""
    loss = ambient * lost[:, :1]
    if environment is not None:
        loss = loss + lost[:, 1:] @ environment.to(lost.dtype)
    if bounce is not None:
        loss = loss - lost[:, :1] * bounce.to(lost.dtype)
    return loss

