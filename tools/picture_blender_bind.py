"""Write docs/blender_bind.png: an avatar bound into Blender by the add-on (harp_addon), rendered
by Blender (Cycles) through the bound footage camera at two fitted frames and laid over those
frames of the footage, beside the footage itself.

    .venv/bin/python tools/picture_blender_bind.py AVATAR [--out docs/blender_bind.png] [--frames 2,16]

docs/blender_bind.png: the demo avatar (harp demo's clip and fit), frames 2 and 16.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.preview_render import label  # noqa: E402


def render_bound(avatar, frames, samples=32, sequence=None, direct_light_only=False):
    """({sequence frame: (H, W, 4) float RGBA render}, the BoundAvatar) of the avatar bound into a
    new scene, with its recorded footage or `sequence`; `direct_light_only`: no bounces (the light
    the fit models)."""
    import bpy

    from harp_addon import actions
    from harp_addon.scene import FIRST_FRAME

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bound = actions.bind(avatar, sequence)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising = samples, False
    if direct_light_only:
        scene.cycles.max_bounces = 0
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    renders = {}
    with tempfile.TemporaryDirectory() as folder:
        for frame in frames:
            scene.frame_set(FIRST_FRAME + frame)
            scene.render.filepath = str(Path(folder) / f"{frame}.png")
            bpy.ops.render.render(write_still=True)
            image = cv2.imread(scene.render.filepath, cv2.IMREAD_UNCHANGED)
            renders[frame] = image[..., [2, 1, 0, 3]].astype(np.float64) / 255
    return renders, bound


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("avatar")
    parser.add_argument("--out", default=str(ROOT / "docs" / "blender_bind.png"))
    parser.add_argument("--frames", default=None, help="two fitted sequence frames (default: the first and the middle)")
    args = parser.parse_args(argv)
    from pipeline.formats import avatar_folder as av

    files = av.read_avatar_folder(args.avatar)
    fitted = files.poses.frames.tolist()
    frames = [int(f) for f in args.frames.split(",")] if args.frames else \
        [fitted[0], fitted[len(fitted) // 2]]
    renders, bound = render_bound(args.avatar, frames)
    sequence = Path(files.description["footage"]["sequence"])
    info = seq.read_sequence_info(sequence)
    rows = []
    for frame in frames:
        footage = seq.read_rgb(seq.frame_path(sequence, info, frame)).astype(np.float64) / 255
        render = cv2.resize(renders[frame], footage.shape[1::-1], interpolation=cv2.INTER_AREA)
        over = render[..., :3] * render[..., 3:] + footage * (1 - render[..., 3:])
        tiles = [(footage, f"footage, frame {frame}"), (over, "Blender (Cycles) over it"),
                 (render[..., :3] * render[..., 3:] + 0.85 * (1 - render[..., 3:]), "the bound avatar")]
        rows.append(np.concatenate([label((np.clip(t, 0, 1) * 255).astype(np.uint8), text) for t, text in tiles], 1))
    picture = np.concatenate(rows, 0)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, picture[..., ::-1])
    print(f"wrote {args.out} ({len(bound.frames)} keyed frames)")


if __name__ == "__main__":
    main()
