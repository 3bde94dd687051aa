"""Benchmark: the cost of a joint step (energy and its backward) with the displacements on the
subdivided mesh ("fine") and on the unsubdivided one ("coarse", the default), alternately.

    .venv/bin/python benchmarks/bench_displacement_grid.py SEQ [--frames 30] [--repeats 12]

Prints the median milliseconds of a `fast` joint step over 6 frames, per grid, twice each.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.fit.energy import batch_energy  # noqa: E402
from pipeline.fit.problem import build_problem  # noqa: E402
from pipeline.fit.schedule import StageKind, StageSpec  # noqa: E402
from pipeline.fit.settings import settings_for  # noqa: E402
from pipeline.formats.initial_estimate import read_initial_estimate  # noqa: E402


def step_milliseconds(sequence, grid, frames, repeats):
    count = read_initial_estimate(sequence).frame_count
    settings = settings_for("fast", count, displacement_grid=grid)
    problem = build_problem(sequence, settings, list(range(0, count, max(1, count // frames)))[:frames], "cpu")
    stage, batch = StageSpec(StageKind.JOINT, 1), torch.arange(6)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        total, _ = batch_energy(problem, stage, batch, False, torch.Generator().manual_seed(0))
        total.backward()
        times.append(time.perf_counter() - start)
    times = sorted(times[2:])            # the first two warm up
    return 1000 * times[len(times) // 2]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=12)
    args = parser.parse_args(argv)
    for grid in ("fine", "coarse", "fine", "coarse"):
        print(f"{grid}: {step_milliseconds(args.sequence, grid, args.frames, args.repeats):.1f} ms per joint step",
              flush=True)


if __name__ == "__main__":
    main()
