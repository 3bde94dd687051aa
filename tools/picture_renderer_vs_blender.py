"""Write docs/renderer_vs_blender.png: our renderer beside Blender (Cycles) on the same posed
hand and camera, with the silhouette and depth differences.

    .venv/bin/python tools/picture_renderer_vs_blender.py [--out docs/renderer_vs_blender.png]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_reference import render_mask_and_depth, render_shaded  # noqa: E402

from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.handmodel.poses import NAMED_POSES  # noqa: E402
from pipeline.preview_render import label  # noqa: E402
from pipeline.render.renderer import Appearance, Light, RenderMesh, render  # noqa: E402

CASES = [("hand", "spread", (np.pi, 0.2, 0.1), (0.0, 0.09, 0.5)),
         ("hand", "fist", (2.5, 0.9, 0.3), (0.01, 0.06, 0.42)),
         ("arm", "pinch", (np.pi, -0.4, 0.0), (0.0, 0.12, 0.8))]
SIZE, FOCAL = 256, 560.0
LIGHT = np.array([0.25, -0.35, 0.1])


def row(mode, pose, orient, transl):
    model = HandModel.load(mode, subdivided=True, dtype=torch.float64)
    vertices = model(pose=torch.as_tensor(NAMED_POSES[pose])[None], global_orient=torch.tensor([orient]),
                     transl=torch.tensor([transl])).vertices
    K = np.array([[FOCAL, 0, SIZE / 2], [0, FOCAL, SIZE / 2], [0, 0, 1]])
    albedo = torch.tensor([0.8, 0.6, 0.5], dtype=torch.float64).view(3, 1, 1).expand(3, 4, 4)
    ours = render(vertices, RenderMesh.from_model_data(model.data, dtype=torch.float64), torch.tensor(K), SIZE, SIZE,
                  outputs=("rgb", "alpha", "depth"), appearance=Appearance(albedo),
                  light=Light(torch.tensor(LIGHT), torch.tensor(0.35, dtype=torch.float64), shadows=True),
                  background=torch.tensor([0.25, 0.25, 0.25], dtype=torch.float64))
    alpha, depth = render_mask_and_depth(vertices[0].numpy(), model.data.faces, K, SIZE, SIZE)
    shaded = render_shaded(vertices[0].numpy(), model.data.faces, K, SIZE, SIZE, LIGHT)
    our_rgb = (ours["rgb"][0].numpy() ** (1 / 2.2) * 255).clip(0, 255).astype(np.uint8)
    blender_rgb = (shaded[..., :3] * shaded[..., 3:] + 0.25 ** (1 / 2.2) * (1 - shaded[..., 3:])) * 255
    blender_rgb = blender_rgb.clip(0, 255).astype(np.uint8)
    our_mask, their_mask = ours["alpha"][0, ..., 0].numpy() > 0.5, alpha > 0.5
    mask_tile = np.full((SIZE, SIZE, 3), 255, np.uint8)
    mask_tile[our_mask & their_mask] = (200, 200, 200)
    mask_tile[our_mask & ~their_mask] = (220, 40, 40)
    mask_tile[~our_mask & their_mask] = (40, 40, 220)
    both = our_mask & their_mask
    difference = np.zeros((SIZE, SIZE))
    difference[both] = np.abs(ours["depth"][0, ..., 0].numpy()[both] - depth[both]) * 1000
    depth_tile = np.repeat((255 * (1 - np.clip(difference / 1.0, 0, 1))).astype(np.uint8)[..., None], 3, axis=2)
    depth_tile[~both] = (235, 245, 255)
    iou = both.sum() / (our_mask | their_mask).sum()
    return [label(our_rgb.copy(), f"ours: {mode}, {pose}"), label(blender_rgb.copy(), "Blender Cycles"),
            label(mask_tile, f"masks IoU {iou:.4f}"),
            label(depth_tile, f"depth diff {difference[both].mean():.4f} mm (black 1 mm)", 0.4)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/renderer_vs_blender.png")
    args = parser.parse_args()
    rows = [np.concatenate(row(*case), axis=1) for case in CASES]
    cv2.imwrite(args.out, np.concatenate(rows, axis=0)[:, :, ::-1])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
