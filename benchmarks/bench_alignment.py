"""Benchmark: the alignment alone at several silhouette sizes (FitSettings.align_downscale).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_alignment.py SEQ... --downscales 1 2 3 4 \\
        --out /tmp/bench_alignment

For each synthetic sequence and factor, `fast`'s alignment stage is run alone (`fit` with no
steps in the three stages after it, no albedo solve, no light search, environment light and
specular lobe off: the work after the stages reduced to writing the outputs), then scored as
benchmarks/score_fits.py scores a fit: the mean and least silhouette IoU of its fitted frames
at the working size (the report's, on the subdivided mesh, so not at the alignment's own size),
and the Procrustes joint and vertex errors against gt.npz. One JSON line per fit, with the
alignment's seconds (the report's stage time: one torch thread when OMP_NUM_THREADS=1). The
figures in docs/performance.md ("`fast` on one core, 150 frames, today") come from this script.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pipeline.evaluate.poses import PoseScorer  # noqa: E402
from pipeline.fit.fitting import fit  # noqa: E402
from score_fits import score  # noqa: E402


def aligned(sequence: Path, out: Path, downscale: int, resolution: int) -> dict:
    """The alignment of `sequence` at `downscale`, fitted into `out` (kept when already there), scored."""
    if not (out / "report.json").is_file():
        fit(sequence, out, preset="fast", progress="none", steps=(0, 0, 0), solve_albedo=False, align_downscale=downscale,
            light_search="off", environment="off", specular="off")
    report = json.loads((out / "report.json").read_text())
    scores = score(out, sequence, PoseScorer(sequence), resolution)
    ious = report["metrics"]["silhouette_iou"]
    return {"sequence": sequence.name, "downscale": downscale, "frames": len(report["frames"]),
            "align_seconds": round(report["stage_seconds"]["align"], 1),
            "iou_mean": round(float(np.mean(ious)), 4), "iou_least": round(float(np.min(ious)), 3),
            "joint_mm": scores["joint_mm"], "vertex_mm": scores["vertex_mm"]}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("--downscales", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path, required=True, help="folder of the fits (one per sequence and factor)")
    parser.add_argument("--resolution", type=int, default=256, help="the size the poses are scored at (fast's)")
    args = parser.parse_args()
    for sequence in args.sequences:
        for downscale in args.downscales:
            folder = args.out / f"{sequence.parent.name}_{sequence.name}_d{downscale}"
            print(json.dumps(aligned(sequence, folder, downscale, args.resolution)), flush=True)


if __name__ == "__main__":
    main()
