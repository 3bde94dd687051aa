"""A synthetic person: shape vector, personal geometry outside the shape space, appearance
parameters (numpy). Everything follows from an integer seed unless set explicitly.

Personal geometry (rest model space, metres): a smooth random displacement field along the
vertex normals (a few millimetres, fading to zero at the fingertip keypoints so they stay on the
skin) plus fingernails as plates raised by a fraction of a millimetre.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.handmodel.digit_coordinates import smoothstep

NUM_BETAS = 12
FINGERTIPS = {"thumb": (15, 4), "index": (3, 8), "middle": (6, 12), "ring": (12, 16), "pinky": (9, 20)}
"""Per digit: (distal joint index, fingertip keypoint index)."""
DIGIT_PART = {"thumb": 1, "index": 2, "middle": 3, "ring": 4, "pinky": 5}  # PART_NAMES indices
TIP_FADE_RADIUS = 0.012  # metres: the personal field fades to zero at the fingertip keypoints
FEATURES = ("freckles", "tattoo", "scars", "polish")
POLISH_COLOURS = ((150, 10, 25), (200, 40, 90), (40, 30, 45), (230, 150, 160), (30, 60, 140))  # sRGB


@dataclasses.dataclass
class Identity:
    """One synthetic person. betas (12,), skin_tone 0 (very light) .. 1 (very dark)."""

    seed: int
    betas: np.ndarray
    skin_tone: float
    redness: float                  # 0 .. 1, redness of knuckles, palm and fingertips
    features: tuple                 # subset of FEATURES
    polish_colour: tuple            # sRGB 0..255 (used when "polish" in features)
    displacement_mm: float = 1.0    # std of the smooth personal displacement field
    nail_height_mm: float = 0.4

    def to_json(self) -> dict:
        return {"seed": self.seed, "betas": [float(b) for b in self.betas], "skin_tone": self.skin_tone,
                "redness": self.redness, "features": list(self.features),
                "polish_colour": list(self.polish_colour), "displacement_mm": self.displacement_mm,
                "nail_height_mm": self.nail_height_mm}


def make_identity(seed, skin_tone=None, size=None, betas=None, features=None):
    """Draw an identity from `seed`; skin_tone, size (the scale shape parameter), the full
    betas (12,) and the features override the drawn values."""
    rng = np.random.default_rng([seed, 1])
    drawn_betas = np.clip(rng.normal(scale=0.8, size=NUM_BETAS), -2.0, 2.0)
    drawn_tone = float(rng.uniform())
    redness = float(rng.uniform(0.2, 0.8))
    drawn_features = tuple(name for name, chance in zip(FEATURES, (0.35, 0.3, 0.3, 0.3)) if rng.uniform() < chance)
    polish = POLISH_COLOURS[int(rng.integers(len(POLISH_COLOURS)))]
    if betas is not None:
        drawn_betas = np.asarray(betas, dtype=np.float64)
    if size is not None:
        drawn_betas[0] = size
    return Identity(seed=int(seed), betas=drawn_betas, skin_tone=drawn_tone if skin_tone is None else float(skin_tone),
                    redness=redness, features=drawn_features if features is None else tuple(features),
                    polish_colour=polish)


def vertex_normals(vertices, faces):
    """(V, 3) area-weighted unit vertex normals."""
    face_normals = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def smooth_field(points, seed, wavelengths=(0.025, 0.07), waves=32):
    """A smooth random scalar field of unit standard deviation at (N, 3) points (metres):
    a sum of plane waves with random directions, wavelengths and phases."""
    rng = np.random.default_rng([seed, 2])
    directions = rng.normal(size=(waves, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    k = directions * (2 * np.pi / rng.uniform(*wavelengths, size=(waves, 1)))
    phases = rng.uniform(0, 2 * np.pi, size=waves)
    return np.cos(points @ k.T + phases).sum(1) / np.sqrt(waves / 2)


def digit_coordinates(data, points, digit):
    """Coordinates (N, 3) of points in the rest frame of a digit's distal joint, and the
    length of the distal segment (joint to fingertip keypoint). Model at beta = 0."""
    joint, tip = FINGERTIPS[digit]
    local = (points - data.joints[joint]) @ data.joint_frames[joint]
    return local, float(np.linalg.norm(data.keypoints[tip] - data.joints[joint]))


def nail_weight(data, points, parts):
    """(N,) nail-plate membership in [0, 1] of rest points (beta = 0) with part ids (N,):
    a rounded plate on the dorsal side (local -z) of each distal phalanx, near its tip."""
    weight = np.zeros(len(points))
    for digit, part in DIGIT_PART.items():
        on_digit = parts == part
        if not on_digit.any():
            continue
        local, length = digit_coordinates(data, points[on_digit], digit)
        radius = np.median(np.hypot(local[:, 0], local[:, 2])[(local[:, 1] > 0.2 * length) & (local[:, 1] < 0.6 * length)])
        s = local[:, 1] / length                        # 0 at the joint, 1 at the tip keypoint
        across = np.abs(local[:, 0]) / (0.62 * radius)  # 1 at the nail's side edge
        along = np.clip((s - 0.42) / 0.2, 0, 1) * np.clip((1.02 - s) / 0.06, 0, 1)
        dorsal = np.clip((-local[:, 2] / radius - 0.25) / 0.25, 0, 1)
        weight[on_digit] = smoothstep(along) * smoothstep(np.clip((1 - across) / 0.25, 0, 1)) * dorsal
    return weight


def personal_offsets(data, identity, betas=None):
    """(V, 3) rest-space personal displacements of `data`'s vertices (metres)."""
    betas = identity.betas if betas is None else betas
    shaped = data.vertices + data.shapedirs @ betas
    normals = vertex_normals(shaped, data.faces)
    field = np.clip(smooth_field(data.vertices, identity.seed), -2.5, 2.5) * identity.displacement_mm * 1e-3
    for digit, (_, tip) in FINGERTIPS.items():  # keep the fingertip keypoints on the skin
        distance = np.linalg.norm(data.vertices - data.keypoints[tip], axis=1)
        field *= smoothstep(np.clip(distance / TIP_FADE_RADIUS, 0, 1))
    nails = nail_weight(data, data.vertices, data.vertex_parts) * identity.nail_height_mm * 1e-3
    return (field + nails)[:, None] * normals
