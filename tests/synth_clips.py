"""Tiny Cycles clips for the fit's tests: a few 96 px frames of `flip`, hand only (or hand +
forearm), with a gt-noise initial estimate (5 degrees per joint, 5 mm)."""
import subprocess
import sys
from pathlib import Path

from pipeline.init.initial_from_ground_truth import ground_truth_with_noise
from pipeline.formats import sequence_folder as seq
from pipeline.formats.initial_estimate import write_initial_estimate

ROOT = Path(__file__).resolve().parents[1]


def render_tiny_clip(folder, frames, mode="hand"):
    result = subprocess.run([sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(folder), "--frames",
                             str(frames), "--width", "96", "--height", "96", "--samples", "1", "--texture-size", "128",
                             "--motion", "flip", "--mode", mode], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    write_initial_estimate(folder, ground_truth_with_noise(gt, joint_degrees=5, translation_m=0.005, seed=0))
    return folder
