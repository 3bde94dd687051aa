"""Benchmark: the masks `harp import-video` makes from the footage, against exact masks.

    .venv/bin/python benchmarks/bench_masks.py SEQUENCE... [--step N] [--json OUT]

For each sequence folder with exact masks (synthetic clips from synth/dataset.py or
synth/render.py), the masks are made from its frames as the import makes them
(detection/hand_masks.clip_masks) and compared with the folder's masks: IoU per frame, mean,
worst (and which frame), MediaPipe's detection rate and the time per frame. `--step N` scores
every N-th frame.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from pipeline.detection.hand_masks import clip_masks  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.metrics import mask_iou  # noqa: E402


def score_sequence(folder, step=1):
    info = seq.validate_sequence_folder(folder)
    picks = list(range(0, info.frame_count, step))
    frames = [seq.read_rgb(seq.frame_path(folder, info, index)) for index in picks]
    start = time.perf_counter()
    masks, detected, _ = clip_masks(frames, info.hand_side, fps=info.fps)
    seconds = time.perf_counter() - start
    iou = []
    for index, mask in zip(picks, masks):
        truth = seq.read_mask(seq.mask_path(folder, info, index))
        iou.append(mask_iou(mask, truth))
    iou = np.array(iou)
    return {"clip": Path(folder).name, "frames": len(picks), "size": info.width, "iou_mean": float(iou.mean()),
            "iou_min": float(iou.min()), "worst_frame": picks[int(iou.argmin())],
            "detected": float(np.mean(detected)), "ms_per_frame": 1000 * seconds / len(picks)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+")
    parser.add_argument("--step", type=int, default=1)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    rows = []
    for folder in args.sequences:
        row = score_sequence(folder, args.step)
        rows.append(row)
        print(f"{row['clip']}: IoU mean {row['iou_mean']:.3f}, worst {row['iou_min']:.3f} (frame "
              f"{row['worst_frame']}), {row['frames']} frames at {row['size']} px, detected {row['detected']:.0%}, "
              f"{row['ms_per_frame']:.0f} ms/frame", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
