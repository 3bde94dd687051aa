"""Benchmark: the masks `harp import-video` makes from the footage, against exact masks.

    .venv/bin/python benchmarks/bench_masks.py SEQUENCE... [--step N] [--reference DIR] [--json OUT]

For each sequence folder with exact masks (synthetic clips from synth/dataset.py or
synth/render.py), the masks are made from its frames as the import makes them (at most the
import's AUTO_MASK_SIZE pixels on the long side; detection/hand_masks.clip_masks) and compared
with the folder's masks at that size: IoU per frame, mean, worst (and which frame), MediaPipe's
detection rate and the time per frame, and the same for GrabCut's outline before refine_outline
moves it ("grabcut alone"). `--step N` scores every N-th frame. `--reference DIR`: score against
the masks in DIR instead (PNGs named by frame index, e.g. masks drawn by hand: 000009.png), on
those frames only.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.detection.hand_masks import screened_masks  # noqa: E402
from pipeline.detection.mediapipe_hands import detect_keypoints  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.metrics import mask_iou  # noqa: E402
from pipeline.sequence_import import mask_size_frames  # noqa: E402


def score_sequence(folder, step=1, reference=None):
    info = seq.validate_sequence_folder(folder)
    if reference is None:
        picks = list(range(0, info.frame_count, step))
        truth_paths = [seq.mask_path(folder, info, index) for index in picks]
    else:
        truth_paths = sorted(Path(reference).glob("[0-9]*.png"))
        picks = [int(path.stem) for path in truth_paths]
    frames, _, _ = mask_size_frames((index, seq.read_rgb(seq.frame_path(folder, info, index))) for index in picks)
    height, width = frames[0].shape[:2]
    truths = [cv2.resize(seq.read_mask(path).astype(np.float32), (width, height), interpolation=cv2.INTER_AREA) > 0.5
              for path in truth_paths]
    start = time.perf_counter()
    keypoints = detect_keypoints(frames, info.hand_side)
    masks, _ = screened_masks(frames, keypoints, info.fps)
    seconds = time.perf_counter() - start
    unrefined, _ = screened_masks(frames, keypoints, info.fps, refine=False)
    iou = np.array([mask_iou(mask, truth) for mask, truth in zip(masks, truths)])
    iou_unrefined = np.array([mask_iou(mask, truth) for mask, truth in zip(unrefined, truths)])
    return {"clip": Path(folder).name, "frames": len(picks), "size": frames[0].shape[1], "iou_mean": float(iou.mean()),
            "iou_min": float(iou.min()), "worst_frame": picks[int(iou.argmin())],
            "grabcut_alone_iou_mean": float(iou_unrefined.mean()), "grabcut_alone_iou_min": float(iou_unrefined.min()),
            "detected": float(np.mean(keypoints.detected)), "ms_per_frame": 1000 * seconds / len(picks)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+")
    parser.add_argument("--step", type=int, default=1)
    parser.add_argument("--reference", default=None, help="masks to score against (PNGs named by frame index)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    rows = []
    for folder in args.sequences:
        row = score_sequence(folder, args.step, args.reference)
        rows.append(row)
        print(f"{row['clip']}: IoU mean {row['iou_mean']:.3f}, worst {row['iou_min']:.3f} (frame "
              f"{row['worst_frame']}); GrabCut alone {row['grabcut_alone_iou_mean']:.3f}, worst "
              f"{row['grabcut_alone_iou_min']:.3f}; {row['frames']} frames at {row['size']} px, detected {row['detected']:.0%}, "
              f"{row['ms_per_frame']:.0f} ms/frame", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
