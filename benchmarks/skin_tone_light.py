"""Benchmark: how much lighter than its albedo each skin tone looks in a synthetic clip's frames.

    .venv/bin/python benchmarks/skin_tone_light.py SEQ [--frames 0-3,26-29 12-17]

The true hand is rasterised at its true poses (gt.npz vertices) by our renderer, which gives
each pixel the true albedo (gt_albedo.png) and the surface's normal. Over the pixels inside the
mask (3 px from its edge), for each group of frames, per skin tone (the true albedo's brightness
under 0.35: dark; above 0.5: light) and per band of n . v (how squarely the skin faces the
camera), printed: the median of the frame's colour over the true albedo, per channel. Under a
colour model colour = albedo x shading the two tones give the same figures where they face the
camera alike; a part of the colour that does not scale with the albedo (the skin's reflection
of the room) makes the dark tone lighter than its albedo, most in its darkest channel
(docs/fidelity.md, "Dark and light skin").
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402
from scipy import ndimage  # noqa: E402

from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.handmodel.lbs import load_model_data  # noqa: E402
from pipeline.render.renderer import Appearance, RenderMesh, render  # noqa: E402

TONES = {"dark": (0.0, 0.35), "light": (0.5, 1.01)}
FACING = [(0.2, 0.45), (0.45, 0.65), (0.65, 0.8), (0.8, 0.9), (0.9, 1.01)]
EDGE_PX = 3


def frame_range(text):
    """Frame indices from "0-3,26-29"."""
    indices = []
    for part in text.split(","):
        first, _, last = part.partition("-")
        indices.extend(range(int(first), int(last or first) + 1))
    return indices


def true_pixels(folder, info, gt, mesh, albedo, frame):
    """(colour (N, 3), true albedo (N, 3), n . v (N,)) of the pixels inside frame `frame`'s
    rendered true hand, EDGE_PX from its outline."""
    points = torch.as_tensor(gt.vertices[frame:frame + 1], dtype=torch.float32)
    K = torch.as_tensor(info.frame_K()[frame], dtype=torch.float32)
    images = render(points, mesh, K, info.height, info.width, outputs=("albedo", "normal", "alpha"),
                    appearance=Appearance(albedo), antialiased=False)
    inside = ndimage.binary_erosion(images["alpha"][0, ..., 0].numpy() > 0.5, iterations=EDGE_PX)
    colour = seq.read_rgb(seq.frame_path(folder, info, frame)).astype(np.float32) / 255
    pixel = np.stack(np.meshgrid(np.arange(info.width) + 0.5, np.arange(info.height) + 0.5), -1)
    rays = np.concatenate([pixel, np.ones(pixel.shape[:2] + (1,))], -1) @ np.linalg.inv(info.frame_K()[frame]).T
    to_camera = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    facing = (images["normal"][0].numpy() * to_camera).sum(-1)
    return colour[inside], images["albedo"][0].numpy()[inside], facing[inside]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--frames", nargs="+", default=["0-3,26-29", "12-17"],
                        help="groups of frames, e.g. those that show the back and those that show the palm")
    args = parser.parse_args(argv)
    info = seq.read_sequence_info(args.sequence)
    if not info.ground_truth or not info.albedo:
        parser.error(f"{args.sequence} has no ground truth (gt.npz and gt_albedo.png)")
    gt = seq.read_ground_truth(args.sequence / info.ground_truth)
    if gt.vertices is None:
        parser.error(f"{args.sequence / info.ground_truth} has no vertices")
    mesh = RenderMesh.from_model_data(load_model_data(gt.mode, gt.side))
    albedo = torch.as_tensor(seq.read_rgb(args.sequence / info.albedo).astype(np.float32) / 255).permute(2, 0, 1)
    for group in args.frames:
        pixels = [true_pixels(args.sequence, info, gt, mesh, albedo, frame) for frame in frame_range(group)
                  if frame < info.frame_count]
        colour, truth, facing = (np.concatenate(column) for column in zip(*pixels))
        brightness = truth.mean(-1)
        print(f"frames {group}:")
        for tone, (low, high) in TONES.items():
            for near, far in FACING:
                chosen = (brightness >= low) & (brightness < high) & (facing >= near) & (facing < far)
                if chosen.sum() < 100:
                    continue
                ratio = np.median(colour[chosen] / np.maximum(truth[chosen], 1e-3), axis=0)
                print(f"  {tone:5s} skin, n.v {near:.2f}-{far:.2f}: {chosen.sum():7d} px, colour over albedo "
                      + " / ".join(f"{value:.2f}" for value in ratio))


if __name__ == "__main__":
    main()
