"""Independent units of work (cells: one clip's import, init, fit and evaluation in `harp batch`,
one clip and seed of `harp study`) run one after another here, several at once on this machine,
or as tasks on a Ray cluster.

- `local` with one job: in this process, in order.
- `local` with N jobs: a pool of N spawned processes, each with its own torch threads. Two fits of
  one thread each share a 2-core machine at 1.02x the time of one alone (docs/performance.md,
  "Threads"), where one fit with two threads gains 0-20%: single-threaded jobs, one per core, is
  the default (`default_jobs`).
- `ray`: each cell a Ray task reserving `threads` CPUs, retried when its worker dies (the cell
  then resumes from the checkpoints it left, where the node can see them). Cells whose `ship`
  names folders work in a scratch copy on the worker: those folders go to the task with it and
  come back to the driver when it ends, so no shared filesystem is needed (a cluster that has one
  may pass `ship="never"`). Ray is an optional extra (`pip install .[cluster]`).

A cell names the cells that must finish before it starts. A cell that fails is recorded with
its one-line reason and the others go on; run_cells then raises CellFailure naming every failure
(finished work stays on disk for a rerun).
"""
from __future__ import annotations

import dataclasses
import io
import multiprocessing
import os
import shutil
import tarfile
import tempfile
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable

EXECUTORS = ("local", "ray")
RAY_INSTALL = "Ray is not installed: `pip install .[cluster]` (or `bash tools/setup.sh --cluster`) adds it"
RAY_RETRIES = 3          # a task whose worker dies is run again this many times


class ExecutorError(ValueError):
    """An executor cannot be used as asked (one-line message)."""


@dataclasses.dataclass(frozen=True)
class Cell:
    """One unit of work: `function(**kwargs, log=...)`, a module-level function (it crosses to
    worker processes); `after` names the cells it needs finished first; `ship` names the kwargs
    that are folders the cell reads and writes (sent to a Ray worker and back where it has no
    shared filesystem)."""

    name: str
    function: Callable
    kwargs: dict
    after: tuple[str, ...] = ()
    ship: tuple[str, ...] = ()


class CellFailure(RuntimeError):
    """Cells that failed: {name: one-line reason}; `results` holds those that finished."""

    def __init__(self, failures: dict, results: dict | None = None):
        self.failures, self.results = failures, results or {}
        super().__init__("; ".join(f"{name}: {reason}" for name, reason in failures.items()))


