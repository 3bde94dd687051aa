"""Shading formulas: vertex normals, UV tangent frames, tangent-space normal maps and the
HARP light model  colour = albedo * (a + (1 - a) * max(0, n' . l) * V), and the environment
light's and the specular lobe's shares of it (formats/environment_light.py, formats/specular_lobe.py):
the lobe's highlight of the point light, and its sheen of the room (room_specular)."""
from __future__ import annotations

import functools

import torch

from ..formats.environment_light import basis as environment_basis
from ..formats.environment_light import radiance_basis, sphere_directions
from ..formats.specular_lobe import BASE_REFLECTANCE, ROUGHNESS_RANGE
from .vector_ops import normalized


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
    w1, w2, handedness = tangent_weights(t0, t1, t2)
    return (p1 - p0) * w1[:, None] + (p2 - p0) * w2[:, None], handedness.to(p0.dtype)


def tangent_weights(t0, t1, t2):
    """(w1 (F,), w2 (F,), handedness (F,)) of faces whose corners have UVs t0, t1, t2 (F, 2): a
    face's tangent (the direction of increasing u) is w1 e1 + w2 e2 for its edges e1 = p1 - p0 and
    e2 = p2 - p0; the handedness is -1 where the face is mirrored in UV space, else +1."""
    d1, d2 = t1 - t0, t2 - t0
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    handedness = torch.where(det < 0, -1.0, 1.0).to(t0.dtype)
    safe = torch.where(det.abs() > 1e-20, det, torch.full_like(det, 1e-20))
    return d2[:, 1] / safe, -d1[:, 1] / safe, handedness


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


def distance_falloff(light_position, position, reach):
    """(N, 1) the inverse-square falloff of a light at `light_position` ((3,) or (N, 3)) at the
    surface points `position` (N, 3), 1 at the distance `reach` ((N, 1) or scalar, metres):
    (reach / |light - position|)^2."""
    distance = (light_position - position).norm(dim=-1, keepdim=True).clamp(min=1e-6)
    return (reach / distance).square()


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
    lobe, v_h = _lobe_without_fresnel(normal, to_light, to_camera, roughness)
    return lobe * principled_fresnel(v_h, level.to(normal.dtype))


def _lobe_without_fresnel(normal, to_light, to_camera, roughness):
    """((N, 1) specular_shading with a reflectance of 1, (N, 1) the cosine its Fresnel term takes:
    between the direction to the camera and the half-vector)."""
    half = normalized(to_light + to_camera)
    n_l = (normal * to_light).sum(-1, keepdim=True).clamp(min=0)
    n_v = (normal * to_camera).sum(-1, keepdim=True).clamp(min=1e-4)
    n_h = (normal * half).sum(-1, keepdim=True).clamp(min=0)
    v_h = (to_camera * half).sum(-1, keepdim=True).clamp(min=0, max=1)
    alpha2 = roughness.to(normal.dtype) ** 4                                   # alpha = roughness^2
    distribution_times_pi = alpha2 / (n_h * n_h * (alpha2 - 1) + 1) ** 2       # pi * GGX D
    visibility = 0.5 / (n_l * torch.sqrt(n_v * n_v * (1 - alpha2) + alpha2)
                        + n_v * torch.sqrt(n_l * n_l * (1 - alpha2) + alpha2)).clamp(min=1e-8)
    return distribution_times_pi * visibility * n_l, v_h


def principled_fresnel(cosine, level):
    """The reflectance of the skin's dielectric surface at the cosine between the direction to
    the camera and the microfacet's normal, as Principled BSDF's "Specular IOR Level" makes it:
    the IOR-1.5 reflectance at normal incidence, BASE_REFLECTANCE, times 2 * level, and the
    exact (unpolarised) Fresnel reflectance of the index of refraction that has it, rising to 1 at
    grazing angles for any level above 0, and none at level 0 (short of grazing itself). Schlick's approximation,
    which this replaced, is 20-30% low at 50-65 degrees."""
    root = torch.sqrt((2 * BASE_REFLECTANCE * level).clamp(min=1e-12, max=0.99))
    eta = (1 + root) / (1 - root)
    g = torch.sqrt(eta * eta - 1 + cosine * cosine)
    c = cosine.clamp(min=1e-6)
    return 0.5 * ((g - c) / (g + c)) ** 2 * (1 + ((c * (g + c) - 1) / (c * (g - c) + 1)) ** 2)


# The room's sheen: the lobe reflects the room's light too (a Principled BSDF in Cycles or EEVEE reflects its
# world), strongest on dark skin, where it is a large share of the colour, and towards the outline, where
# Fresnel's term grows. Its reflectance of uniform light, tabulated over n . v and the roughness, with the
# Fresnel term left out and the integral split by the cosine that term takes (it depends on the level):
ROOM_SHEEN_COSINES = 33        # n . v from 0 to 1
ROOM_SHEEN_ROUGHNESSES = 17    # roughness over the lobe's range (formats/specular_lobe.ROUGHNESS_RANGE)
ROOM_SHEEN_FRESNEL_BINS = 64   # of v . h, over [0, 1]
ROOM_SHEEN_SAMPLES = 64        # half-vectors per side of the stratified grid each entry is integrated over


