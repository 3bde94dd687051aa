"""A light with a size: a disc of light (a window, a softbox, a lamp's shade) in place of the
point light, seen from the hand under an angular radius.

Its shading and its shadows are the point light's averaged over `count` points spread evenly
over the disc (a sunflower spiral: equal areas, no two on one ring), the disc facing the hand's
centre. A point of the skin that sees the whole disc is lit as by its centre, up to the cosine's
curvature; one that sees part of it is in the penumbra, whose width grows with the distance
between the occluder and the point, as a window's shadows soften away from the finger that casts
them. Blender's sun of angle 2 x the radius casts the same shadows (harp_addon/scene.py).
"""
from __future__ import annotations

import math

import torch

from .shadow_map import facing_frame

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def disc_offsets(count: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """(count, 2) points of the unit disc: the k-th at radius sqrt((k + 1/2) / count) and angle
    k x the golden angle, so that each stands for an equal share of the disc's area."""
    k = torch.arange(count, dtype=torch.float64)
    radius = torch.sqrt((k + 0.5) / count)
    angle = k * GOLDEN_ANGLE
    return torch.stack([radius * torch.cos(angle), radius * torch.sin(angle)], dim=-1).to(dtype=dtype, device=device)


def light_points(position, centre, angular_radius: float, count: int) -> list:
    """The points the light's shading is averaged over: [position] for a point light
    (angular_radius 0 or count 1), else `count` points of the disc of that angular radius seen
    from `centre` ((3,) or (B, 3), what the light shines on), centred on `position` ((3,) or
    (B, 3)) and facing `centre`. The disc's frame carries no gradient: each point moves with
    `position` as the light's centre does."""
    if angular_radius <= 0 or count <= 1:
        return [position]
    with torch.no_grad():
        towards = position.detach() - centre
        distance = towards.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        across, up = facing_frame(towards / distance)
        radius = distance * math.tan(angular_radius)
        offsets = disc_offsets(count, towards.dtype, towards.device)
        shifts = [radius * (u * across + v * up) for u, v in offsets.tolist()]
    return [position + shift for shift in shifts]
