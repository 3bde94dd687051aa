"""Benchmark: the estimate's cost of the work after the stages against finished fits.

    .venv/bin/python benchmarks/bench_after_stages.py FIT...

For each finished fit folder, one JSON line: what the work after the stages took (report.json's
`after_stages_seconds` by part, summed, with `output_seconds`), what the fit's own estimate
costed it at (the code it ran), what the rule before 2026-11-27 costs it at (6.5 appearance steps
per batch of fitted frames) and what today's `estimate.after_stages_seconds` costs it at, both from
the same fit's measured step costs and its settings (the checkpoint's). The table in
docs/performance.md ("The work after the stages, costed from its parts") comes from this script.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint  # noqa: E402
from pipeline.fit.estimate import after_stages_seconds  # noqa: E402
from pipeline.fit.schedule import StageKind, StepKind  # noqa: E402

OLD_RULE_STEPS = 6.5    # appearance steps per batch of fitted frames: the estimate's rule until 2026-11-27


def after_stages_figures(folder: Path) -> dict:
    report = json.loads((folder / "report.json").read_text())
    saved = load_checkpoint(folder / CHECKPOINT_FILE)
    steps = report["estimate"]["step_seconds"]
    joint = StepKind(StageKind.JOINT)
    frame_count = len(saved.avatar["exposure"])      # one row of gains per fitted frame
    costed_now = after_stages_seconds({joint: steps[str(joint)]}, saved.settings, frame_count)
    return {"fit": str(folder), "frames": frame_count, "solve_resolution": saved.settings.solve_resolution,
            "measured": round(sum(report["after_stages_seconds"].values()) + report["output_seconds"], 1),
            "costed_by_the_fit": report["estimate"]["after_stages_seconds"],
            "costed_by_the_old_rule": round(OLD_RULE_STEPS * steps["appearance"] * frame_count
                                            / saved.settings.batch_size, 1),
            "costed_now": round(costed_now, 1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("fits", nargs="+", type=Path, help="finished fit folders")
    for folder in parser.parse_args().fits:
        if not (folder / "report.json").is_file() or not (folder / CHECKPOINT_FILE).is_file():
            sys.exit(f"{folder} is not a finished fit folder (no report.json or {CHECKPOINT_FILE})")
        print(json.dumps(after_stages_figures(folder)))


if __name__ == "__main__":
    main()
