"""How much of the light the fitted frames show comes from the skin's specular lobe: what
`auto` keeps the lobe by (fitting.py)."""
from __future__ import annotations

import dataclasses

import torch

from ..render.renderer import render

FRAMES = 12       # fitted frames measured (spread over the clip)
BATCH = 4
HIGHLIGHT_QUANTILE = 0.99   # a highlight covers a few per cent of the skin: its strength is a high quantile
# and only the skin that faces the camera counts (the normal's cosine with the view at least this): towards the
# outline the lobe's sheen of the room grows with Fresnel's term whatever the level, and there the pixels mix
# with the background; a lobe fitted to a clip drawn without one read 3.1% there, 0.3% without it
FACING = 0.5


@torch.no_grad()
def specular_share(problem, shadows) -> dict:
    """The lobe's share of the colour the avatar shows on up to FRAMES of its fitted frames, on
    the rendered silhouette where it faces the camera (FACING): {"mean": the summed sheen over the
    summed colour, "highlight": the HIGHLIGHT_QUANTILE of the per-pixel share (grey levels)};
    zeros with the lobe off. The sheen is
    what the lobe adds to the frames' values (the render less the render without it), so it
    reads the same in either colour model."""
    avatar, clip = problem.avatar, problem.clip
    if avatar.light().specular is None:
        return {"mean": 0.0, "highlight": 0.0}
    count = len(problem.frames)
    chosen = torch.linspace(0, count - 1, min(FRAMES, count), device=avatar.albedo.device).round().long().unique()
    appearance = avatar.appearance()
    sheens, colours = [], []
    for batch in chosen.split(BATCH):
        vertices, _ = avatar.posed(batch)
        light = avatar.light(shadows, batch, vertices)
        matte = dataclasses.replace(light, specular=None)
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                        outputs=("rgb", "alpha", "normal"), appearance=appearance, light=light, antialiased=False)
        sheen = images["rgb"] - render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                                       outputs=("rgb",), appearance=appearance, light=matte, antialiased=False)["rgb"]
        inside = (images["alpha"][..., 0] > 0.5) & (-images["normal"][..., 2] >= FACING)   # the camera looks along +z
        sheens.append(sheen.mean(-1)[inside])
        colours.append(images["rgb"].mean(-1)[inside])
    sheen, colour = torch.cat(sheens), torch.cat(colours)
    if len(sheen) == 0:
        return {"mean": 0.0, "highlight": 0.0}
    per_pixel = sheen / colour.clamp(min=1e-3)
    return {"mean": float(sheen.sum() / colour.sum().clamp(min=1e-12)),
            "highlight": float(torch.quantile(per_pixel.float(), HIGHLIGHT_QUANTILE))}
