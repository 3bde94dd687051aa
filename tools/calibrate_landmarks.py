"""Where MediaPipe puts its 21 hand landmarks on our hand model: the offsets (mm, in the right
hand's rest frame) from the model's own keypoints to MediaPipe's, fitted on synthetic clips whose
true pose and shape are known (gt.npz) and whose frames MediaPipe saw (keypoints.json, from
`harp init` or `harp import-video`).

    python tools/calibrate_landmarks.py --fit CLIP [CLIP ...] [--check CLIP ...] [--write]

Each landmark is rigid on its keypoint's bone, so an offset in the rest frame is one in the
bone's frame. The offsets minimise the robust reprojection error of the true posed keypoints
plus their offsets against MediaPipe's landmarks (Huber at 3% of the hand's size in the image),
with a weak pull to zero. `--check` clips are only scored: the landmarks' reprojection error
with the model's keypoints and with the offsets, and the hand's depth and size from
`harp init` against the truth before and after (the init's depth follows the landmarks' spread in
the image). `--write` stores them in pipeline/assets/mediapipe_landmarks.json, which
`harp init` reads (pipeline/init/landmark_offsets.py).
"""
from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.keypoint_file import read_keypoint_file  # noqa: E402
from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.handmodel.mirror import mirror_points  # noqa: E402
from pipeline.init.landmark_offsets import OFFSETS_FILE  # noqa: E402
from pipeline.render.rasterize import project  # noqa: E402

HUBER = 0.03        # of the hand's size in the image
RIDGE = 1e-3        # pull of the offsets to zero, per cm squared, against the mean robust error
STEPS = 800


def clip_data(folder):
    """(posed keypoint carriers (F, 21, 3, 4), rest keypoints (21, 3), K (F, 3, 3), landmarks
    (F, 21, 2), detected (F,) bool, side) of a synthetic clip, in float64."""
    folder = Path(folder)
    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(folder / info.ground_truth)
    keypoints = read_keypoint_file(folder / "keypoints.json", info.frame_count, info.width, info.height)
    model = HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    betas, pose, orient, transl = (torch.as_tensor(np.asarray(a), dtype=torch.float64)
                                   for a in (gt.betas, gt.pose, gt.global_orient, gt.transl))
    _, joints, rest = model.shaped(betas)
    carriers = model.bone_transforms(joints, pose, orient, transl)[:, model.keypoint_joints][:, :21]
    return (carriers, rest[:21], torch.as_tensor(info.frame_K()), torch.as_tensor(keypoints.points),
            torch.as_tensor(keypoints.detected), gt.side, folder)


def landmarks_on_model(data, offsets):
    """(F, 21, 2) pixels of the model's keypoints moved by `offsets` (21, 3) metres (right hand)."""
    carriers, rest, K, _, _, side, _ = data
    moved = rest + (offsets if side == "right" else mirror_points(offsets))
    points = (carriers[..., :3] @ moved[..., None])[..., 0] + carriers[..., 3]
    return project(points, K)


def robust_error(data, offsets):
    """(mean Huber error in units of the hand's size, per-landmark mean pixel error (21,))."""
    _, _, _, pixels, detected, _, _ = data
    predicted = landmarks_on_model(data, offsets)[detected]
    target = pixels[detected]
    size = (target.amax(1) - target.amin(1)).norm(dim=-1)[:, None]
    distance = (predicted - target).norm(dim=-1)
    relative = distance / size
    huber = torch.where(relative < HUBER, 0.5 * relative ** 2 / HUBER, relative - 0.5 * HUBER)
    return huber.mean(), distance.mean(0)


def calibrate(clips):
    offsets = torch.zeros(21, 3, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([offsets], lr=1e-4)
    for _ in range(STEPS):
        optimiser.zero_grad()
        loss = sum(robust_error(data, offsets)[0] for data in clips) / len(clips)
        loss = loss + RIDGE * (offsets * 100).square().sum(-1).mean()
        loss.backward()
        optimiser.step()
    return offsets.detach()


def report(name, data, offsets):
    zero = torch.zeros_like(offsets)
    before, after = robust_error(data, zero)[1], robust_error(data, offsets)[1]
    print(f"{name}: landmark error {before.mean():.2f} -> {after.mean():.2f} px "
          f"(wrist {before[0]:.1f} -> {after[0]:.1f}, thumb base {before[1]:.1f} -> {after[1]:.1f})")


def _describe(folder):
    """A clip as the offsets file records it: how synth/render.py made it."""
    info = seq.read_sequence_info(folder)
    made = (info.metadata or {}).get("settings", {}) or {}
    entry = {key: made.get(key) for key in ("motion", "lighting", "mode", "side", "identity", "samples")}
    return {"size": [info.width, info.height], "frames": info.frame_count, **entry}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit", nargs="+", required=True, help="synthetic clips with gt.npz and keypoints.json")
    parser.add_argument("--check", nargs="*", default=[], help="clips only scored")
    parser.add_argument("--write", action="store_true", help=f"store the offsets in {OFFSETS_FILE}")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    fitted = [clip_data(folder) for folder in args.fit]
    offsets = calibrate(fitted)
    millimetres = (offsets * 1000).numpy()
    print("offsets (mm, right hand's rest frame: x, y, z):")
    for index, row in enumerate(millimetres):
        print(f"  {index:2d}  {row[0]:6.1f} {row[1]:6.1f} {row[2]:6.1f}   |{np.linalg.norm(row):5.1f}|")
    for data in fitted:
        report(f"fitted on {data[-1]}", data, offsets)
    for folder in args.check:
        report(f"checked on {folder}", clip_data(folder), offsets)
    if args.write:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip()
        entry = {"offsets_mm": np.round(millimetres, 2).tolist(),
                 "frame": "the right hand's rest frame (mirrored for the left hand)",
                 "fitted_on": [_describe(folder) for folder in args.fit], "code": commit,
                 "date": datetime.date.today().isoformat(),
                 "command": "python tools/calibrate_landmarks.py --fit CLIP ... --write, on the clips above"}
        rows = ",\n".join("  " + json.dumps(row) for row in entry.pop("offsets_mm"))
        rest = "".join(f',\n "{key}": {json.dumps(value)}' for key, value in entry.items())
        OFFSETS_FILE.write_text('{\n "offsets_mm": [\n' + rows + "\n ]" + rest + "\n}\n")
        print(f"wrote {OFFSETS_FILE}")


if __name__ == "__main__":
    main()
