"""Wall-clock timing shared by the benchmark scripts."""
from __future__ import annotations

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
