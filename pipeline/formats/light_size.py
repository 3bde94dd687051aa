"""The light's size: the angular radius (radians) under which the hand sees its light, a disc
(render/area_light.py). 0 is HARP's point light, whose shadows are hard; a window or a softbox
seen from a hand a metre away is 10-20 degrees across, and its shadows soften with the distance
from the finger that casts them.

Stored in avatar.json's light as "angular_radius" (radians); avatar folders written before it
have none (a point light). Blender's sun takes it as its angle, the disc's angular diameter
(sun_angle). numpy and the standard library only: the add-on reads it too.
"""
from __future__ import annotations

import math

KEY = "angular_radius"
MAX_ANGULAR_RADIUS = math.radians(45.0)   # wider is a room's light, which the environment light holds


def to_description(angular_radius) -> float:
    """avatar.json's entry for a light of `angular_radius` (radians; a float or one-element tensor)."""
    return round(float(angular_radius), 6)


def from_description(light: dict) -> float:
    """The angular radius (radians) of avatar.json's `light` (a dict): 0 where it has none; a
    malformed or out-of-range entry is a ValueError."""
    value = light.get(KEY, 0.0)
    try:
        radius = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"the light's {KEY} must be a number of radians, got {value!r}") from None
    if not math.isfinite(radius) or not 0 <= radius <= MAX_ANGULAR_RADIUS:
        raise ValueError(f"the light's {KEY} {radius} is out of range [0, {MAX_ANGULAR_RADIUS:.3f}] radians")
    return radius


def sun_angle(light: dict) -> float:
    """Blender's sun angle (radians: the light's angular diameter) for avatar.json's `light`."""
    return 2.0 * from_description(light)
