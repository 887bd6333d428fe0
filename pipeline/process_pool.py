"""Worker process pools that are safe next to OpenCV, OpenBLAS and torch thread pools.

Every pool in agrivio starts its workers with ``spawn``, never ``fork``: a child forked after OpenCV's (or
OpenBLAS's) thread pool exists inherits its locks in whatever state the parent's threads left them, and the
first ``cv2.setNumThreads`` there can block for ever (seen: the end-to-end test hung in ``pthread_cond_destroy``
inside cv2 in both workers). A spawned worker costs one interpreter start and the imports (≈2 s), once per pool.
Each worker runs single-threaded (one job = one core): parallelism is across processes.

A worker ends when the process that started the pool is gone (killed with ``SIGTERM`` / ``SIGKILL``, which runs
no cleanup): before, such workers went on with the task they held and then waited for ever, ≈ 0.5 GB each (found
after a ``kill`` of ``agrivio experiment`` during a simulation). A daemon thread in each worker compares its parent
pid with the pool owner's once a second and exits the process when they differ. What a worker had written stays
(every output is atomic); the task it held is not finished.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

#: How often a worker checks that the pool's owner is alive, s.
PARENT_CHECK_S = 1.0


def _exit_when_orphaned(owner_pid: int) -> None:
    """End this worker process as soon as its parent is no longer ``owner_pid`` (it died; the worker was
    re-parented)."""
    while True:
        time.sleep(PARENT_CHECK_S)
        if os.getppid() != owner_pid:
            os._exit(1)


def _single_threaded(initializer: Callable[..., None] | None, initargs: tuple[Any, ...],
                     owner_pid: int | None = None) -> None:
    if owner_pid is not None:
        threading.Thread(target=_exit_when_orphaned, args=(owner_pid,), daemon=True,
                         name="agrivio-orphan-watch").start()
    # BLAS and torch (OpenMP) threads are already 1: ``pipeline/__init__`` sets OPENBLAS/OMP/MKL_NUM_THREADS (unless
    # the user did) and spawned workers inherit the environment. Importing torch here would only cost every worker
    # ≈1.7 s, also those that never use it.
    import cv2

    cv2.setNumThreads(1)
    if initializer is not None:
        initializer(*initargs)


def spawn_pool(workers: int, initializer: Callable[..., None] | None = None,
               initargs: tuple[Any, ...] = ()) -> ProcessPoolExecutor:
    """A ``ProcessPoolExecutor`` of ``workers`` spawned, single-threaded processes (then ``initializer(*initargs)``).

    ``initializer`` and every submitted function must be importable module-level callables (spawn pickles them).
    """
    return ProcessPoolExecutor(max_workers=max(1, int(workers)), mp_context=mp.get_context("spawn"),
                               initializer=_single_threaded, initargs=(initializer, initargs, os.getpid()))
