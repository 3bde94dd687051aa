"""Worker jobs: `harp` commands run by the engine's Python in a process of their own, so that
Blender never waits for them. Plain Python, no bpy: the interface polls a Job from a timer
(tests call the same functions directly).

A Job runs its commands one after the other (e.g. `harp init`, then `harp fit`), reads their
output as it comes (`--progress jsonl` lines become progress events, other lines log lines),
keeps the last lines of their error output for the interface, and can be cancelled: the fit
catches the interrupt, saves its checkpoint and stops, and a resumed fit goes on from there.
"""
from __future__ import annotations

import collections
import dataclasses
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time

LOG_LINES = 200             # lines kept for the panel
ERROR_LINES = 12            # last lines of the worker's error output shown on a failure
CANCEL_GRACE_SECONDS = 60   # how long a cancelled worker may take to save its checkpoint before it is killed
RESIGNAL_SECONDS = 1.0      # a worker that has said nothing yet is sent the interrupt again this often (one sent
#                             while it was still starting can be lost, and there is nothing to save yet)


@dataclasses.dataclass
class ProgressEvent:
    kind: str                      # "progress" or "log"
    message: str = ""
    stage: str | None = None
    step: int | None = None
    loss: float | None = None
    done: int | None = None
    total: int | None = None
    seconds_left: float | None = None
    stage_number: int | None = None    # the stage's place among the fit's stages (from 1), and their count
    stage_count: int | None = None


def parse_progress_line(line):
    """A ProgressEvent from one output line of a worker: `--progress jsonl` events, any other
    text a log line; None for a blank line."""
    text = line.strip()
    if not text:
        return None
    if text.startswith("{"):
        try:
            entry = json.loads(text)
        except json.JSONDecodeError:
            return ProgressEvent("log", text)
        if entry.get("event") == "progress":
            return ProgressEvent("progress", stage=entry.get("stage"), step=entry.get("step"), loss=entry.get("loss"),
                                 done=entry.get("done"), total=entry.get("total"),
                                 seconds_left=entry.get("seconds_left"), stage_number=entry.get("stage_number"),
                                 stage_count=entry.get("stage_count"))
        return ProgressEvent("log", str(entry.get("message", text)))
    return ProgressEvent("log", text)


class Job:
    """Commands (lists of arguments) run one after the other in worker processes."""

    def __init__(self, commands, label="job", env=None):
        self.commands, self.label = [list(c) for c in commands], label
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.state = "waiting"            # waiting, running, finished, failed, cancelled
        self.command_index = -1
        self.process = None
        self.log = collections.deque(maxlen=LOG_LINES)
        self.errors = collections.deque(maxlen=ERROR_LINES)
        self.progress = None              # the latest progress event
        self.returncode = None
        self._lines = queue.Queue()
        self._readers = []
        self._cancel_requested = False
        self._cancelled_at = self._signalled_at = None
        self._heard = False               # any output from the current command yet
        self.started = None

    # ------------------------------------------------------------------ control
    def start(self):
        """Start the first command; returns self. A command that cannot start fails the job."""
        self.started = time.time()
        self._next_command()
        return self

    def cancel(self):
        """Ask the worker to stop: an interrupt, which makes a fit save its checkpoint first. A
        worker still starting is interrupted again until it stops or speaks; one that has not
        stopped CANCEL_GRACE_SECONDS later is killed (poll does both)."""
        self._cancel_requested = True
        self._cancelled_at = time.time()
        self._interrupt()

    def _interrupt(self):
        if self.process is not None and self.process.poll() is None:
            self._signalled_at = time.time()
            if sys.platform == "win32":
                self.process.send_signal(signal.CTRL_BREAK_EVENT)
            else:
                self.process.send_signal(signal.SIGINT)

    def _follow_up_cancel(self):
        now = time.time()
        if now - self._cancelled_at > CANCEL_GRACE_SECONDS:
            self.kill()
        elif not self._heard and (self._signalled_at is None or now - self._signalled_at > RESIGNAL_SECONDS):
            self._interrupt()

    def kill(self):
        if self.process is not None and self.process.poll() is None:
            self.process.kill()

    @property
    def active(self):
        return self.state in ("waiting", "running")

    def poll(self):
        """Read what the worker wrote since the last call and move the job on; returns the new
        ProgressEvents. Never blocks."""
        events = []
        while True:
            try:
                stream, line = self._lines.get_nowait()
            except queue.Empty:
                break
            self._heard = True
            if stream == "stderr":
                if line.strip():
                    self.errors.append(line.rstrip())
                continue
            event = parse_progress_line(line)
            if event is None:
                continue
            events.append(event)
            if event.kind == "progress":
                self.progress = event
            else:
                self.log.append(event.message)
        if self.state == "running" and self._cancel_requested and self.process.poll() is None:
            self._follow_up_cancel()
        if self.state == "running" and self.process.poll() is not None and not any(r.is_alive() for r in self._readers):
            if self._lines.empty():
                self._command_ended(self.process.returncode)
        return events

    def wait(self, timeout=None, interval=0.05):
        """Poll until the job is over (for tests and scripts); returns its state."""
        deadline = None if timeout is None else time.time() + timeout
        while self.active and (deadline is None or time.time() < deadline):
            self.poll()
            time.sleep(interval)
        self.poll()
        return self.state

    # ------------------------------------------------------------------ what the panel shows
    @property
    def fraction(self):
        if self.progress is None or not self.progress.total:
            return 0.0
        return min(1.0, self.progress.done / self.progress.total)

    def status_line(self):
        if self.state == "failed":
            return f"{self.label} failed: {self.errors[-1] if self.errors else f'exit status {self.returncode}'}"
        if self.state == "cancelled":
            return f"{self.label} cancelled"
        if self.state == "finished":
            return f"{self.label} finished"
        if self.progress is not None:
            p = self.progress
            loss = f", loss {p.loss:.4f}" if p.loss is not None else ""
            left = f", {_duration(p.seconds_left)} left" if p.seconds_left is not None else ""
            stage = p.stage if p.stage_number is None else f"stage {p.stage_number}/{p.stage_count}: {p.stage}"
            return f"{stage}: step {p.done}/{p.total}{loss}{left}"
        return f"{self.label}: {self.log[-1] if self.log else 'starting'}"

    # ------------------------------------------------------------------ internals
    def _next_command(self):
        self.command_index += 1
        self._heard = False
        if self.command_index >= len(self.commands):
            self.state = "finished"
            return
        flags = subprocess.CREATE_NEW_PROCESS_GROUP if sys.platform == "win32" else 0
        try:
            self.process = subprocess.Popen(self.commands[self.command_index], stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True, bufsize=1, env=self.env,
                                            creationflags=flags, start_new_session=sys.platform != "win32")
        except OSError as error:
            self.errors.append(f"cannot start {self.commands[self.command_index][0]}: {error.strerror or error}")
            self.state, self.returncode = "failed", None
            return
        self.state = "running"
        self._readers = [threading.Thread(target=self._read, args=(stream, name), daemon=True)
                         for stream, name in ((self.process.stdout, "stdout"), (self.process.stderr, "stderr"))]
        for reader in self._readers:
            reader.start()

    def _read(self, stream, name):
        for line in stream:
            self._lines.put((name, line))
        stream.close()

    def _command_ended(self, returncode):
        self.returncode = returncode
        if self._cancel_requested:
            self.state = "cancelled"
        elif returncode != 0:
            self.state = "failed"
        else:
            self._next_command()


def _duration(seconds):
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 else \
        f"{seconds // 60}:{seconds % 60:02d}"
