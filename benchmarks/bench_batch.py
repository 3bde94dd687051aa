"""Clips per hour through `harp batch` at several numbers of clips at once (issue 32: the local
executor's default, justified by measurement). Run it alone on the machine.

    .venv/bin/python benchmarks/bench_batch.py CLIP... --out DIR [--jobs 1,2] [--preset fast]
        [--init mediapipe|gt-noise] [--executor local|ray] [--kill-a-worker]

Each setting runs the same clips into DIR/jobsN/ (a fresh batch each time) and prints its wall
time, clips per hour and the figures of each clip (which must not depend on the setting: each
clip is fitted by one single-threaded process either way). Writes DIR/bench_batch.json.

`--kill-a-worker` (with `--executor ray`): once the first clip's fit has written its checkpoint, one
Ray worker running a clip is killed (SIGKILL), as a lost process or node would be; the batch must
still finish every clip, the killed one with 2 attempts and its fit resumed from the checkpoint.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clips", nargs="+", help="videos or sequence folders")
    parser.add_argument("--out", required=True)
    parser.add_argument("--jobs", default="1,2", help="comma-separated numbers of clips at once (default 1,2)")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--init", default="mediapipe", choices=("mediapipe", "gt-noise"))
    parser.add_argument("--executor", default="local", choices=("local", "ray"))
    parser.add_argument("--hold-out-every", type=int, default=5)
    parser.add_argument("--kill-a-worker", action="store_true",
                        help="ray: kill one worker mid-fit, once a fit has written its checkpoint")
    args = parser.parse_args(argv)
    if args.kill_a_worker and args.executor != "ray":
        parser.error("--kill-a-worker needs --executor ray")

    from pipeline.batch import run_batch
    from pipeline.threads import configure_threads

    configure_threads(1)
    out = Path(args.out)
    results = {}
    for jobs in (int(j) for j in args.jobs.split(",")):
        folder = out / f"jobs{jobs}"
        shutil.rmtree(folder, ignore_errors=True)
        killed = []
        if args.kill_a_worker:
            threading.Thread(target=_kill_a_worker, args=(folder, killed), daemon=True).start()
        start = time.perf_counter()
        table = run_batch([(clip, None) for clip in args.clips], folder, executor=args.executor, jobs=jobs,
                          threads=1, preset=args.preset, init=args.init, hold_out_every=args.hold_out_every,
                          progress="none", log=lambda message: None)
        wall = time.perf_counter() - start
        done = sum(row["status"] == "done" for row in table)
        results[jobs] = {"wall_seconds": wall, "clips": len(table), "done": done,
                         "clips_per_hour": done / wall * 3600, "rows": table, "killed": killed}
        for note in killed:
            print(f"  killed {note}", flush=True)
        print(f"{jobs} at once ({args.executor}): {done} of {len(table)} clips in {wall / 60:.1f} min, "
              f"{done / wall * 3600:.1f} clips per hour", flush=True)
        for row in table:
            print(f"  {row['clip']}: {row['status']}, held out {row.get('held_out_psnr') or float('nan'):.2f} dB, "
                  f"fit {row.get('fit_s') or 0:.0f} s, evaluate {row.get('evaluate_s') or 0:.0f} s, "
                  f"attempts {row.get('attempts')}", flush=True)
    (out / "bench_batch.json").write_text(json.dumps(results, indent=1))
    return 0


def _kill_a_worker(folder, killed, timeout=3600):
    """Wait for a fit's checkpoint in the batch `folder`, then SIGKILL one process that runs a Ray
    cell (its title is `ray::_ray_cell`); what was killed goes into `killed`."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        checkpoints = sorted(Path(folder).glob("*/avatar/checkpoint.pt"))
        if checkpoints:
            for pid in sorted(int(p) for p in os.listdir("/proc") if p.isdigit()):
                try:
                    command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
                except OSError:
                    continue
                if command.startswith("ray::_ray_cell"):
                    os.kill(pid, signal.SIGKILL)
                    killed.append(f"process {pid} ({command.strip()}) after {checkpoints[0]} was written")
                    return
        time.sleep(1.0)


if __name__ == "__main__":
    sys.exit(main())
