"""Procedural skin albedo (and roughness) in the model's UV layout (numpy).

Every feature is a function of the rest-pose surface point behind a texel (model at beta = 0),
so patterns run seamlessly across UV chart borders: skin tone (very light to very dark, palms
lighter), low-frequency colour variation and blotches, redness of knuckles, palm and
fingertips, darker flexion creases and palm lines, knuckle wrinkles, nails (natural or
polished), and optionally freckles, a tattoo and scars. Colours are mixed in linear RGB; the
albedo is returned 8-bit sRGB-encoded (as saved in gt_albedo.png).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.handmodel.uv_raster import dilate, interpolate, rasterize_uv

from .identity import DIGIT_PART, digit_coordinates, nail_weight, smooth_field, vertex_normals

# Skin tones from very light to very dark (sRGB 8-bit), interpolated in linear RGB.
SKIN_TONES = np.array([(247, 224, 210), (232, 190, 172), (210, 158, 126), (172, 117, 84),
                       (122, 80, 56), (72, 46, 34)], dtype=np.float64)
NAIL_COLOUR = (238, 208, 203)
INK_COLOUR = (32, 40, 62)
SCAR_COLOUR = (236, 196, 190)
FRECKLE_TINT = np.array([0.78, 0.62, 0.52])  # multiplies linear RGB at the freckle centre
PALM = 0  # PART_NAMES index


@dataclasses.dataclass
class Appearance:
    albedo: np.ndarray      # (H, W, 3) uint8 sRGB, v = 1 on the top row
    roughness: np.ndarray   # (H, W) float32 in [0, 1]
    uv_mask: np.ndarray     # (H, W) bool, texels covered by the UV layout


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.clip(c, 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def skin_colour(tone):
    """Linear RGB (3,) of a skin tone in [0, 1] (0 very light, 1 very dark)."""
    position = np.clip(tone, 0, 1) * (len(SKIN_TONES) - 1)
    i = min(int(position), len(SKIN_TONES) - 2)
    linear = srgb_to_linear(SKIN_TONES / 255)
    return linear[i] + (position - i) * (linear[i + 1] - linear[i])


def make_appearance(data, identity, size=512):
    """Albedo and roughness textures of `identity` on `data`'s UV layout (size x size texels)."""
    face, bary = rasterize_uv(data.uvs, data.faces_uv, size)
    covered = face >= 0
    normals = vertex_normals(data.vertices, data.faces)
    dominant = data.skin_indices[np.arange(data.num_vertices), data.skin_weights.argmax(1)]
    palmar = np.einsum("vi,vi->v", normals, data.joint_frames[dominant][:, :, 2])  # +1 palm side
    per_vertex = np.concatenate([data.vertices, palmar[:, None]], axis=1)
    texel = interpolate(face, bary, data.faces, per_vertex)[covered]
    points, palmar = texel[:, :3], texel[:, 3]
    nearest = data.faces[face[covered], bary[covered].argmax(1)]
    parts = data.vertex_parts[nearest]
    rng = np.random.default_rng([identity.seed, 3])
    seed = identity.seed

    base = skin_colour(identity.skin_tone)
    palm_colour = skin_colour(identity.skin_tone * 0.45)  # palms carry less melanin
    colour = base + (palm_colour - base) * _ramp(palmar, 0.0, 0.6)[:, None]
    colour = colour * (1 + 0.07 * smooth_field(points, seed + 10, (0.03, 0.09)))[:, None]
    colour = colour * (1 + 0.035 * smooth_field(points, seed + 11, (0.004, 0.012)))[:, None]
    redness = identity.redness * _redness_map(data, points, palmar, parts)
    redness = np.clip(redness * (1 + 0.5 * smooth_field(points, seed + 12, (0.01, 0.03))), 0, 1)
    colour = colour * (1 + redness[:, None] * np.array([0.10, -0.22, -0.18]))
    roughness = 0.5 + 0.05 * smooth_field(points, seed + 13, (0.003, 0.01))

    creases = _creases(data, points, palmar, parts)
    colour = colour * (1 - 0.45 * creases[:, None] * np.array([0.9, 1.0, 1.0]))
    roughness = roughness + 0.15 * creases

    if "freckles" in identity.features:
        colour = colour * (1 - _freckles(data, points, palmar, rng)[:, None] * (1 - FRECKLE_TINT))
    if "scars" in identity.features:
        scar = _scars(points, palmar, parts, rng)
        colour = colour + (srgb_to_linear(np.array(SCAR_COLOUR) / 255) * (0.6 + 0.4 * base) - colour) * 0.5 * scar[:, None]
    if "tattoo" in identity.features:
        ink = 0.85 * _tattoo(points, palmar, parts, identity.betas[0], rng)
        colour = colour + (srgb_to_linear(np.array(INK_COLOUR) / 255) - colour) * ink[:, None]

    nail = nail_weight(data, points, parts)
    nail_colour = _nail_colour(data, points, parts, base, identity)
    colour = colour + (nail_colour - colour) * nail[:, None]
    roughness = roughness + ((0.12 if "polish" in identity.features else 0.3) - roughness) * nail

    image = np.zeros((size, size, 4))
    image[covered, :3] = colour
    image[covered, 3] = roughness
    image, grown = dilate(image, covered, iterations=4)
    image[~grown, :3] = base
    image[~grown, 3] = 0.5
    albedo = np.round(linear_to_srgb(image[..., :3]) * 255).astype(np.uint8)
    return Appearance(albedo=albedo, roughness=np.clip(image[..., 3], 0, 1).astype(np.float32), uv_mask=covered)


