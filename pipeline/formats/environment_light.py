"""The environment light: a room's light from every side, as low-order spherical harmonics.

The fit's light is a point light (which casts the shadows) plus an ambient ratio a; the
environment adds what a uniform ambient cannot: light that depends on the direction the skin
faces (a bright window on one side, a dark floor below). It is stored as the coefficients c of
the real spherical harmonics of bands 1 and 2 (8 of them, per colour channel) of the extra
shading factor

    colour = albedo * (a + (1 - a) * max(0, n . l) * V + sum_k c_k Y_k(n))

where n is the unit shading normal in the camera frame (OpenCV axes) and Y_k the orthonormal
real harmonics (band 0, a constant, is the ambient ratio a). For a Lambertian surface this
factor is the irradiance over pi, so the radiance of the world that produces it is
a + sum_k c_k pi / A_l Y_k, with A_1 = 2 pi / 3 and A_2 = pi / 4 the clamped-cosine's band
weights (Ramamoorthi and Hanrahan 2001): the Blender bind bakes that radiance into its world.

numpy and the standard library only: the add-on reads it too. The functions take any array
type with element-wise arithmetic (numpy arrays or torch tensors) for the basis.
"""
from __future__ import annotations

import math

import numpy as np

COEFFICIENTS = 8       # bands 1 and 2 of the real spherical harmonics
BANDS = (1, 1, 1, 2, 2, 2, 2, 2)        # the band of each coefficient
# the clamped cosine's band weights A_l / pi: irradiance / pi = sum_l (A_l / pi) L_lm Y_lm
COSINE_LOBE = {0: 1.0, 1: 2.0 / 3.0, 2: 1.0 / 4.0}


def basis(x, y, z):
    """The 8 orthonormal real harmonics of bands 1 and 2 at unit directions (x, y, z) (arrays
    of one shape): a list of 8 arrays, in the order y, z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2."""
    b1 = math.sqrt(3.0 / (4.0 * math.pi))
    b2 = math.sqrt(15.0 / (4.0 * math.pi))
    b20 = math.sqrt(5.0 / (16.0 * math.pi))
    return [b1 * y, b1 * z, b1 * x, b2 * x * y, b2 * y * z, b20 * (3.0 * z * z - 1.0), b2 * x * z,
            0.5 * b2 * (x * x - y * y)]


def shading_factor(directions, coefficients):
    """(N, 3) the environment's share of the shading factor (sum_k c_k Y_k(n)) of unit normals
    `directions` (N, 3) under `coefficients` (8, 3); numpy."""
    directions = np.asarray(directions, dtype=np.float64)
    values = np.stack(basis(directions[:, 0], directions[:, 1], directions[:, 2]), axis=1)
    return values @ np.asarray(coefficients, dtype=np.float64)


def relative_strength(coefficients, ambient) -> float:
    """How much the environment varies with direction against the ambient ratio: the root mean
    square over the sphere of its factor (mean over colours) over `ambient`. 0: a uniform room."""
    coefficients = np.asarray(coefficients, dtype=np.float64)
    mean_square = float((coefficients ** 2).sum(0).mean()) / (4.0 * math.pi)
    return math.sqrt(mean_square) / max(float(ambient), 1e-6)


def colour_strength(coefficients, ambient) -> float:
    """relative_strength of the environment's colour alone (each coefficient less its mean over
    the colours): what a white point light and an ambient ratio cannot explain, as a room whose
    light has different colours from different sides does."""
    coefficients = np.asarray(coefficients, dtype=np.float64)
    return relative_strength(coefficients - coefficients.mean(1, keepdims=True), ambient)


def radiance_basis(x, y, z):
    """The 8 functions R_k(d) = Y_k(d) / (A_l / pi) at unit directions d = (x, y, z) (arrays of
    one shape, numpy or torch), whose combination a + sum_k c_k R_k(d) is the radiance of the
    world that the coefficients c and the ambient ratio a stand for (radiance())."""
    return [value / COSINE_LOBE[band] for value, band in zip(basis(x, y, z), BANDS)]


def sphere_directions(count=256):
    """(count, 3) float64 unit directions spread evenly over the sphere (a Fibonacci lattice):
    where the fit checks that its world's radiance is realisable (nowhere negative)."""
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    azimuth = math.pi * (1.0 + math.sqrt(5.0)) * index
    ring = np.sqrt(1.0 - z * z)
    return np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)


def unclipped_radiance(directions, coefficients, ambient):
    """(N, 3) a + sum_k c_k R_k(d) at unit directions (N, 3), negative where the coefficients
    ask a world for less than no light (radiance() clips it)."""
    directions = np.asarray(directions, dtype=np.float64)
    values = np.stack(radiance_basis(directions[:, 0], directions[:, 1], directions[:, 2]), axis=1)
    return float(ambient) + values @ np.asarray(coefficients, dtype=np.float64)


def radiance(directions, coefficients, ambient):
    """(N, 3) the radiance of a world that lights a Lambertian surface as the fit's ambient and
    environment do: a + sum_k c_k / (A_l / pi) Y_k(d) at unit directions `directions` (N, 3)
    (the direction the light comes from, camera frame); negative values clipped to 0 (the fit
    keeps them at or above 0: fit/albedo_solve.py, the `environment_realisable` energy term)."""
    return np.clip(unclipped_radiance(directions, coefficients, ambient), 0.0, None)


def equirectangular_directions(width, height, to_camera=None):
    """(height, width, 3) unit directions, in the camera frame, of an equirectangular image's
    pixel centres as Blender's Environment Texture maps them onto its world (x towards u = 0.5,
    z up, u increasing clockwise seen from above, as Cycles' u = 0.5 - atan2(y, x) / 2 pi):
    longitude 2 pi (0.5 - u), latitude pi (v - 0.5), v upwards (row 0 is the bottom in
    Blender's image space). `to_camera` (3, 3) turns Blender world directions into the camera
    frame (default: identity)."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    longitude = 2.0 * math.pi * (0.5 - u)
    latitude = math.pi * (v - 0.5)
    lat, lon = np.meshgrid(latitude, longitude, indexing="ij")
    world = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    if to_camera is not None:
        world = world @ np.asarray(to_camera, dtype=np.float64).T
    return world


def equirectangular_radiance(coefficients, ambient, width=64, height=32, to_camera=None):
    """(height, width, 3) float32 radiance image (row 0 the bottom, as Blender stores pixels) of
    the world that reproduces the ambient and environment light (radiance())."""
    directions = equirectangular_directions(width, height, to_camera)
    return radiance(directions.reshape(-1, 3), coefficients, ambient).reshape(height, width, 3).astype(np.float32)


def to_description(coefficients):
    """The coefficients (8, 3) (array or tensor) as avatar.json's light stores them: a list of
    8 [r, g, b] lists, or None for no environment light."""
    if coefficients is None:
        return None
    if hasattr(coefficients, "detach"):
        coefficients = coefficients.detach().cpu().numpy()
    return np.asarray(coefficients, dtype=np.float64).reshape(COEFFICIENTS, 3).tolist()


def from_description(light: dict):
    """(8, 3) float64 coefficients of avatar.json's `light` (a dict), or None where it has no
    environment light (also folders written before it); a malformed entry is a ValueError."""
    values = light.get("environment")
    if values is None:
        return None
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (COEFFICIENTS, 3) or not np.isfinite(array).all():
        raise ValueError(f"the light's environment must be {COEFFICIENTS} x 3 finite numbers, got shape {array.shape}")
    return array