@functools.lru_cache(maxsize=1)
def room_sheen_table() -> torch.Tensor:
    """(ROOM_SHEEN_COSINES, ROOM_SHEEN_ROUGHNESSES, ROOM_SHEEN_FRESNEL_BINS) float64: for a
    viewer at n . v = cosine and each roughness, the share of uniform light of radiance 1 that the
    lobe would send towards it with a reflectance of 1, (1 / pi) * the integral of specular_shading
    over the hemisphere of light directions, split by the bin of v . h (half-vectors distributed
    as GGX's, importance sampling on a fixed stratified grid). The reflectance of a level is then
    the sum over the bins of this times principled_fresnel at the bins' centres."""
    cosines = torch.linspace(0.0, 1.0, ROOM_SHEEN_COSINES, dtype=torch.float64)
    roughnesses = torch.linspace(*ROUGHNESS_RANGE, ROOM_SHEEN_ROUGHNESSES, dtype=torch.float64)
    strata = (torch.arange(ROOM_SHEEN_SAMPLES, dtype=torch.float64) + 0.5) / ROOM_SHEEN_SAMPLES
    u, w = (grid.reshape(-1) for grid in torch.meshgrid(strata, strata, indexing="ij"))
    n_v = cosines.clamp(min=1e-3)[:, None, None]
    alpha2 = (roughnesses ** 4)[None, :, None]
    # half-vectors with density D(h) (n . h) (GGX, alpha = roughness^2)
    cos_h = torch.sqrt((1 - u) / (1 + (alpha2 - 1) * u))
    sin_h = torch.sqrt((1 - cos_h * cos_h).clamp(min=0))
    half = torch.stack(torch.broadcast_tensors(sin_h * torch.cos(2 * torch.pi * w), sin_h * torch.sin(2 * torch.pi * w),
                                               cos_h), dim=-1)
    to_camera = torch.stack(torch.broadcast_tensors(torch.sqrt(1 - n_v * n_v), torch.zeros_like(n_v), n_v), dim=-1)
    v_h = (to_camera * half).sum(-1, keepdim=True)
    to_light = 2 * v_h * half - to_camera
    shape = to_light.shape[:-1]
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(to_light)
    roughness = roughnesses[None, :, None].expand(shape).reshape(-1, 1)
    lobe, _ = _lobe_without_fresnel(normal.reshape(-1, 3), to_light.reshape(-1, 3),
                                    to_camera.expand_as(to_light).reshape(-1, 3), roughness)
    distribution = alpha2 / (torch.pi * (cos_h * cos_h * (alpha2 - 1) + 1) ** 2)
    density = distribution * cos_h / (4 * v_h[..., 0].clamp(min=1e-12))          # of the light direction
    valid = (to_light[..., 2] > 0) & (v_h[..., 0] > 0)
    share = torch.where(valid, lobe.reshape(shape) / torch.pi / density.clamp(min=1e-30), torch.zeros(shape,
                                                                                                    dtype=torch.float64))
    bins = (v_h[..., 0].clamp(0, 1) * ROOM_SHEEN_FRESNEL_BINS).long().clamp(max=ROOM_SHEEN_FRESNEL_BINS - 1)
    table = torch.zeros(*shape[:2], ROOM_SHEEN_FRESNEL_BINS, dtype=torch.float64)
    return table.scatter_add_(2, bins, share) / shape[-1]


def room_sheen_reflectance(n_v, roughness, level):
    """(N, 1) the lobe's reflectance of uniform light towards viewers at n . v = `n_v` (N, 1), for
    a scalar roughness and level (tensors): room_sheen_table weighted by principled_fresnel,
    bilinear in n . v and the roughness (differentiable in both and in the level)."""
    table = room_sheen_table().to(device=n_v.device, dtype=n_v.dtype)
    centres = (torch.arange(ROOM_SHEEN_FRESNEL_BINS, device=n_v.device, dtype=n_v.dtype) + 0.5) / ROOM_SHEEN_FRESNEL_BINS
    table = table @ principled_fresnel(centres, level.to(n_v.dtype))                   # (COSINES, ROUGHNESSES)
    low, high = ROUGHNESS_RANGE
    column = ((roughness.to(n_v.dtype) - low) / (high - low)).clamp(0, 1) * (ROOM_SHEEN_ROUGHNESSES - 1)
    left = column.detach().floor().clamp(max=ROOM_SHEEN_ROUGHNESSES - 2).long()
    along = column - left
    by_cosine = table[:, left] * (1 - along) + table[:, left + 1] * along            # (COSINES,)
    row = n_v.clamp(0, 1) * (ROOM_SHEEN_COSINES - 1)
    below = row.detach().floor().clamp(max=ROOM_SHEEN_COSINES - 2).long()
    return by_cosine[below] * (1 - (row - below)) + by_cosine[below + 1] * (row - below)


def room_specular(normal, to_camera, roughness, level, ambient, environment=None):
    """(N, C) the lobe's sheen of the room's light (C = 1 with no environment light, else 3): the
    room's radiance seen along the mirror direction, blurred as the environment's harmonics blur it
    (a + sum_k c_k Y_k(r), r = 2 (n . v) n - v, at least 0), times the lobe's reflectance of
    uniform light at this n . v (room_sheen_reflectance). Unit normals and
    directions to the camera (N, 3), camera frame; roughness and level scalars (tensors)."""
    n_v = (normal * to_camera).sum(-1, keepdim=True)
    radiance = torch.as_tensor(ambient, dtype=normal.dtype, device=normal.device).reshape(1, 1).expand(len(normal), 1)
    if environment is not None:
        mirror = 2 * n_v * normal - to_camera
        radiance = (radiance + environment_shading(mirror, environment)).clamp(min=0)
    return room_sheen_reflectance(n_v.clamp(min=0), roughness, level) * radiance
