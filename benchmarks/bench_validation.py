"""Benchmark: what validation inside the fit costs (pipeline/fit/validation.py): one check
against one joint step of the fit, timed alternately in one process (the ratio holds on a
machine that is busy with other work; the seconds do not), and the checks a `fast` fit takes.

    .venv/bin/python benchmarks/bench_validation.py SEQ [--validation-frames 6] [--repeats 5]

Prints the median seconds of a joint step and of a check, their ratio, the checks of a `fast`
fit of the clip and what they add to its joint and appearance stages' steps.
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
from pipeline.fit.schedule import StageKind  # noqa: E402
from pipeline.fit.stage_run import StageRun  # noqa: E402
from pipeline.fit.validation import Validator  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--validation-frames", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    job = fitting.FitJob(device="cpu")
    setup = fitting._set_up(args.sequence, job, {"validation_frames": args.validation_frames})
    problem, frames = setup.problem, setup.validation
    if not len(frames):
        sys.exit(f"{args.sequence}: too few frames for {args.validation_frames} validation frames")
    validator = Validator(problem, frames)
    schedule = problem.settings.schedule()
    joint = next(stage for stage in schedule if stage.kind is StageKind.JOINT)
    state = FitState.fresh(schedule, "off")
    state.stage = list(schedule).index(joint)
    run = StageRun(problem, joint, state, torch.Generator().manual_seed(0))
    steps, checks = [], []
    run.step()
    validator.score(False)      # warm-up of both
    for _ in range(args.repeats):
        begin = time.perf_counter()
        for _ in range(5):
            run.step()
        steps.append((time.perf_counter() - begin) / 5)
        begin = time.perf_counter()
        validator.score(False)
        checks.append(time.perf_counter() - begin)
    step, check = statistics.median(steps), statistics.median(checks)
    state.stage, state.step = list(schedule).index(joint), 0
    count = validator.checks_left(state)
    appearance_steps = sum(stage.steps for stage in schedule if stage.kind in (StageKind.JOINT, StageKind.APPEARANCE))
    print(f"{len(problem.frames)} frames fitted at {problem.clip.width} px, {len(frames)} kept out: a joint step "
          f"{step:.3f} s, a check {check:.2f} s ({check / step:.1f} steps); {count} checks in a fast fit: "
          f"{count * check:.0f} s, {100 * count * check / (appearance_steps * step):.0f}% of its joint and appearance "
          "stages' steps")


if __name__ == "__main__":
    main()
