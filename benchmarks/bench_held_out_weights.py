"""Finished fits scored on their held-out frames with the keypoint anchor's held-out weight at
several factors of its default 10 (pipeline/fit/energy_terms.py), under both protocols: the
figures that chose the factor (docs/fit.md, "Held-out frames").

    .venv/bin/python benchmarks/bench_held_out_weights.py FIT SEQ [FIT SEQ ...] [--factors 1,0.1]
        [--keypoint-steps 100] [--threads 2]

FIT is a folder `harp fit --hold-out-every N` wrote, SEQ its sequence folder. Prints per fit,
factor and protocol: PSNR in the mask before and after the refinement, silhouette IoU, L1 and
the steps taken. The steps are `harp evaluate`'s: the neighbours protocol until its loss stops
falling (at most 300), the keypoints protocol KEYPOINT_PROTOCOL_STEPS unless --keypoint-steps.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.evaluate.held_out import KEYPOINT_PROTOCOL_STEPS, PROTOCOLS, evaluate_held_out  # noqa: E402

TERM = "keypoint_anchor"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="+", help="FIT SEQ pairs")
    parser.add_argument("--factors", default="1,0.1", help="the anchor's held-out factors to compare")
    parser.add_argument("--keypoint-steps", type=int, default=KEYPOINT_PROTOCOL_STEPS)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    if len(args.pairs) % 2:
        parser.error("give the fits and their sequences in pairs: FIT SEQ [FIT SEQ ...]")
    torch.set_num_threads(args.threads)
    factors = [float(value) for value in args.factors.split(",")]
    for fit_folder, sequence in zip(args.pairs[::2], args.pairs[1::2]):
        print(f"== {fit_folder}", flush=True)
        for factor in factors:
            for protocol in PROTOCOLS:
                steps = args.keypoint_steps if protocol == "keypoints" else 300
                result = evaluate_held_out(fit_folder, sequence, steps=steps, protocol=protocol,
                                           stage_factors={TERM: {"held-out": factor}})
                before, after = result.metrics_before, result.metrics
                print(f"anchor x{factor:g} ({10 * factor:g}), {protocol}: PSNR {before['psnr_mean']:.2f} -> "
                      f"{after['psnr_mean']:.2f} dB, IoU {after['silhouette_iou_mean']:.3f}, "
                      f"L1 {after['l1_mean']:.4f}, {len(result.history)} steps", flush=True)


if __name__ == "__main__":
    main()
