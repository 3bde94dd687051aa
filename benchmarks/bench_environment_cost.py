"""What the environment light costs a fit: seconds per step of the joint stage (geometry +
appearance, the shaded render) and seconds of the final albedo solve, with the light and
without it, on a sequence folder with an init.npz (`fast`'s settings, one thread; run it alone).

    .venv/bin/python benchmarks/bench_environment_cost.py SEQ [--steps 10]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.fit.albedo_solve import solve_avatar_albedo  # noqa: E402
from pipeline.fit.checkpoint import FitState  # noqa: E402
from pipeline.fit.frames import select_frames  # noqa: E402
from pipeline.fit.problem import build_problem  # noqa: E402
from pipeline.fit.schedule import Schedule, StageKind, StageSpec  # noqa: E402
from pipeline.fit.settings import settings_for  # noqa: E402
from pipeline.fit.stage_run import StageRun  # noqa: E402
from pipeline.formats.initial_estimate import read_initial_estimate  # noqa: E402
from pipeline.formats.sequence_folder import validate_sequence_folder  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--steps", type=int, default=10)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    info = validate_sequence_folder(args.sequence)
    count = read_initial_estimate(args.sequence).frame_count
    for environment in ("off", "on"):
        settings = settings_for("fast", count, image_size=max(info.width, info.height), environment=environment)
        frames = select_frames(count, settings.max_frames, exclude=np.array([], dtype=np.int64))
        problem = build_problem(args.sequence, settings, frames, "cpu")
        schedule = Schedule((StageSpec(StageKind.JOINT, args.steps + 2),))
        state = FitState.fresh(schedule, "off")
        run = StageRun(problem, schedule[0], state, torch.Generator().manual_seed(0))
        run.step(), run.step()                      # warm up
        started = time.perf_counter()
        for _ in range(args.steps):
            run.step()
        step_seconds = (time.perf_counter() - started) / args.steps
        if environment == "on":     # a light to solve, as a fit's stages leave one
            with torch.no_grad():
                problem.avatar.environment.normal_(0.0, 0.02, generator=torch.Generator().manual_seed(0))
        started = time.perf_counter()
        solve_avatar_albedo(dataclasses.replace(problem), False)
        solve_seconds = time.perf_counter() - started
        print(f"environment {environment:3s}: {len(frames)} frames at {max(problem.clip.images.shape[1:3])} px, "
              f"joint step {step_seconds:.3f} s (batch {settings.batch_size}), albedo solve {solve_seconds:.1f} s",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
