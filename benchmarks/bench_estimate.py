"""Benchmark: the fit's printed time estimate and its time left against the truth.

    .venv/bin/python benchmarks/bench_estimate.py SEQ [--presets fast,full] [--work DIR]
                     [--max-frames N] [--budget TIME] [--threads N]

Fits SEQ with each preset as `harp fit` does (or reads a finished fit already in DIR/P) and
prints, from its report.json: the estimate printed before the stages, the true time from then
to the end of the outputs, their ratio, and the worst error of the progress bar's time left
after the first minute while a minute or more is left (the speed issue's targets: within 25%
both). The traces go to
DIR/bench_estimate.json and a plot (estimated against true time left) to DIR/bench_estimate.png.
Run it alone: a second busy process changes the truth while the fit runs.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SETTLED_SECONDS = 60.0


def fitted(sequence, out, preset, **options):
    """report.json of a fit (run unless it has finished before)."""
    if not (out / "report.json").is_file():
        from pipeline.fit import fit

        fit(sequence, out, preset=preset, progress="none", **options)
    return json.loads((out / "report.json").read_text())


def figures(report):
    """The estimate against the truth, from a report's "estimate" (estimate.FitEstimate.report)."""
    estimate = report["estimate"]
    true_seconds = estimate["seconds_before_outputs"] + report["output_seconds"]
    trace = [(elapsed, left, true_seconds - elapsed) for elapsed, left in estimate["time_left"]]
    # after the first minute, while at least a minute is left (a few seconds off near the end
    # are a large share of what is left, and no one reads the bar then)
    settled = [(left, truth) for elapsed, left, truth in trace if elapsed >= SETTLED_SECONDS and truth >= SETTLED_SECONDS]
    errors = [abs(left - truth) / truth for left, truth in settled]
    return {"expected_seconds": estimate["expected_seconds"], "true_seconds": round(true_seconds, 1),
            "expected_over_true": round(estimate["expected_seconds"] / true_seconds, 3),
            "calibration_seconds": estimate["calibration_seconds"],
            "worst_time_left_error_after_first_minute": round(max(errors), 3) if errors else None,
            "worst_time_left_error_seconds": round(max(abs(left - truth) for left, truth in settled), 1) if settled else None,
            "trace": trace}


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6, 4))
    for preset, result in results.items():
        elapsed, left, truth = zip(*result["trace"])
        line, = axis.plot(elapsed, left, label=f"{preset}: estimated")
        axis.plot(elapsed, truth, "--", color=line.get_color(), label=f"{preset}: true")
    axis.axvline(SETTLED_SECONDS, color="grey", linewidth=0.5)
    axis.set_xlabel("seconds into the fit")
    axis.set_ylabel("seconds left")
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence")
    parser.add_argument("--presets", default="fast,full")
    parser.add_argument("--work", default="bench_estimate_work")
    parser.add_argument("--max-frames", type=int, help="fit at most this many frames (spread evenly)")
    parser.add_argument("--budget", help="as harp fit --budget")
    parser.add_argument("--threads", type=int)
    args = parser.parse_args()
    from pipeline.threads import configure_threads

    configure_threads(args.threads)     # before torch is imported
    from pipeline.fit.budget import parse_budget

    options = {"max_frames": args.max_frames, "budget_seconds": parse_budget(args.budget) if args.budget else None}
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    for preset in args.presets.split(","):
        results[preset] = figures(fitted(Path(args.sequence).resolve(), work / preset, preset, **options))
        shown = {k: v for k, v in results[preset].items() if k != "trace"}
        print(json.dumps({"preset": preset, **shown}), flush=True)
    (work / "bench_estimate.json").write_text(json.dumps(results, indent=1))
    plot(results, work / "bench_estimate.png")


if __name__ == "__main__":
    main()
