"""Shading formulas: vertex normals, UV tangent frames, tangent-space normal maps and the
HARP light model  colour = albedo * (a + (1 - a) * max(0, n' . l) * V), and the environment
light's and the specular lobe's shares of it (formats/environment_light.py, formats/specular_lobe.py)."""
from __future__ import annotations

import functools

import torch

from ..formats.environment_light import basis as environment_basis
from ..formats.environment_light import radiance_basis, sphere_directions
from ..formats.specular_lobe import BASE_REFLECTANCE


def vertex_normals(points, faces):
    """(B, V, 3) unit area-weighted vertex normals of (B, V, 3) points."""
    v0, v1, v2 = (points[:, faces[:, k]] for k in range(3))
    face_normals = torch.cross(v1 - v0, v2 - v0, dim=-1)
    normals = torch.zeros_like(points)
    for k in range(3):
        normals = normals.index_add(1, faces[:, k], face_normals)
    return torch.nn.functional.normalize(normals, dim=-1, eps=1e-12)


def uv_tangents(points, faces, uvs, faces_uv):
    """Per-UV-vertex tangents (B, U, 3) (direction of increasing u on the surface) and the
    per-face handedness (F,) (+1, or -1 where a chart is mirrored in UV space)."""
    p0, p1, p2 = (points[:, faces[:, k]] for k in range(3))
    t0, t1, t2 = (uvs[faces_uv[:, k]] for k in range(3))
    face_tangent, handedness = face_tangents(p0, p1, p2, t0, t1, t2)
    tangents = torch.zeros(points.shape[0], uvs.shape[0], 3, dtype=points.dtype, device=points.device)
    for k in range(3):
        tangents = tangents.index_add(1, faces_uv[:, k], face_tangent)
    return tangents, handedness


def face_tangents(p0, p1, p2, t0, t1, t2):
    """Per-face tangent (B, F, 3) from corner positions (B, F, 3) and UVs (F, 2), and the
    handedness (F,): +1, or -1 where the face is mirrored in UV space."""
    e1, e2 = p1 - p0, p2 - p0
    d1, d2 = t1 - t0, t2 - t0
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    handedness = torch.where(det < 0, -1.0, 1.0).to(p0.dtype)
    safe = torch.where(det.abs() > 1e-20, det, torch.full_like(det, 1e-20))
    return (e1 * d2[:, 1, None] - e2 * d1[:, 1, None]) / safe[:, None], handedness


def perturbed_normal(normal, tangent, handedness, normal_map_value):
    """Shading normal from a tangent-space normal-map value (N, 3) in [-1, 1] (z out of the
    surface), the interpolated normal (N, 3), tangent (N, 3) and handedness (N,)."""
    n = torch.nn.functional.normalize(normal, dim=-1, eps=1e-12)
    t = tangent - (tangent * n).sum(-1, keepdim=True) * n
    t = torch.nn.functional.normalize(t, dim=-1, eps=1e-12)
    b = handedness[:, None] * torch.cross(n, t, dim=-1)
    m = normal_map_value
    return torch.nn.functional.normalize(m[:, :1] * t + m[:, 1:2] * b + m[:, 2:3] * n, dim=-1, eps=1e-12)


def shade(albedo, normal, to_light, ambient, visibility=None):
    """colour = albedo * (a + (1 - a) * max(0, n . l) * V); all (N, .), ambient a scalar or (N, 1)."""
    diffuse = (normal * to_light).sum(-1, keepdim=True).clamp(min=0)
    if visibility is not None:
        diffuse = diffuse * visibility
    return albedo * (ambient + (1 - ambient) * diffuse)


def lit_colour(albedo, normal, position, light_position, ambient, visibility=None):
    """shade() under a point light at light_position ((3,) or (N, 3)) seen from the surface
    points `position` (N, 3)."""
    to_light = torch.nn.functional.normalize(light_position - position, dim=-1, eps=1e-12)
    return shade(albedo, normal, to_light, ambient, visibility)


def environment_basis_values(normal):
    """(..., 8) the environment light's harmonics Y_k at unit normals (..., 3) (camera frame;
    formats/environment_light.py)."""
    return torch.stack(environment_basis(normal[..., 0], normal[..., 1], normal[..., 2]), dim=-1)


@functools.lru_cache(maxsize=8)
def sphere_radiance_basis(dtype, device) -> torch.Tensor:
    """(D, 8) the environment's radiance functions R_k (formats/environment_light.radiance_basis)
    at the directions spread over the sphere where the fit holds its room's radiance
    a + R . c at or above 0 (sphere_directions); made once per dtype and device, never modified."""
    directions = torch.as_tensor(sphere_directions(), dtype=dtype, device=device)
    return torch.stack(radiance_basis(directions[:, 0], directions[:, 1], directions[:, 2]), dim=1)


def environment_shading(normal, coefficients):
    """(N, 3) the environment light's share of the shading factor, sum_k c_k Y_k(n), of unit
    normals (N, 3) (camera frame) under its spherical-harmonic coefficients (8, 3)."""
    return environment_basis_values(normal) @ coefficients.to(normal.dtype)


def specular_shading(normal, to_light, to_camera, roughness, level):
    """(N, 1) the specular lobe's share of the colour for a light of irradiance pi, before the
    (1 - a) V that the diffuse share also carries: pi f_s(n, l, v) max(0, n . l), f_s Principled's
    GGX lobe of `roughness` and Specular IOR Level `level` (formats/specular_lobe.py). All
    directions unit (N, 3), camera frame; roughness and level scalars (tensors)."""
    half = torch.nn.functional.normalize(to_light + to_camera, dim=-1, eps=1e-12)
    n_l = (normal * to_light).sum(-1, keepdim=True).clamp(min=0)
    n_v = (normal * to_camera).sum(-1, keepdim=True).clamp(min=1e-4)
    n_h = (normal * half).sum(-1, keepdim=True).clamp(min=0)
    v_h = (to_camera * half).sum(-1, keepdim=True).clamp(min=0, max=1)
    alpha2 = roughness.to(normal.dtype) ** 4                                   # alpha = roughness^2
    distribution_times_pi = alpha2 / (n_h * n_h * (alpha2 - 1) + 1) ** 2       # pi * GGX D
    visibility = 0.5 / (n_l * torch.sqrt(n_v * n_v * (1 - alpha2) + alpha2)
                        + n_v * torch.sqrt(n_l * n_l * (1 - alpha2) + alpha2)).clamp(min=1e-8)
    fresnel = 2 * level.to(normal.dtype) * (BASE_REFLECTANCE + (1 - BASE_REFLECTANCE) * (1 - v_h) ** 5)
    return distribution_times_pi * visibility * fresnel * n_l
