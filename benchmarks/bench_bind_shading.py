"""Benchmark: the avatar bound in Blender, rendered by Cycles, against the fit's own render of the
same fitted frame (bpy).

    .venv/bin/python benchmarks/bench_bind_shading.py FIT SEQ [--frame 0] [--samples 128] [--picture OUT.png]

The add-on binds the fit folder FIT with its footage SEQ into an empty scene (its camera, keyed
rig, skin material, sun and world); Cycles renders the first fitted frame (or the fitted frame
`--frame`, its index among the fitted frames) with direct light only and the Standard view
transform (tools/picture_blender_bind.py render_bound); our renderer draws the fitted avatar
in the same frame, camera and size under its fitted light. Printed over the pixels both cover (2 px in from the outline): the
PSNR between the two, the Blender render's brightness over the fit's in bands of the fit's
brightness, and the exponent k of the best power law blender = c * fit^k (1: the bind shades as
the fit does; about 0.45: the fit's shading taken as linear light, docs/fidelity.md "Dark and
light skin").
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from picture_blender_bind import render_bound  # noqa: E402
from scipy import ndimage  # noqa: E402

BANDS = [(0.0, 0.3), (0.3, 0.45), (0.45, 0.6), (0.6, 0.75), (0.75, 1.01)]


def fit_render(avatar, frame_K, index, bound):
    """(rgb (H, W, 3), alpha (H, W)) of the fitted avatar at its fitted frame `index`, drawn by our
    renderer at the bound camera's size with that frame's K (the footage's) under the fitted light."""
    from pipeline.render.renderer import render

    with torch.no_grad():
        vertices, _ = avatar.posed(torch.tensor([index]))
        K = torch.as_tensor(frame_K, dtype=vertices.dtype)
        images = render(vertices, avatar.mesh, K, bound.height, bound.width, outputs=("rgb", "alpha"),
                        appearance=avatar.appearance(), light=avatar.light(False), antialiased=False)
    return images["rgb"][0].numpy(), images["alpha"][0, ..., 0].numpy()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--frame", type=int, default=0, help="which fitted frame (its index among them)")
    parser.add_argument("--samples", type=int, default=128)
    parser.add_argument("--picture", type=Path, help="write the fit's render beside Blender's here")
    args = parser.parse_args(argv)
    from pipeline.evaluate.finished_fit import fitted_avatar
    from pipeline.formats import sequence_folder as seq

    avatar, report = fitted_avatar(args.fit, args.sequence, device="cpu")
    frame = report["frames"][args.frame]
    renders, bound = render_bound(args.fit, [frame], args.samples, args.sequence, direct_light_only=True)
    blender = renders[frame]
    rgb, alpha = fit_render(avatar, seq.read_sequence_info(args.sequence).frame_K()[frame], args.frame, bound)
    both = ndimage.binary_erosion((alpha > 0.5) & (blender[..., 3] > 0.99), iterations=2)
    union = ((alpha > 0.5) | (blender[..., 3] > 0.5)).sum()
    fitted, bound_rgb = rgb[both], blender[..., :3][both]
    psnr = 10 * np.log10(1 / max(np.square(bound_rgb - fitted).mean(), 1e-12))
    print(f"{args.fit}: {both.sum()} px both cover (IoU {((alpha > 0.5) & (blender[..., 3] > 0.5)).sum() / union:.4f}); "
          f"Blender against the fit: PSNR {psnr:.2f} dB")
    f, b = fitted.mean(-1), bound_rgb.mean(-1)
    for low, high in BANDS:
        chosen = (f >= low) & (f < high)
        if chosen.sum() >= 50:
            print(f"  fit brightness {low:.2f}-{high:.2f}: {chosen.sum():6d} px, fit {f[chosen].mean():.3f}, "
                  f"Blender {b[chosen].mean():.3f} (x{np.median(b[chosen] / f[chosen]):.2f})")
    k, c = np.polyfit(np.log(np.clip(f, 1e-3, None)), np.log(np.clip(b, 1e-3, None)), 1)
    print(f"  Blender ~ {np.exp(c):.2f} * fit^{k:.2f}")
    if args.picture:
        side = np.concatenate([rgb, blender[..., :3]], 1)
        cv2.imwrite(str(args.picture), (side[..., ::-1] * 255).clip(0, 255).round().astype(np.uint8))


if __name__ == "__main__":
    main()
