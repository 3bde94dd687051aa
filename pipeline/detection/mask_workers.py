"""The masks of a clip's frames made by several processes at once.

A mask made from the footage (hand_masks.frame_mask) is OpenCV's GrabCut and a few image
operations, about a second of one core per 640 px frame and independent of every other frame's:
a 16-second phone clip (493 frames) took 11 minutes of one core on a 2-core machine whose other
core sat idle (docs/real_footage.md). GrabCut runs on one thread, so the frames are shared
between processes instead. They are spawned, not forked: the importing process has MediaPipe's
threads running, which a forked child would inherit in whatever state they were. Each worker
runs OpenCV single-threaded, so N workers take N cores.
"""
from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from ..threads import available_cores

MIN_JOBS_PER_WORKER = 4     # below this many frames a worker's start (about a second) is not worth it


def each_frame(function, jobs, workers=1):
    """An iterator over function(job) for each of `jobs` (a list), in their order; with `workers`
    > 1 (None: every available core) computed by that many spawned processes, where there are at
    least MIN_JOBS_PER_WORKER jobs for each. `function` must be a module-level function (it is
    pickled by name). Where the processes cannot be started, or die, the frames not yet done are
    made here, one after another."""
    workers = min(available_cores() if workers is None else workers, len(jobs) // MIN_JOBS_PER_WORKER)
    if workers <= 1:
        yield from map(function, jobs)
        return
    done, pool = 0, None
    try:
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_single_threaded_opencv)
        for result in pool.map(function, jobs):
            done += 1
            yield result
    except (BrokenProcessPool, OSError):
        yield from map(function, jobs[done:])
    finally:     # stopped early (an error, Ctrl-C): the frames not started are dropped, not waited for
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _single_threaded_opencv():
    import cv2

    cv2.setNumThreads(1)
