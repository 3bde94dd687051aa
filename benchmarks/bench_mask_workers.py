"""Benchmark: the masks `harp import-video` makes from the footage, by one process and by several.

    .venv/bin/python benchmarks/bench_mask_workers.py VIDEO [--frames 60] [--workers 1,2]

The first `--frames` frames of VIDEO (a video file or a folder of images), shrunk as the import
shrinks them (at most AUTO_MASK_SIZE pixels on the long side), MediaPipe's landmarks found once,
then the masks made (detection/hand_masks.screened_masks) with each worker count in turn: wall
seconds, seconds per frame, the speed-up over the first count, and whether every mask is the same
as the first count's (it must be: each frame's mask depends on that frame alone). Run it alone:
the workers take a core each.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from pipeline.detection.hand_masks import screened_masks  # noqa: E402
from pipeline.detection.mediapipe_hands import detect_keypoints  # noqa: E402
from pipeline.sequence_import import DEFAULT_FPS, FrameSource, mask_size_frames  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("video")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--workers", default="1,2", help="worker counts to time, comma-separated (default 1,2)")
    parser.add_argument("--side", choices=("right", "left"), default="right")
    args = parser.parse_args(argv)
    source = FrameSource(Path(args.video), "video", limit=args.frames)
    small, _, _ = mask_size_frames(source)
    started = time.perf_counter()
    keypoints = detect_keypoints(small, args.side)
    print(f"{len(small)} frames at {max(small[0].shape[:2])} px; MediaPipe: {time.perf_counter() - started:.1f} s")
    first = None
    for workers in (int(count) for count in args.workers.split(",")):
        started = time.perf_counter()
        masks, _ = screened_masks(small, keypoints, source.fps or DEFAULT_FPS, workers=workers)
        seconds = time.perf_counter() - started
        if first is None:
            first = (seconds, masks)
        same = all(np.array_equal(a, b) for a, b in zip(first[1], masks))
        print(f"workers {workers}: {seconds:.1f} s, {seconds / len(small):.2f} s per frame, "
              f"{first[0] / seconds:.2f}x the first count's speed, masks the same: {same}", flush=True)


if __name__ == "__main__":
    main()
