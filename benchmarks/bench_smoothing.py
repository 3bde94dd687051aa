"""Benchmark: what smoothing the keys at bind time (pipeline/formats/pose_smoothing.py, `harp
blend --smooth N`, the add-on's "Smooth keys") does to a fitted synthetic clip's motion:
jitter (the joints' mean acceleration, mm per frame^2, over every three consecutive fitted
frames) and accuracy (joint error against gt.npz, Procrustes-aligned and in the camera frame),
for several windows, beside the truth's own acceleration.

    .venv/bin/python benchmarks/bench_smoothing.py FIT SEQ [--windows 0,5,7,9,11,15]

FIT is an avatar folder fitted from the sequence folder SEQ (which has gt.npz).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pipeline.evaluate.finished_fit import fitted_avatar  # noqa: E402
from pipeline.evaluate.poses import PoseScorer, _hand, point_errors  # noqa: E402
from pipeline.formats.avatar_folder import read_poses  # noqa: E402
from pipeline.formats.pose_smoothing import smooth_poses  # noqa: E402


def mean_acceleration_mm(joints, frames):
    """Mean norm (mm per frame^2) of the joints' second difference over every three keys at
    consecutive frames; joints (F, J, 3) in metres."""
    frames = np.asarray(frames)
    triples = np.flatnonzero((frames[1:-1] - frames[:-2] == 1) & (frames[2:] - frames[1:-1] == 1)) + 1
    second = joints[triples + 1] - 2 * joints[triples] + joints[triples - 1]
    return float(np.linalg.norm(second, axis=-1).mean() * 1000)


def motion_figures(fit, sequence, windows):
    """[(window, acceleration mm/frame^2, joint PA mm, joint camera mm)], and the truth's acceleration."""
    torch.set_num_threads(1)
    avatar, _ = fitted_avatar(fit, sequence, "cpu")
    poses = read_poses(fit)
    scorer = PoseScorer(sequence)
    truth = scorer.truth(poses.frames)[0]["joints"]
    betas = avatar.betas.detach().cpu().numpy()
    rows = []
    for window in windows:
        smoothed = smooth_poses(poses, window)
        joints, _ = _hand(scorer.model, betas, smoothed.pose, smoothed.global_orient, smoothed.transl)
        errors = point_errors(joints, truth)
        rows.append((window, mean_acceleration_mm(joints.numpy(), poses.frames), errors["procrustes_mm_mean"],
                     errors["camera_mm_mean"]))
    return rows, mean_acceleration_mm(truth.numpy(), poses.frames)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--windows", default="0,5,7,9,11,15")
    args = parser.parse_args()
    windows = [int(w) for w in args.windows.split(",")]
    rows, truth = motion_figures(args.fit, args.sequence, windows)
    print(f"truth: mean joint acceleration {truth:.3f} mm/frame^2")
    print("| window (frames) | joint acceleration mm/frame^2 | vs none | joint PA mm | joint camera mm |")
    print("|---|---|---|---|---|")
    for window, acceleration, aligned, camera in rows:
        print(f"| {window or 'off'} | {acceleration:.3f} | {acceleration / rows[0][1] - 1:+.0%} | {aligned:.3f} | "
              f"{camera:.3f} |")


if __name__ == "__main__":
    main()
