"""The study's fits as independent cells, run one after another in this process or several at
once, each in a process of its own with its own torch threads.

Two fits of one thread each share this project's 2-core machine at 1.02x the time of one alone
(docs/performance.md, "Threads"), so two cells at once nearly halve a study's time where one fit
with two threads gains 0-20%. A cell names the cells that must finish before it starts (HARP-known
takes the same identity's flip fit). A cell that fails is recorded and the others go on; the
study then stops with every failure named, its finished work kept on disk for a rerun.
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable


@dataclasses.dataclass(frozen=True)
class Cell:
    """One unit of the study's work: `function(**kwargs, log=...)`, a module-level function
    (it crosses to a worker process); `after` names the cells it needs finished first."""

    name: str
    function: Callable
    kwargs: dict
    after: tuple[str, ...] = ()


class CellFailure(RuntimeError):
    """Cells that failed: {name: one-line reason}."""

    def __init__(self, failures: dict):
        self.failures = failures
        super().__init__("; ".join(f"{name}: {reason}" for name, reason in failures.items()))


def run_cells(cells, jobs=1, threads=None, log=print, logs=None):
    """Run `cells`; returns {name: result}. jobs == 1: here, in order (each cell's `after` must
    come before it). jobs > 1: a pool of `jobs` processes with `threads` torch threads each,
    every cell started as soon as a worker is free and its `after` cells have finished, its
    log lines written to `logs`/NAME.log. Raises CellFailure naming every cell that failed (or
    could not start because one it needs failed) once the others have finished."""
    cells = list(cells)
    names = [cell.name for cell in cells]
    if len(set(names)) != len(names):
        raise ValueError("cell names must be unique")
    unknown = {need for cell in cells for need in cell.after} - set(names)
    if unknown:
        raise ValueError(f"cells need unknown cells: {', '.join(sorted(unknown))}")
    if jobs <= 1:
        return _run_here(cells, log)
    return _run_pool(cells, jobs, threads, log, Path(logs) if logs else None)


def _run_here(cells, log):
    results, failures = {}, {}
    for cell in cells:
        failed = [need for need in cell.after if need in failures]
        if failed:
            failures[cell.name] = f"needs {failed[0]}, which failed"
            continue
        try:
            results[cell.name] = cell.function(**cell.kwargs, log=log)
        except Exception as error:          # recorded; the other cells go on
            failures[cell.name] = _reason(error)
            log(f"{cell.name} failed: {failures[cell.name]}")
    if failures:
        raise CellFailure(failures)
    return results


def _run_pool(cells, jobs, threads, log, logs):
    results, failures = {}, {}
    waiting = list(cells)
    running = {}
    started = time.perf_counter()
    context = multiprocessing.get_context("spawn")      # no forked torch state in the workers
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context, initializer=_worker_start,
                             initargs=(threads,)) as pool:
        while waiting or running:
            for cell in list(waiting):
                if len(running) >= jobs:
                    break
                failed = [need for need in cell.after if need in failures]
                if failed:
                    failures[cell.name] = f"needs {failed[0]}, which failed"
                    waiting.remove(cell)
                elif all(need in results for need in cell.after):
                    log_file = None if logs is None else str(logs / f"{cell.name}.log")
                    running[pool.submit(_worker_call, cell.function, cell.kwargs, log_file)] = cell
                    waiting.remove(cell)
                    log(f"started {cell.name}")
            if not running:
                break            # what waits needs a cell that can no longer finish
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                cell = running.pop(future)
                try:
                    results[cell.name] = future.result()
                except Exception as error:
                    failures[cell.name] = _reason(error)
                finished = len(results) + len(failures)
                status = "finished" if cell.name in results else f"failed: {failures[cell.name]}"
                log(f"[{finished}/{len(cells)}] {cell.name} {status} "
                    f"({(time.perf_counter() - started) / 60:.1f} min into the study)")
    for cell in waiting:
        failures.setdefault(cell.name, "never started")
    if failures:
        raise CellFailure(failures)
    return results


def _reason(error):
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _worker_start(threads):
    from ..threads import configure_threads

    configure_threads(threads)


def _worker_call(function, kwargs, log_file):
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