def _ramp(x, lo, hi):
    t = np.clip((x - lo) / (hi - lo), 0, 1)
    return t * t * (3 - 2 * t)


def _redness_map(data, points, palmar, parts):
    """Where skin reddens: dorsal knuckles, fingertips, the palm's mounds."""
    red = 0.5 * _ramp(palmar, 0.2, 0.8) * (parts == PALM)
    for j in range(1, 16):  # knuckles on the back (MCP, PIP, DIP)
        distance = np.linalg.norm(points - data.joints[j], axis=1)
        red = np.maximum(red, _ramp(-palmar, 0.0, 0.5) * np.exp(-(distance / 0.009) ** 2))
    for tip in (4, 8, 12, 16, 20):
        distance = np.linalg.norm(points - data.keypoints[tip], axis=1)
        red = np.maximum(red, np.exp(-(distance / 0.009) ** 2))
    return red


def _line(distance, width):
    return np.exp(-(distance / width) ** 2)


def _creases(data, points, palmar, parts):
    """Darkening in [0, 1]: finger flexion creases, palm lines, dorsal knuckle wrinkles."""
    crease = np.zeros(len(points))
    palm_side = _ramp(palmar, 0.1, 0.5)
    back_side = _ramp(-palmar, 0.1, 0.5)
    for digit, part in DIGIT_PART.items():
        on = parts == part
        first = {"thumb": 13, "index": 1, "middle": 4, "ring": 10, "pinky": 7}[digit]
        for j, offsets in ((first, (0.017,) if digit != "thumb" else (0.0,)),
                           (first + 1, (-0.001, 0.0015)), (first + 2, (0.0,))):
            local = (points[on] - data.joints[j]) @ data.joint_frames[j]
            for offset in offsets:
                wobble = 0.0008 * np.sin(local[:, 0] * 400 + j)
                crease[on] = np.maximum(crease[on], palm_side[on] * _line(local[:, 1] - offset - wobble, 0.0005))
            if j != first:  # wrinkles over the PIP and DIP joints on the back
                wrinkles = 0.5 + 0.5 * np.cos(local[:, 1] * 2 * np.pi / 0.0016 + 2 * np.sin(local[:, 0] * 300))
                patch = np.exp(-(local[:, 1] / 0.0035) ** 2 - (local[:, 0] / 0.006) ** 2)
                crease[on] = np.maximum(crease[on], 0.45 * back_side[on] * patch * wrinkles ** 4)
    palm = (parts == PALM) & (palmar > 0)
    for start, control, end in (((-0.043, 0.068), (-0.01, 0.06), (0.016, 0.078)),     # distal transverse
                                ((0.034, 0.062), (0.0, 0.058), (-0.036, 0.044)),      # proximal transverse
                                ((0.032, 0.06), (0.006, 0.04), (0.012, 0.002))):      # thenar
        t = np.linspace(0, 1, 60)[:, None]
        curve = (1 - t) ** 2 * np.array(start) + 2 * t * (1 - t) * np.array(control) + t ** 2 * np.array(end)
        distance = np.min(np.linalg.norm(points[palm, None, :2] - curve[None], axis=2), axis=1)
        crease[palm] = np.maximum(crease[palm], palm_side[palm] * _line(distance, 0.0006))
    return crease


