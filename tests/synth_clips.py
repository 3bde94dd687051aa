"""Tiny Cycles clips for the fit's tests: a few 96 px frames of `flip`, hand only (or hand +
forearm), with a gt-noise initial estimate (5 degrees per joint, 5 mm)."""
import subprocess
import sys
from pathlib import Path

from pipeline.init.initial_from_ground_truth import ground_truth_with_noise
from pipeline.formats import sequence_folder as seq
from pipeline.formats.initial_estimate import write_initial_estimate

ROOT = Path(__file__).resolve().parents[1]


def render_tiny_clip(folder, frames, mode="hand", side="right"):
    result = subprocess.run([sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(folder), "--frames",
                             str(frames), "--width", "96", "--height", "96", "--samples", "1", "--texture-size", "128",
                             "--motion", "flip", "--mode", mode, "--side", side], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    write_initial_estimate(folder, ground_truth_with_noise(gt, joint_degrees=5, translation_m=0.005, seed=0))
    return folder


def exact_clip(folder, frames, size=96, turn_degrees=25):
    """A clip of the `open` hand turning, drawn exactly (no Cycles: evaluate/exact_clips.py), with
    a gt-noise initial estimate: the fit's quick tests."""
    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.init import initialise_sequence
    from synth.motions import OPEN

    write_clip(folder, OPEN, frames=frames, size=size, turn_degrees=turn_degrees)
    initialise_sequence(folder, "gt-noise", log=lambda *a: None)
    return folder



def known_scene(folder):
    """Everything an exact clip was drawn with but its light (float64 torch), for the tests that
    recover one part of the light from it: {vertices (F, V, 3), mesh, K, height, width, frames
    (F, H, W, 3) in [0, 1], masks (F, H, W, 1) bool, appearance (the true albedo), linear (the
    clip was shaded in linear light: Light.linear), occlusion (the room light's, as the clip was
    drawn with it: Light.occlusion, or None), bounce (Light.bounce, or None)}."""
    import cv2
    import numpy as np
    import torch

    from pipeline.evaluate.exact_clips import mottled_albedo
    from pipeline.formats import colour_model
    from pipeline.handmodel.lbs import HandModel
    from pipeline.render.occlusion import bounce_radiance, hand_lost_light
    from pipeline.render.renderer import Appearance, RenderMesh

    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    model = HandModel.load("hand", "right", dtype=torch.float64)
    count = range(info.frame_count)
    frames = torch.stack([torch.as_tensor(cv2.imread(str(seq.frame_path(folder, info, i)))[..., ::-1].copy(),
                                          dtype=torch.float64) / 255 for i in count])
    masks = torch.stack([torch.as_tensor(cv2.imread(str(seq.mask_path(folder, info, i)), cv2.IMREAD_GRAYSCALE) > 127)
                         for i in count])[..., None]
    vertices = torch.as_tensor(gt.vertices, dtype=torch.float64)
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    occlusion = hand_lost_light(vertices, model.data) \
        if gt.light.get("occlusion", False) else None
    bounce = None if occlusion is None else bounce_radiance(torch.as_tensor(mottled_albedo()), gt.light["ambient"],
                                                            colour_model.is_linear(gt.light))
    return {"vertices": vertices, "mesh": mesh, "occlusion": occlusion, "bounce": bounce,
            "K": torch.as_tensor(np.asarray(info.K), dtype=torch.float64), "height": info.height, "width": info.width,
            "frames": frames, "masks": masks, "appearance": Appearance(torch.as_tensor(mottled_albedo())),
            "linear": colour_model.is_linear(gt.light)}


def quick_fits(clips, names, out_root, **options):
    """{clip name: report, with "out" its avatar folder} of `fast` fits (200 steps a stage, 96 px,
    a 64 px texture) of the exact clips `clips / name`, from a gt-noise start; `options` are more
    fit() options (environment="auto", ...). The steps are named here, not taken from the preset,
    so that retuning `fast` does not move what these tests recover (the lobe's level needs the
    appearance stage's 200 steps: with fast's 100 it recovers 0.23 of a drawn 0.6)."""
    from pipeline.fit.fitting import fit
    from pipeline.init import initialise_sequence

    reports = {}
    for name in names:
        initialise_sequence(clips / name, "gt-noise", log=lambda *a: None)
        out = out_root / name
        reports[name] = fit(clips / name, out, **{"steps": (200, 200, 200), "max_steps": 200, "progress": "none",
                                                  "resolution": 96, "texture_size": 64, **options})
        reports[name]["out"] = out
    return reports
