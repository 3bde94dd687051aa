"""Progress of a fit: tqdm on a terminal, JSON lines (for the Blender add-on), or nothing."""
from __future__ import annotations

import json
import math
import sys
import time


def progress_log(kind):
    """A log(message) function that speaks as Progress(kind).log does, outside any bar."""
    if kind == "none":
        return lambda message: None
    if kind == "jsonl":
        return lambda message: print(json.dumps({"event": "log", "message": message}), flush=True)
    return lambda message: print(message, file=sys.stderr, flush=True)


class Progress:
    """Counts steps towards `total`; `kind` is "bar", "jsonl" or "none". The time left is the
    caller's (a fit's stages cost differently: estimate.TimeLeft) or, without one, the steps
    left at the average rate so far."""

    def __init__(self, kind, total):
        self.kind, self.total, self.done, self.start = kind, total, 0, time.time()
        self.stage_number = self.stage_count = None
        self.bar = None
        if kind == "bar":
            from tqdm import tqdm
            self.bar = tqdm(total=total, unit="step", dynamic_ncols=True,
                            bar_format="{desc}{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")

    def enter_stage(self, number, count):
        """The steps that follow are stage `number` (from 1) of `count`."""
        self.stage_number, self.stage_count = number, count

    def update(self, stage, step, loss, seconds_left=None, steps_left=None):
        """One step done; `steps_left` (when given) replaces the total (a budget re-plans)."""
        self.done += 1
        if steps_left is not None and self.done + steps_left != self.total:
            self.total = self.done + steps_left
            if self.bar is not None:
                self.bar.total = self.total
        elapsed = time.time() - self.start
        left = seconds_left if seconds_left is not None else elapsed / self.done * (self.total - self.done)
        if self.bar is not None:
            self.bar.set_description(stage if self.stage_number is None else
                                     f"stage {self.stage_number}/{self.stage_count} {stage}")
            self.bar.set_postfix_str(f"{_clock(left)} left, loss {loss:.4f}", refresh=False)
            self.bar.update(1)
        elif self.kind == "jsonl" and (self.done % 10 == 0 or self.done == self.total):
            finite = loss if math.isfinite(loss) else None
            print(json.dumps({"event": "progress", "stage": stage, "step": step, "loss": finite, "done": self.done,
                              "total": self.total, "seconds_left": round(left, 1), "stage_number": self.stage_number,
                              "stage_count": self.stage_count}), flush=True)

    def extend(self, steps):
        """More steps than planned (a stage that found it needs them)."""
        self.total += steps
        if self.bar is not None:
            self.bar.total = self.total
            self.bar.refresh()

    def log(self, message):
        if self.kind == "jsonl":
            print(json.dumps({"event": "log", "message": message}), flush=True)
        elif self.bar is not None:
            self.bar.write(message)
        else:
            print(message, file=sys.stderr)

    def close(self):
        if self.bar is not None:
            self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def duration_text(seconds):
    """A duration as a log line gives it: "75 s", "6.2 min"."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def _clock(seconds):
    """H:MM:SS or M:SS."""
    seconds = max(0, int(round(seconds)))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"
