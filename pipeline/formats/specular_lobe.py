"""The skin's specular lobe: the white sheen of real skin beside the albedo's diffuse colour.

With it the fit's colour is

    colour = albedo * (a + (1 - a) * max(0, n . l) * V + environment)
             + (1 - a) * V * pi * f_s(n, l, v) * max(0, n . l)
             + E(n . v) * L(r)

f_s is the specular half of Blender's Principled BSDF: a GGX microfacet lobe (alpha = roughness^2),
Smith's height-correlated masking, and the exact dielectric Fresnel term of the index of
refraction whose reflectance at normal incidence is that of IOR 1.5 (F0 = 0.04) times 2 * level,
as Principled's "Specular IOR Level" sets it (0.5: the IOR's own reflectance, 0: none, 1: twice
it; render/shading.py principled_fresnel). The fit's light has irradiance pi (1 - a) (a Blender
sun of that strength lights a Lambertian albedo exactly as the fit does), hence the pi. The last
line is the lobe's sheen of the room (render/shading.py room_specular): E the lobe's reflectance
of uniform light towards the camera, L the room's radiance (ambient and environment) along the
mirror direction r, blurred as the environment's harmonics are. The bind puts roughness and
level into the Principled BSDF (principled_inputs), which then reflects the sun and the bound
world as the fit does (tests/test_blender_specular.py).

Stored in avatar.json's light as {"roughness": r, "level": s}, or null where the fit found no
sheen; avatar folders written before it have no such key (Blender's defaults then).
numpy and the standard library only: the add-on reads it too.
"""
from __future__ import annotations

import math

ROUGHNESS_RANGE = (0.2, 1.0)   # below 0.2 a lobe is a mirror's glint, not skin; the fit's roughness stays inside
LEVEL_MAX = 1.0                # twice the reflectance of IOR 1.5 (F0 0.08): oilier than any skin
IOR = 1.5
BASE_REFLECTANCE = ((IOR - 1) / (IOR + 1)) ** 2   # F0 of IOR 1.5 at level 0.5
# what Blender's Principled BSDF does without a fitted lobe (avatar folders from before it): the bind's
# long-standing satin skin, and Principled's own specular level
BLENDER_DEFAULT = {"roughness": 0.5, "level": 0.5}
KEY = "specular"


def to_description(roughness, level):
    """avatar.json's entry for a lobe of `roughness` and `level` (floats or one-element tensors),
    or None for none (either None)."""
    if roughness is None or level is None:
        return None
    return {"roughness": _number(roughness), "level": _number(level)}


def from_description(light: dict):
    """(roughness, level) of avatar.json's `light` (a dict), or None where the fit found no sheen
    or the folder is from before the lobe; a malformed entry is a ValueError."""
    values = light.get(KEY)
    if values is None:
        return None
    try:
        roughness, level = float(values["roughness"]), float(values["level"])
    except (TypeError, KeyError, ValueError):
        raise ValueError(f"the light's specular lobe must be {{'roughness': r, 'level': s}}, got {values!r}") from None
    if not (math.isfinite(roughness) and math.isfinite(level)) or not 0 < roughness <= 1 or not 0 <= level <= 4:
        raise ValueError(f"the light's specular lobe is out of range: roughness {roughness} (0..1], level {level} [0..4]")
    return roughness, level


def principled_inputs(light: dict) -> dict:
    """{Principled BSDF input name: value} that give a bound avatar the fit's sheen: its
    roughness and level; a fit that found none is matte (level 0); a folder from before the lobe
    keeps BLENDER_DEFAULT."""
    if KEY not in light:
        lobe = BLENDER_DEFAULT["roughness"], BLENDER_DEFAULT["level"]
    else:
        lobe = from_description(light) or (BLENDER_DEFAULT["roughness"], 0.0)
    return {"Roughness": lobe[0], "Specular IOR Level": lobe[1], "IOR": IOR}


def _number(value) -> float:
    """A float of a number or a one-element array or tensor (a tensor's gradient dropped)."""
    return float(value.detach() if hasattr(value, "detach") else value)
