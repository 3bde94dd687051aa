"""Held-out frames: the frames a fit leaves out so that its avatar can be judged on frames it
never saw (HARP's appearance evaluation). The fit records them in report.json; evaluation.py
fits only pose and light on them, with the appearance frozen.

Rule: with `every` = N, frames N-1, 2N-1, 3N-1, ... (every N-th frame counting from one) are
held out, so the first frame always stays in the fit.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

REPORT_KEY = "held_out_frames"


def held_out_frames(count, every=None):
    """Sorted sequence frame indices (K,) held out of a fit of `count` frames (none if `every`
    is None or 0). Raises ValueError for every < 2, which would leave nothing to fit."""
    if not every:
        return np.zeros(0, dtype=np.int64)
    if int(every) < 2:
        raise ValueError(f"hold_out_every must be at least 2, got {every}")
    frames = np.arange(count)
    return frames[(frames + 1) % int(every) == 0]


def record_held_out(out, report, held_out):
    """Add the held-out frames to the fit's report (dict and out/report.json); returns it."""
    from .outputs import REPORT_FILE

    if len(held_out):
        report[REPORT_KEY] = [int(i) for i in held_out]
        (Path(out) / REPORT_FILE).write_text(json.dumps(report, indent=2))
    return report
