"""MediaPipe's landmarks against the hand model's keypoints, with and without the landmark
offsets (pipeline/init/landmark_offsets.py), on synthetic clips whose truth is known.

    python benchmarks/bench_landmark_offsets.py OUT [--identities 1,2,4,5] [--samples 1] [--size 256]
        [--clips CLIP ...]

Renders one short clip per identity (6 frames of `flip`, hand + forearm, `--size` px square,
`--samples` Cycles samples; the last identity a left hand) into OUT unless it is there, runs MediaPipe on each clip and on each of
`--clips` (synthetic clips of your own, e.g. `harp demo`'s), and prints per clip: the landmarks'
mean distance (px) from the true posed keypoints and from the same moved by the offsets; then
the initial fit's depth (mean over frames, over the truth's), its hand's size (keypoints' mean
spread over the truth's) and its Procrustes-aligned joint error (mm), with the landmarks taken
for the model's keypoints and with the offsets. Writes OUT/bench_landmark_offsets.json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.detection.mediapipe_hands import detect_sequence_keypoints  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.init.initial_fit import InitialFitSettings, fit_initial_estimate  # noqa: E402
from pipeline.init.landmark_offsets import on_mediapipe_landmarks  # noqa: E402
from pipeline.metrics import procrustes_error  # noqa: E402
from pipeline.render.rasterize import project  # noqa: E402


def render_clip(out, identity, side, samples, size):
    if (out / seq.GT_FILE).is_file():
        return out
    command = [sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(out), "--width", str(size),
               "--height", str(size), "--samples", str(samples), "--texture-size", "256", "--lighting", "ambient", "--motion", "flip",
               "--frames", "6", "--seconds", "1", "--side", side, "--identity", str(identity)]
    subprocess.run(command, check=True, capture_output=True, timeout=600)
    return out


def _spread(points):
    return float(np.linalg.norm(points - points.mean(-2, keepdims=True), axis=-1).mean())


def measure(folder):
    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(folder / info.ground_truth)
    keypoints = detect_sequence_keypoints(folder, info)
    found = keypoints.detected
    model = HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    truth = [torch.as_tensor(np.asarray(a), dtype=torch.float64) for a in (gt.betas, gt.pose, gt.global_orient, gt.transl)]
    K = torch.as_tensor(info.frame_K())
    row = {"clip": str(folder), "side": gt.side, "frames": int(info.frame_count), "detected": int(found.sum())}
    for name, on_model in (("keypoints", model), ("offsets", on_mediapipe_landmarks(model))):
        with torch.no_grad():
            pixels = project(on_model(*truth).keypoints[:, :21], K).numpy()
        row[f"landmark_px_{name}"] = float(np.linalg.norm(pixels - keypoints.points, axis=-1)[found].mean())
    true_points = gt.keypoints3d[:, :21]
    for name, offsets in (("keypoints", False), ("offsets", True)):
        estimate = fit_initial_estimate(keypoints, info.K, mode=gt.mode, side=gt.side,
                                        settings=InitialFitSettings(landmark_offsets=offsets))
        joints = procrustes_error(torch.as_tensor(estimate.keypoints3d), torch.as_tensor(true_points)).numpy()
        row[f"init_{name}"] = {"depth_ratio": float(estimate.keypoints3d[..., 2].mean() / true_points[..., 2].mean()),
                               "size_ratio": _spread(estimate.keypoints3d) / _spread(true_points),
                               "joints_mm": float(1000 * joints.mean())}
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--identities", default="1,2,4,5")
    parser.add_argument("--samples", type=int, default=1, help="Cycles samples of the rendered clips")
    parser.add_argument("--size", type=int, default=256, help="their width and height, pixels")
    parser.add_argument("--clips", nargs="*", default=[], type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    identities = [int(i) for i in args.identities.split(",") if i]
    clips = [render_clip(args.out / f"identity{i}_{args.size}px_{args.samples}spp", i,
                         "left" if k == len(identities) - 1 else "right", args.samples, args.size)
             for k, i in enumerate(identities)] + list(args.clips)
    rows = []
    print("clip | landmarks px: keypoints -> offsets | init depth ratio | init size ratio | init joints mm")
    for folder in clips:
        row = measure(Path(folder))
        rows.append(row)
        a, b = row["init_keypoints"], row["init_offsets"]
        print(f"{Path(folder).name} ({row['side']}) | {row['landmark_px_keypoints']:.2f} -> {row['landmark_px_offsets']:.2f} | "
              f"{a['depth_ratio']:.3f} -> {b['depth_ratio']:.3f} | {a['size_ratio']:.3f} -> {b['size_ratio']:.3f} | "
              f"{a['joints_mm']:.2f} -> {b['joints_mm']:.2f}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_landmark_offsets.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