def _freckles(data, points, palmar, rng):
    """Freckle strength in [0, 1]: small soft spots on the back of the hand and fingers."""
    spots = np.zeros(len(points))
    faces = data.faces
    corners = data.vertices[faces]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    chosen = rng.choice(len(faces), size=500, p=areas / areas.sum())
    weights = rng.dirichlet(np.ones(3), size=500)
    centres = np.einsum("nk,nkc->nc", weights, corners[chosen])
    radii = rng.uniform(0.0004, 0.0011, size=500)
    strength = rng.uniform(0.4, 1.0, size=500)
    back = _ramp(-palmar, -0.1, 0.4)
    for centre, radius, s in zip(centres, radii, strength):
        distance = np.linalg.norm(points - centre, axis=1)
        near = distance < 3 * radius
        spots[near] = np.maximum(spots[near], s * back[near] * np.exp(-(distance[near] / radius) ** 2))
    return spots


def _scars(points, palmar, parts, rng):
    """One or two thin healed cuts on the back of the hand."""
    scar = np.zeros(len(points))
    back = (parts == PALM) & (palmar < -0.3)
    for _ in range(int(rng.integers(1, 3))):
        start = np.array([rng.uniform(-0.03, 0.03), rng.uniform(0.005, 0.065)])
        angle = rng.uniform(0, np.pi)
        length = rng.uniform(0.01, 0.025)
        bend = rng.uniform(-0.003, 0.003)
        t = np.linspace(0, 1, 40)[:, None]
        direction = np.array([np.cos(angle), np.sin(angle)])
        normal = np.array([-direction[1], direction[0]])
        curve = start + t * length * direction + 4 * t * (1 - t) * bend * normal
        distance = np.min(np.linalg.norm(points[back, None, :2] - curve[None], axis=2), axis=1)
        width = 0.0007 * (1 - 0.5 * np.abs(2 * t[np.argmin(np.linalg.norm(points[back, None, :2] - curve[None], axis=2), axis=1), 0] - 1))
        scar[back] = np.maximum(scar[back], _line(distance, width))
    return scar


def _tattoo(points, palmar, parts, size_beta, rng):
    """Ink opacity in [0, 1]: a ring with a star, or a sun with rays, on the back of the hand."""
    back = (parts == PALM) & (palmar < -0.4)
    scale = 1 + 0.05 * size_beta
    centre = np.array([rng.uniform(-0.012, 0.012), rng.uniform(0.035, 0.05)]) * scale
    xy = (points[back, :2] - centre) / scale
    radius = np.linalg.norm(xy, axis=1)
    angle = np.arctan2(xy[:, 1], xy[:, 0]) + rng.uniform(0, 2 * np.pi)
    ink = _line(radius - 0.013, 0.0009)
    if rng.uniform() < 0.5:  # star: distance to the outline r(angle) of a five-pointed star
        star_radius = 0.0105 * (0.62 + 0.38 * np.abs(np.cos(2.5 * angle)) ** 3)
        ink = np.maximum(ink, _line(radius - star_radius, 0.0007))
    else:  # sun: filled disc and twelve rays
        ink = np.maximum(ink, _ramp(0.0055 - radius, -0.0004, 0.0004))
        rays = _ramp(np.cos(12 * angle), 0.85, 0.97) * _ramp(radius, 0.0065, 0.0075) * _ramp(0.0105 - radius, 0, 0.001)
        ink = np.maximum(ink, rays)
    out = np.zeros(len(points))
    out[back] = ink
    return out


def _nail_colour(data, points, parts, base, identity):
    """Linear RGB of the nail plate at each point (natural with lunula and free edge, or polish)."""
    if "polish" in identity.features:
        return np.broadcast_to(srgb_to_linear(np.array(identity.polish_colour) / 255), points.shape).copy()
    natural = srgb_to_linear(np.array(NAIL_COLOUR) / 255) * 0.7 + 0.3 * base
    colour = np.broadcast_to(natural, points.shape).copy()
    for digit, part in DIGIT_PART.items():
        on = parts == part
        local, length = digit_coordinates(data, points[on], digit)
        s = local[:, 1] / length
        whiter = np.maximum(_ramp(0.52 - s, -0.04, 0.04), _ramp(s, 0.95, 0.99))  # lunula, free edge
        colour[on] = colour[on] + (srgb_to_linear(np.array([0.96, 0.93, 0.92])) - colour[on]) * 0.6 * whiter[:, None]
    return colour
