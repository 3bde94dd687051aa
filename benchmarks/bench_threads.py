"""Benchmark: a fit alone and two fits side by side, for a choice of thread settings.

    .venv/bin/python benchmarks/bench_threads.py SEQ [--work DIR] [--max-steps 40]
                     [--settings default,torch] [--preset fast]

Each setting runs `harp fit SEQ --max-steps N --no-solve-albedo` once alone and then twice at
the same time (not pinned: the operating system places them), and prints the wall times and
the slowdown of the pair against the lone fit (the speed issue's target: at most 2.3x).

default   what `harp fit` does without --threads: half the cores, OpenMP waiting passively.
torch     torch's own default: a thread per core, spinning OpenMP threads.
N         --threads N with passive waiting (e.g. 1, 2).
Figures go to stdout and DIR/bench_threads.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def command(sequence, out, setting, max_steps, preset):
    """(argv, environment) of one fit under a setting."""
    argv = [sys.executable, "-m", "pipeline.cli", "fit", str(sequence), "--out", str(out), "--preset", preset,
            "--max-steps", str(max_steps), "--progress", "none", "--no-solve-albedo"]
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    if setting == "torch":
        argv += ["--threads", str(os.cpu_count() or 1)]
        env["OMP_WAIT_POLICY"] = "ACTIVE"
    elif setting != "default":
        argv += ["--threads", setting]
    return argv, env


def run_together(jobs, cwd):
    """Wall seconds of each job when all start at once."""
    started = time.perf_counter()
    processes = [subprocess.Popen(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for argv, env in jobs]
    seconds = []
    for process in processes:
        _, error = process.communicate()
        if process.returncode:
            raise SystemExit(f"a fit failed: {error.strip().splitlines()[-1] if error.strip() else process.returncode}")
        seconds.append(time.perf_counter() - started)
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence")
    parser.add_argument("--work", default="bench_threads_work")
    parser.add_argument("--max-steps", type=int, default=40)
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--settings", default="default,torch")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    for setting in args.settings.split(","):
        alone = run_together([command(args.sequence, work / f"{setting}_alone", setting, args.max_steps,
                                      args.preset)], ROOT)[0]
        pair = run_together([command(args.sequence, work / f"{setting}_pair{k}", setting, args.max_steps, args.preset)
                             for k in range(2)], ROOT)
        results[setting] = {"alone_s": alone, "pair_s": pair, "slowdown": max(pair) / alone}
        print(f"{setting:>8}: alone {alone:.1f} s, two side by side {max(pair):.1f} s "
              f"({max(pair) / alone:.2f}x)", flush=True)
    (work / "bench_threads.json").write_text(json.dumps({"sequence": str(args.sequence), "max_steps": args.max_steps,
                                                         "preset": args.preset, "cpus": os.cpu_count(),
                                                         "results": results}, indent=1))


if __name__ == "__main__":
    main()
