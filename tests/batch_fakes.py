"""Fake run functions for the batch-runner tests (importable by worker processes and Ray workers)."""

from __future__ import annotations

import os
import time

from pipeline.batch import Job


def quick_run(job: Job) -> dict:
    """A run that succeeds unless the job asks to fail; the record carries a metric derived from the seed."""
    if job.options.get("fail"):
        raise RuntimeError(f"diverged on purpose (seed {job.seed})")
    return {"record_type": "run", "sequence": job.sequence, "variant": job.variant, "seed": job.seed,
            "metrics": {"ate_rmse_m": 0.1 * (job.seed + 1)}, "pid": os.getpid()}


def slow_run(job: Job) -> dict:
    """A run that takes a while, for kill-and-resume tests."""
    time.sleep(float(job.options.get("sleep_s", 0.3)))
    return quick_run(job)


def crash_run(job: Job) -> dict:
    """A run that kills its worker process outright (no Python exception to catch)."""
    if job.options.get("crash"):
        os._exit(13)
    return quick_run(job)
