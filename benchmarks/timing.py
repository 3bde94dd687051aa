"""Wall-clock timing shared by the benchmark scripts."""
from __future__ import annotations

import statistics
import time

import torch


def seconds_per_call(function, repeats):
    """Mean wall time of `function()` over `repeats` calls, after one warm-up call."""
    function()
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / repeats


def alternating_medians(functions, rounds):
    """Median wall time of each of `functions` over `rounds` rounds that call them in turn (after
    one warm-up round): paths compared this way see the same machine, busy or not."""
    times = [[] for _ in functions]
    for round_index in range(rounds + 1):
        for function, record in zip(functions, times):
            if torch.cuda.is_available():
                torch.cuda.synchronize()
            start = time.perf_counter()
            function()
            if torch.cuda.is_available():
                torch.cuda.synchronize()
            if round_index:
                record.append(time.perf_counter() - start)
    return [statistics.median(record) for record in times]


def timed(figures, name, work):
    """`work()`, its wall time recorded as figures[name + "_seconds"] and printed."""
    start = time.perf_counter()
    result = work()
    figures[f"{name}_seconds"] = round(time.perf_counter() - start, 1)
    print(f"{name}: {figures[f'{name}_seconds']:.1f} s", flush=True)
    return result
