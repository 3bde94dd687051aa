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
    """Counts steps towards `total`; `kind` is "bar", "jsonl" or "none"."""

    def __init__(self, kind, total):
        self.kind, self.total, self.done, self.start = kind, total, 0, time.time()
        self.bar = None
        if kind == "bar":
            from tqdm import tqdm
            self.bar = tqdm(total=total, unit="step", dynamic_ncols=True)

    def update(self, stage, step, loss):
        self.done += 1
        elapsed = time.time() - self.start
        left = elapsed / self.done * (self.total - self.done)
        if self.bar is not None:
            self.bar.set_description(stage)
            self.bar.set_postfix(loss=f"{loss:.4f}")
            self.bar.update(1)
        elif self.kind == "jsonl" and (self.done % 10 == 0 or self.done == self.total):
            finite = loss if math.isfinite(loss) else None
            print(json.dumps({"event": "progress", "stage": stage, "step": step, "loss": finite, "done": self.done,
                              "total": self.total, "seconds_left": round(left, 1)}), flush=True)

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