def default_jobs(threads=1):
    """Cells at once on this machine: one per `threads` cores (at least one)."""
    from .threads import available_cores

    return max(1, available_cores() // max(1, threads))


def run_cells(cells, jobs=1, threads=None, log=print, logs=None, executor="local", address=None, ship="auto",
              on_result=None):
    """Run `cells`; returns {name: result}. `executor` "local": jobs == 1 here, in order (each
    cell's `after` before it); jobs > 1 a pool of `jobs` processes with `threads` torch threads
    each, log lines in `logs`/NAME.log. "ray": a task per cell on the Ray cluster at `address`
    (None: a local one of this machine's cores), `threads` CPUs each; `ship` "auto" (send the
    cells' folders where the worker is on another node), "always" or "never". `on_result(name,
    result)` is called as each cell finishes. Raises CellFailure naming every cell that failed (or
    could not start because one it needs failed) once the others have finished."""
    cells = list(cells)
    names = [cell.name for cell in cells]
    if len(set(names)) != len(names):
        raise ValueError("cell names must be unique")
    unknown = {need for cell in cells for need in cell.after} - set(names)
    if unknown:
        raise ValueError(f"cells need unknown cells: {', '.join(sorted(unknown))}")
    if executor not in EXECUTORS:
        raise ExecutorError(f"unknown executor {executor!r}; choose from {', '.join(EXECUTORS)}")
    if ship not in ("auto", "always", "never"):
        raise ExecutorError(f"ship must be auto, always or never, got {ship!r}")
    scheduler = _Scheduler(cells, log, on_result)
    if executor == "ray":
        return scheduler.run(_RayBackend(address, threads or 1, ship, logs))
    if jobs <= 1:
        return scheduler.run(_HereBackend(log))
    return scheduler.run(_PoolBackend(jobs, threads, logs))


class _Scheduler:
    """Starts each cell once its `after` cells have finished and a slot is free; records results
    and failures; the backends say how a cell runs."""

    def __init__(self, cells, log, on_result):
        self.cells, self.log, self.on_result = cells, log, on_result
        self.results, self.failures = {}, {}

    def run(self, backend):
        waiting, running = list(self.cells), {}
        started = time.perf_counter()
        with backend:
            while waiting or running:
                for cell in list(waiting):
                    if len(running) >= backend.slots:
                        break
                    failed = [need for need in cell.after if need in self.failures]
                    if failed:
                        self.failures[cell.name] = f"needs {failed[0]}, which failed"
                        waiting.remove(cell)
                    elif all(need in self.results for need in cell.after):
                        running[backend.submit(cell)] = cell
                        waiting.remove(cell)
                        if backend.slots > 1:
                            self.log(f"started {cell.name}")
                if not running:
                    break            # what waits needs a cell that can no longer finish
                for handle, outcome in backend.wait(list(running)):
                    cell = running.pop(handle)
                    self._record(cell, outcome, started, backend.slots > 1)
        for cell in waiting:
            self.failures.setdefault(cell.name, "never started")
        if self.failures:
            raise CellFailure(self.failures, self.results)
        return self.results

    def _record(self, cell, outcome, started, announce):
        kind, value = outcome
        if kind == "result":
            self.results[cell.name] = value
            if self.on_result is not None:
                self.on_result(cell.name, value)
        else:
            self.failures[cell.name] = value
        if announce or kind != "result":
            done = len(self.results) + len(self.failures)
            status = "finished" if kind == "result" else f"failed: {value}"
            self.log(f"[{done}/{len(self.cells)}] {cell.name} {status} "
                     f"({(time.perf_counter() - started) / 60:.1f} min in)")


def reason(error):
    """An exception in one line: its type and its message's first line."""
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


# ---- here, in order ------------------------------------------------------------------------------------------------

class _HereBackend:
    slots = 1

    def __init__(self, log):
        self.log = log

    def __enter__(self):
        self.done = {}
        return self

    def __exit__(self, *exc):
        return False

    def submit(self, cell):
        try:
            self.done[cell.name] = ("result", cell.function(**cell.kwargs, log=self.log))
        except Exception as error:          # recorded; the other cells go on
            self.done[cell.name] = ("failure", reason(error))
        return cell.name

    def wait(self, handles):
        return [(handle, self.done.pop(handle)) for handle in handles]


# ---- a pool of processes on this machine --------------------------------------------------------------------------

class _PoolBackend:
    def __init__(self, jobs, threads, logs):
        self.slots, self.threads, self.logs = jobs, threads, Path(logs) if logs else None

    def __enter__(self):
        context = multiprocessing.get_context("spawn")      # no forked torch state in the workers
        self.pool = ProcessPoolExecutor(max_workers=self.slots, mp_context=context, initializer=_worker_start,
                                        initargs=(self.threads,))
        return self

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)
        return False

    def submit(self, cell):
        log_file = None if self.logs is None else str(self.logs / f"{cell.name}.log")
        return self.pool.submit(_call_logged, cell.function, cell.kwargs, log_file)

    def wait(self, handles):
        done, _ = wait(handles, return_when=FIRST_COMPLETED)
        outcomes = []
        for future in done:
            try:
                outcomes.append((future, ("result", future.result())))
            except Exception as error:
                outcomes.append((future, ("failure", reason(error))))
        return outcomes


def _worker_start(threads):
    from .threads import configure_threads

    _drop_blender_script_paths()
    configure_threads(threads)


def _drop_blender_script_paths():
    """A spawned worker starts with its parent's sys.path. Where the parent imported Blender's
    module, that holds Blender's script folders first, and one of them has a `bpy` package of its
    own that would then be imported instead of the module (and fail: no `_bpy`)."""
    import sys

    sys.path[:] = [entry for entry in sys.path if not {"bpy", "scripts"} <= set(Path(entry).parts)]


