"""Benchmark: the avatar bound in Blender, rendered by Cycles, against the fit's own render of the
same fitted frame (bpy).

    .venv/bin/python benchmarks/bench_bind_shading.py FIT SEQ [--frame 0] [--samples 128] [--picture OUT.png]

`harp_addon.scene.bind_avatar` binds the fit folder FIT with its footage SEQ into an empty scene
(its camera, keyed rig, skin material, sun and world); Cycles renders the first fitted frame (or
the fitted frame `--frame`, its index among the fitted frames) with direct light only and the
Standard view transform; our renderer draws the fitted avatar in the same frame, camera and size
under its fitted light. Printed over the pixels both cover (2 px in from the outline): the
PSNR between the two, the Blender render's brightness over the fit's in bands of the fit's
brightness, and the exponent k of the best power law blender = c * fit^k (1: the bind shades as
the fit does; about 0.45: the fit's shading taken as linear light, docs/fidelity.md "Dark and
light skin").
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from scipy import ndimage  # noqa: E402

BANDS = [(0.0, 0.3), (0.3, 0.45), (0.45, 0.6), (0.6, 0.75), (0.75, 1.01)]


def blender_render(fit, sequence, index, samples, folder):
    """(H, W, 4) RGBA in [0, 1] of the bound avatar at its fitted frame number `index`, and the
    BoundAvatar."""
    import bpy

    from harp_addon import scene as harp_scene

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bound = harp_scene.bind_avatar(fit, sequence)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.max_bounces, scene.cycles.seed = samples, False, 0, 0
    scene.view_settings.view_transform, scene.view_settings.look = "Standard", "None"
    scene.render.film_transparent = True
    scene.render.image_settings.file_format, scene.render.image_settings.color_mode = "PNG", "RGBA"
    scene.frame_set(int(bound.frames[index]))
    scene.render.filepath = str(folder / "bound.png")
    bpy.ops.render.render(write_still=True)
    bgra = cv2.imread(str(folder / "bound.png"), cv2.IMREAD_UNCHANGED)
    return bgra[..., [2, 1, 0, 3]].astype(np.float64) / 255, bound


def fit_render(fit, sequence, index, bound):
    """(rgb (H, W, 3), alpha (H, W)) of the fitted avatar at its fitted frame `index`, drawn by our
    renderer at the bound camera's size with that frame's K (the footage's) under the fitted light."""
    from pipeline.evaluate.finished_fit import fitted_avatar
    from pipeline.formats import sequence_folder as seq
    from pipeline.render.renderer import render

    avatar, report = fitted_avatar(fit, sequence, device="cpu")
    frame_K = seq.read_sequence_info(sequence).frame_K()[report["frames"][index]]
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
    with tempfile.TemporaryDirectory() as folder:
        blender, bound = blender_render(args.fit, args.sequence, args.frame, args.samples, Path(folder))
    rgb, alpha = fit_render(args.fit, args.sequence, args.frame, bound)
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
