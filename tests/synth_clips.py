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

