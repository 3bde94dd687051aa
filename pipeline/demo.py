"""`harp demo`, the README's main job: a synthetic clip rendered with Cycles (synth/), MediaPipe
initialisation, the `fast` fit, and the figures against the clip's exact ground truth.

    <out>/clip/          the sequence folder (frames, masks, gt.npz, gt_albedo.png, init.npz)
    <out>/avatar/        the avatar folder, report.json, fit_grid.png, overlay.mp4, evaluation.json
    <out>/avatar_*.png   the avatar in new poses and light (harp render)
"""
from __future__ import annotations

import time
from pathlib import Path

DEMO_CLIP = {"motion": "flip", "lighting": "ambient", "width": 256, "height": 256, "frames": 30, "samples": 16}
NEW_POSES = ("fist", "thumbs_up")


class DemoError(ValueError):
    """The demo cannot run (one-line message)."""


def render_demo_clip(folder, log=print, **changes):
    """The demo's 30-frame 256x256 `flip` clip under `ambient` light, rendered with Cycles
    (`changes` replace DEMO_CLIP's settings, for tests)."""
    try:
        import bpy  # noqa: F401  (Blender as a Python module renders the clip)
    except ImportError as error:
        raise DemoError("harp demo renders its clip with Blender's Cycles: install the bpy module "
                        "(bash tools/setup.sh does)") from error
    from synth import SynthError
    from synth.clip import render_clip
    from synth.options import parse_clip_args

    try:
        arguments = [f"--{name}={value}" for name, value in {**DEMO_CLIP, **changes}.items()]
        summary = render_clip(parse_clip_args(["--out", str(folder), "--overwrite", *arguments]),
                              log=lambda message: None)
    except SynthError as error:
        raise DemoError(f"rendering the demo clip failed: {error}") from error
    log(f"rendered {summary['frames']} frames to {folder} in {summary['seconds']:.0f} s")


def run_demo(out, progress="bar", log=print, max_steps=None, **clip_changes):
    """Render, initialise, fit and evaluate; returns a dict of the headline figures.
    `max_steps` and `clip_changes` shrink the job for tests."""
    from .avatar_render import render_avatar
    from .evaluate import evaluate_fit, summary_lines
    from .fit import fit
    from .init import initialise_sequence
    from .fit.outputs import metrics_line

    out = Path(out)
    clip, avatar = out / "clip", out / "avatar"
    start = time.time()
    render_demo_clip(clip, log, **clip_changes)
    initialise_sequence(clip, "mediapipe", None, mode="auto", log=log)
    log(f"initialised from MediaPipe keypoints ({time.time() - start:.0f} s so far)")
    report = fit(clip, avatar, preset="fast", progress=progress, max_steps=max_steps)
    evaluation = evaluate_fit(avatar, clip, novel_poses=True)  # against the clip's exact ground truth
    for line in summary_lines(evaluation):
        log(line)
    pictures = [render_avatar(avatar, out / f"avatar_{pose}.png", pose, None, 30.0, 10.0, None, 384, None)
                for pose in NEW_POSES]
    scores = report["metrics"]
    seconds = time.time() - start
    log(f"fit: {metrics_line(scores)}")
    log(f"demo finished in {seconds / 60:.1f} min: avatar in {avatar}, pictures {avatar / 'fit_grid.png'}, "
        + ", ".join(str(p) for p in pictures))
    return {"seconds": seconds, "metrics": scores, "evaluation": evaluation, "pictures": pictures}
