"""Benchmark: the albedo solve's cost on a finished fit (fit/albedo_solve.py).

    .venv/bin/python benchmarks/bench_albedo_solve.py FIT SEQ [--threads 2] [--rounds 3]

The fit's problem is built again (its frames, geometry, poses and light as fitted) and timed:
gathering the observations (rendering the fitted frames), gathering the normal equations once
(the solve does so 4 times, 8 with an environment light) the way the solve does and the way it
did before (an index_add_ per texel pair and channel, kept here as the reference: both must
give the same system), and the whole solve. Medians of --rounds; one JSON line.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import torch  # noqa: E402

from albedo_ceiling import problem_at  # noqa: E402
from pipeline.fit import albedo_solve  # noqa: E402


def per_pair_gather(size, seen, pixel_weight):
    """(matrix (3, T*T*9), rhs (3, T*T)): the normal equations gathered as the solve did before
    (an index_add_ of a transposed (N, 3) source per texel pair)."""
    stencil = len(albedo_solve.STENCIL)
    matrix = torch.zeros(3, size * size * stencil, dtype=seen.shading.dtype)
    rhs = torch.zeros(3, size * size, dtype=seen.shading.dtype)
    rows, columns = seen.texels // size, seen.texels % size
    weighted = seen.shading * pixel_weight[:, None]
    for i in range(4):
        texel = seen.texels[:, i]
        rhs.index_add_(1, texel, (weighted * seen.colour * seen.weights[:, i, None]).t())
        for j in range(4):
            place = (rows[:, j] - rows[:, i] + 1) * 3 + (columns[:, j] - columns[:, i] + 1)
            pair = (seen.weights[:, i] * seen.weights[:, j])[:, None]
            matrix.index_add_(1, texel * stencil + place, (weighted * seen.shading * pair).t())
    return matrix, rhs


def timed(function, rounds):
    times, result = [], None
    for _ in range(rounds):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    problem, shadows = problem_at(args.fit, args.sequence, None)
    size = problem.avatar.albedo.shape[-1]
    with torch.no_grad():
        gather_seconds, seen = timed(lambda: albedo_solve._observations(problem, shadows, albedo_solve.SOLVE_BATCH,
                                                                          size), args.rounds)
        weights = seen.pixel_weights()
        now_seconds, now = timed(lambda: albedo_solve._NormalEquations(size, seen, weights), args.rounds)
        before_seconds, (matrix, rhs) = timed(lambda: per_pair_gather(size, seen, weights), args.rounds)
        solve_seconds, _ = timed(lambda: albedo_solve.solved_albedo(problem, shadows), args.rounds)
    scale = float(matrix.abs().max())
    print(json.dumps({
        "fit": args.fit, "frames": len(problem.frames), "pixels": len(seen.colour), "texture": size,
        "threads": args.threads, "environment": seen.basis is not None,
        "observations_s": round(gather_seconds, 3),
        "normal_equations_s": round(now_seconds, 3), "normal_equations_before_s": round(before_seconds, 3),
        "speed_up": round(before_seconds / now_seconds, 2),
        "largest_difference": float((now.matrix - matrix).abs().max()) / scale
        + float((now.rhs - rhs).abs().max()) / float(rhs.abs().max()),
        "whole_solve_s": round(solve_seconds, 3)}))


if __name__ == "__main__":
    main()
