"""report.json: what a finished fit reports (numpy-free: JSON and the standard library; one home
of the format). Written by `harp fit` into the avatar folder, read by `harp evaluate`, the
study and the Blender add-on.

    sequence, frames (sequence indices fitted), held_out_frames (if any), preset,
    stage_seconds {stage: s}, total_seconds (the stages' seconds), measure_seconds (the anytime
    curve's measuring, not fit time), output_seconds, wall_seconds (the whole run in its process,
    setting up, the work after the stages and the outputs included, measuring left out; absent
    in reports from before it),
    final_losses {stage: {loss, terms...}}, metrics (per-frame and mean image scores),
    shadows, events, perceptual_term, ambient, light_position, appearance
"""
from __future__ import annotations

import json
from pathlib import Path

REPORT_FILE = "report.json"
HELD_OUT_FRAMES = "held_out_frames"   # sequence frames the fit left out for evaluation


class FitReportError(ValueError):
    """No readable report.json (one-line message)."""


def write_report(folder, report: dict) -> Path:
    path = Path(folder) / REPORT_FILE
    path.write_text(json.dumps(report, indent=2))
    return path


def read_report(folder) -> dict:
    """report.json of a finished fit."""
    path = Path(folder) / REPORT_FILE
    if not path.is_file():
        raise FitReportError(f"not a finished fit (no {REPORT_FILE}): {Path(folder)}")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise FitReportError(f"cannot read {path}: {error}") from None
