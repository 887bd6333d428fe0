"""Worker process pools that are safe next to OpenCV, OpenBLAS and torch thread pools.

Every pool in agrivio starts its workers with ``spawn``, never ``fork``: a child forked after OpenCV's (or
OpenBLAS's) thread pool exists inherits its locks in whatever state the parent's threads left them, and the
first ``cv2.setNumThreads`` there can block for ever (seen: the end-to-end test hung in ``pthread_cond_destroy``
inside cv2 in both workers). A spawned worker costs one interpreter start and the imports (≈2 s), once per pool.
Each worker runs single-threaded (one job = one core): parallelism is across processes.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any


def _single_threaded(initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
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
                               initializer=_single_threaded, initargs=(initializer, initargs))
