"""How the renderer turns an albedo and a light into the frames' 8-bit values (numpy and the
standard library only; one home of the sRGB formulas and of avatar.json's `light.colour_model`).

    display   the albedo's 8-bit values times the shading, taken as they are: the frames'
              values are treated as linear (avatar folders from before the choice)
    linear    the way a camera and Blender make the picture: the albedo texture is sRGB-encoded,
              decoded to linear light, shaded there and the colour encoded back to sRGB for
              the frames' values. A dark skin's shading then changes its 8-bit values by as
              much as a light skin's relatively (the display model darkens dark skin more), and
              the bound avatar in Blender (which decodes the texture and encodes its render)
              shades as the fit did.

The formulas take numpy arrays or torch tensors alike (no branch is taken by value: the
gradients stay finite at 0).
"""
from __future__ import annotations

DISPLAY = "display"
LINEAR = "linear"
MODELS = (DISPLAY, LINEAR)
KEY = "colour_model"

_DECODE_KNEE = 0.04045        # sRGB: encoded values at or below this are linear (slope 1 / 12.92)
_ENCODE_KNEE = 0.0031308      # the same point in linear light


def srgb_to_linear(values):
    """Linear light of sRGB-encoded `values` (array or tensor; values above 1 continue the curve)."""
    straight = values <= _DECODE_KNEE
    curved = ((values.clip(min=_DECODE_KNEE) + 0.055) / 1.055) ** 2.4
    return values / 12.92 * straight + curved * ~straight


def linear_to_srgb(values):
    """sRGB-encoded values of linear light `values` (array or tensor; negative values take the
    straight part, values above 1 continue the curve)."""
    straight = values <= _ENCODE_KNEE
    curved = 1.055 * values.clip(min=_ENCODE_KNEE) ** (1 / 2.4) - 0.055
    return values * 12.92 * straight + curved * ~straight


def checked(model: str) -> str:
    """`model` if it is one of MODELS; otherwise one ValueError line."""
    if model not in MODELS:
        raise ValueError(f"the colour model must be one of {', '.join(MODELS)}, got {model!r}")
    return model


def from_description(light: dict) -> str:
    """The colour model of avatar.json's `light` (a dict): DISPLAY for folders from before the
    choice; an unknown name is a ValueError."""
    return checked(light.get(KEY, DISPLAY))


def is_linear(light: dict) -> bool:
    return from_description(light) == LINEAR
