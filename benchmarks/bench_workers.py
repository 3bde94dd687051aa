"""Benchmark: both cores at work. Seconds per step of each kind of a `fast` fit with one process
and one thread, one process and two threads, and two single-threaded processes that share each
batch (batch workers, pipeline/fit/batch_workers.py). Run it with the machine otherwise idle.

    .venv/bin/python benchmarks/bench_workers.py SEQ [--preset fast] [--steps 8] [--max-frames 150]

Prints a table: per kind of step, the median seconds of each setting and the speed-up of the
two processes over one thread.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.fit import fitting  # noqa: E402
from pipeline.fit.checkpoint import FitState  # noqa: E402
from pipeline.fit.stage_run import StageRun  # noqa: E402

SETTINGS = (("1 process, 1 thread", 1, 1), ("1 process, 2 threads", 1, 2), ("2 processes, 1 thread each", 2, 1))


def step_seconds(setup, steps):
    """{stage name: median seconds per step} over `steps` steps of each stage after a warm-up."""
    problem = setup.problem
    schedule = problem.settings.schedule()
    saved = {name: value.clone() for name, value in problem.avatar.state_dict().items()}
    result = {}
    for stage in schedule:
        state = FitState.fresh(schedule, "off")
        run = StageRun(problem, stage, state, torch.Generator().manual_seed(0))
        if not run.has_work:
            continue
        run.step()
        durations = []
        for _ in range(steps):
            begin = time.perf_counter()
            run.step()
            durations.append(time.perf_counter() - begin)
        result[stage.name] = statistics.median(durations)
        problem.avatar.load_state_dict(saved)
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--max-frames", type=int, default=150)
    parser.add_argument("--preset", default="fast")
    args = parser.parse_args()
    setup = fitting._set_up(args.sequence, fitting.FitJob(preset=args.preset, device="cpu"),
                            {"max_frames": args.max_frames, "shadows": "off", "validation_frames": 0})
    table = {}
    for label, workers, threads in SETTINGS:
        torch.set_num_threads(threads)
        with fitting._batch_workers(setup.problem, setup.recipe, workers):
            table[label] = step_seconds(setup, args.steps)
    torch.set_num_threads(1)
    labels = [label for label, _, _ in SETTINGS]
    print(f"preset {args.preset}: {len(setup.problem.frames)} frames at {setup.problem.clip.width} px, batches of "
          f"{setup.problem.settings.batch_size}; seconds per step (median of {args.steps})")
    print("| step | " + " | ".join(labels) + " | 2 processes against 1 thread |")
    print("|---" * (len(labels) + 2) + "|")
    for name in table[labels[0]]:
        values = [table[label][name] for label in labels]
        print(f"| {name} | " + " | ".join(f"{value:.3f}" for value in values) + f" | {values[0] / values[2]:.2f}x |")


if __name__ == "__main__":
    main()
