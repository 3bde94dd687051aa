"""Benchmark: MediaPipe keypoints and the initial fit on synthetic clips with ground truth.

    .venv/bin/python benchmarks/bench_initialisation.py [--clips DIR ...] [--render-to DIR]

Without --clips it renders (once, into --render-to, default /tmp/harp_bench_init) the clips
`flip` and `fingers` (30 frames, ambient light) at 256x256 and 448x448 with synth/render.py.
Per clip it prints the detector's 2D keypoint error against gt.keypoints2d (pixels, detected
frames), its detection rate and handedness agreement, and the Procrustes-aligned 3D keypoint
error of the initial fit against gt.keypoints3d (mm), with its wall time; the same fit from
the exact 2D keypoints (`gt 2D`) separates the detector's error from the fit's.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.init.initial_fit import fit_initial_estimate  # noqa: E402
from pipeline.detection.mediapipe_hands import detect_sequence_keypoints  # noqa: E402
from pipeline.formats.keypoint_file import Keypoints2D  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.metrics import procrustes_error  # noqa: E402

CLIPS = [("flip", 256), ("fingers", 256), ("flip", 448), ("fingers", 448)]


def render_clips(folder):
    clips = []
    for motion, size in CLIPS:
        out = Path(folder) / f"{motion}{size}"
        if not (out / seq.SEQUENCE_FILE).is_file():
            subprocess.run([sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(out), "--motion", motion,
                            "--lighting", "ambient", "--width", str(size), "--height", str(size), "--frames", "30",
                            "--samples", "4", "--overwrite"], check=True)
        clips.append(out)
    return clips


def pa_mm(estimate, gt):
    error = procrustes_error(torch.as_tensor(estimate.keypoints3d), torch.as_tensor(gt.keypoints3d))
    return 1000 * error.numpy()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", nargs="*", help="sequence folders with gt.npz")
    parser.add_argument("--render-to", default="/tmp/harp_bench_init")
    args = parser.parse_args()
    clips = [Path(c) for c in args.clips] if args.clips else render_clips(args.render_to)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    header = (f"{'clip':<14}{'size':>5}{'det.':>7}{'hand ok':>8}{'2D mean':>9}{'2D med':>8}"
              f"{'PA mm':>7}{'PA med':>7}{'init s':>7}{'gt2D PA':>8}{'gt2D s':>7}{'flat PA':>8}")
    print(header)
    for clip in clips:
        info = seq.read_sequence_info(clip)
        gt = seq.read_ground_truth(clip / seq.GT_FILE)
        start = time.perf_counter()
        keypoints = detect_sequence_keypoints(clip, info)
        detect_s = time.perf_counter() - start
        error_2d = np.linalg.norm(keypoints.points - gt.keypoints2d, axis=-1).mean(-1)[keypoints.detected]
        start = time.perf_counter()
        estimate = fit_initial_estimate(keypoints, info.K, mode=gt.mode, side=info.hand_side)
        init_s = time.perf_counter() - start + detect_s
        exact = Keypoints2D(points=gt.keypoints2d, detected=np.ones(info.frame_count, bool),
                            score=np.ones(info.frame_count), source="keypoints")
        start = time.perf_counter()
        oracle = fit_initial_estimate(exact, info.K, mode=gt.mode, side=info.hand_side)
        oracle_s = time.perf_counter() - start
        flat_pa = pa_mm(type(estimate)(**{**estimate.__dict__, "keypoints3d": _flat_hand(gt)}), gt).mean()
        summary = keypoints.summary()
        pa = pa_mm(estimate, gt)
        print(f"{clip.name:<14}{info.width:>5}{summary['detection_rate']:>7.2f}{summary['handedness_agreement']:>8.2f}"
              f"{error_2d.mean():>9.2f}{np.median(error_2d):>8.2f}{pa.mean():>7.1f}{np.median(pa):>7.1f}"
              f"{init_s:>7.1f}{pa_mm(oracle, gt).mean():>8.1f}{oracle_s:>7.1f}{flat_pa:>8.1f}")
    print("det.: detection rate; hand ok: handedness label agreement on detected frames; 2D: MediaPipe keypoint\n"
          "error (px, detected frames); PA: Procrustes-aligned 3D keypoint error of the initial fit (mm, all\n"
          "frames); init s: detection + fit wall time; gt2D: the fit from exact 2D keypoints; flat PA: the\n"
          "flat average hand (no fit) for scale")


def _flat_hand(gt):
    from pipeline.handmodel.lbs import HandModel

    model = HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    with torch.no_grad():
        points = model(torch.zeros(model.num_betas, dtype=torch.float64)).keypoints[0, :21]
    return points.expand(gt.frame_count, -1, -1).numpy()


if __name__ == "__main__":
    main()
