"""How many CPU threads a fit uses, and how they wait.

torch's default (a thread per core, OpenMP threads that spin while they wait for work) is the
fastest a fit can be alone. Next to another busy process it collapses: the spinning threads
take turns on the cores they share, and renderer calls were measured 9-12x slower than with one
pinned thread on a 2-core machine. A fit often shares the machine (with Blender, with a second
fit), so the default here is half the cores and passive waiting: threads that have no work
sleep instead of spinning.

OMP_WAIT_POLICY is read when OpenMP starts, which is when torch is imported: configure_threads
sets it only if torch has not been imported yet (the `harp` command calls it first); the thread
count can change at any time.
"""
from __future__ import annotations

import os
import sys

WAIT_POLICY = "PASSIVE"


def available_cores() -> int:
    """The cores this process may run on (at least one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:       # not on Linux
        return os.cpu_count() or 1


def default_threads() -> int:
    """Half the cores this process may run on (at least one)."""
    return max(1, available_cores() // 2)


def configure_threads(threads: int | None = None) -> dict:
    """Use `threads` CPU threads for torch (None: default_threads()) and, if torch is not imported
    yet and the user has not chosen, OpenMP's passive waiting. Returns what is in effect:
    {"threads", "wait_policy"}."""
    if threads is not None and threads < 1:
        raise ValueError(f"--threads must be at least 1 (got {threads})")
    threads = threads or default_threads()
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)
    import torch

    torch.set_num_threads(threads)
    return {"threads": torch.get_num_threads(), "wait_policy": os.environ.get("OMP_WAIT_POLICY", "torch's default")}