def _call_logged(function, kwargs, log_file):
    """Run a cell in a worker, its log lines (and a traceback if it fails) in `log_file`."""
    if log_file is None:
        return function(**kwargs, log=lambda message: None)
    Path(log_file).parent.mkdir(parents=True, exist_ok=True)
    with open(log_file, "a") as handle:
        def log(message):
            handle.write(f"{message}\n")
            handle.flush()
        try:
            return function(**kwargs, log=log)
        except Exception:
            handle.write(traceback.format_exc())
            raise


# ---- Ray -----------------------------------------------------------------------------------------------------------

def import_ray():
    try:
        import ray
    except ImportError:
        raise ExecutorError(RAY_INSTALL) from None
    return ray


class _RayBackend:
    def __init__(self, address, threads, ship, logs):
        self.ray = import_ray()
        self.address, self.threads, self.ship, self.logs = address, threads, ship, logs

    def __enter__(self):
        ray = self.ray
        self.started_here = not ray.is_initialized()
        if self.started_here:
            options = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
            if self.address:
                ray.init(address=self.address, **options)
            else:        # a cluster of this machine, its workers importing this copy of the code
                from .threads import available_cores

                code = str(Path(__file__).resolve().parents[1])
                ray.init(num_cpus=available_cores(), runtime_env={"env_vars": {"PYTHONPATH": code}}, **options)
        total = int(ray.cluster_resources().get("CPU", 1))
        self.slots = max(1, total // self.threads)
        self.node = ray.get_runtime_context().get_node_id()
        self.task = ray.remote(_ray_cell).options(num_cpus=self.threads, max_retries=RAY_RETRIES,
                                                  retry_exceptions=False)
        self.cells = {}
        return self

    def __exit__(self, *exc):
        if self.started_here:
            self.ray.shutdown()
        return False

    def submit(self, cell):
        shipped = {name: _pack(cell.kwargs[name]) for name in cell.ship} if self.ship != "never" else None
        log_file = None if self.logs is None else str(Path(self.logs) / f"{cell.name}.log")
        reference = self.task.remote(cell.function, cell.kwargs, cell.ship, shipped, self.ship, self.node,
                                     self.threads, log_file)
        self.cells[reference] = cell
        return reference

    def wait(self, handles):
        done, _ = self.ray.wait(handles, num_returns=1)
        outcomes = []
        for reference in done:
            cell = self.cells.pop(reference)
            try:
                result, returned = self.ray.get(reference)
            except Exception as error:
                outcomes.append((reference, ("failure", reason(getattr(error, "cause", None) or error))))
                continue
            for name, archive in (returned or {}).items():      # the shipped folders, as the cell left them
                _unpack(archive, cell.kwargs[name])
            outcomes.append((reference, ("result", result)))
        return outcomes


def _ray_cell(function, kwargs, ship, shipped, mode, driver_node, threads, log_file):
    """A cell as a Ray task: where its folders must travel, in a scratch copy of them, which goes
    back to the driver with the result."""
    import ray

    from .threads import configure_threads

    configure_threads(threads)
    travel = shipped is not None and (mode == "always" or ray.get_runtime_context().get_node_id() != driver_node)
    if not travel:
        return _call_logged(function, kwargs, log_file), None
    with tempfile.TemporaryDirectory(prefix="harp_cell_") as scratch:
        local = dict(kwargs)
        for name in ship:
            local[name] = Path(scratch) / name
            _unpack(shipped[name], local[name])
        log = None if log_file is None else str(Path(scratch) / "cell.log")
        result = _call_logged(function, local, log)
        return result, {name: _pack(local[name]) for name in ship}


def _pack(folder):
    """A folder as gzipped tar bytes (None where it does not exist yet)."""
    folder = Path(folder)
    if not folder.exists():
        return None
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        archive.add(folder, arcname=".")
    return buffer.getvalue()


def _unpack(data, folder):
    """Put the folder packed in `data` at `folder` (replacing what was there); None: nothing."""
    if data is None:
        return
    folder = Path(folder)
    staging = folder.with_name(folder.name + ".incoming")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
        archive.extractall(staging, filter="data")
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(staging, folder)
