"""Run a matrix of jobs (sequences × variants × seeds) in isolation, resumably, locally or on Ray.

Each job writes exactly one record file (JSON), atomically, when it ends — ``status: ok`` or ``status: failed``
with the reason. A batch that is killed and restarted with the same jobs skips every job whose record is reusable
and redoes the others, so nothing already computed is lost. A record is reusable when it is ``ok`` (a failed one
is retried unless ``keep_failed``) and, if the job carries an input key (``options["input_key"]``, see
:mod:`pipeline.run_key`), when the record was made with the same key: a record of other inputs (another bag of
the same name, other frames, GT, config, method or code) is recomputed, never reported as if it were current.

Isolation: a job's Python exception becomes a failed record and the batch goes on. A worker process that dies
(segfault, OOM kill) breaks a ``ProcessPoolExecutor``; the jobs it held are then recorded as failed with that reason
and a fresh pool runs the rest.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from eval.variants import DEPTH_INPAINTED
from pipeline.atomic import write_json_atomic
from pipeline.errors import AgrivioError
from pipeline.process_pool import spawn_pool

RECORD_NAME = "record.json"
#: The job option (and record field) holding the run's input key (see :mod:`pipeline.run_key`).
INPUT_KEY = "input_key"
#: Job options copied to the record's top level, in ok and failed records alike (see :mod:`pipeline.run_key`,
#: :mod:`pipeline.data_quality`); the other options form the record's ``job`` (:func:`job_description`).
RECORD_FIELDS = (INPUT_KEY, "input_key_parts", "data_quality", "simulated")
EXECUTORS = ("local", "serial", "ray")


@dataclass(frozen=True)
class Job:
    """One run: a sequence, a variant and a seed, with its own output folder.

    Attributes:
        sequence: sequence name (used in reports).
        source: a bag path or a simulator preset name.
        variant: ``stereo``, ``depth-raw``, ``depth-inpainted`` or ``odometry``.
        seed: the run's random seed (RANSAC draws, detector jitter).
        out_dir: the folder that receives ``record.json`` and the run's other files.
        options: JSON-able description of the run for its record (the inputs that apply to it, its input key and
            parts, ...); the batch runner reads only ``input_key`` and ``inpaint_method`` from it.
        plan: the resolved settings the run function works from (e.g. a :class:`pipeline.run_plan.RunPlan`), a
            picklable object shipped to the worker as is; None for run functions that need none.
    """

    sequence: str
    source: str
    variant: str
    seed: int
    out_dir: str
    options: dict[str, Any] = field(default_factory=dict)
    plan: Any = None

    @property
    def record_path(self) -> Path:
        return Path(self.out_dir) / RECORD_NAME

    @property
    def label(self) -> str:
        return f"{self.sequence}/{self.variant}/seed{self.seed}"


RunFn = Callable[[Job], dict[str, Any]]


def load_record(path: Path) -> dict[str, Any] | None:
    """The record at ``path`` if it exists and is complete JSON, else None (a partial file counts as not done)."""
    try:
        record = json.loads(Path(path).read_text())
    except (FileNotFoundError, json.JSONDecodeError, UnicodeDecodeError):
        return None
    return record if isinstance(record, dict) and record.get("status") in ("ok", "failed") else None


def job_description(job: Job) -> dict[str, Any]:
    """A record's ``job`` field, the same layout in ok and failed records: the source and the job's options except
    :data:`RECORD_FIELDS` (those sit at the record's top level) and the IMU → base_link rotation."""
    return {"source": job.source, **{k: v for k, v in job.options.items()
                                     if k != "R_base_imu" and k not in RECORD_FIELDS}}


def failed_record(job: Job, reason: str, elapsed_s: float | None = None) -> dict[str, Any]:
    """The record of a run that raised or died: the layout of an ok record (top-level :data:`RECORD_FIELDS`, the
    inpainting method, ``job`` from :func:`job_description`) with ``status: failed`` and the reason."""
    return {
        "record_type": "run",
        "sequence": job.sequence,
        "variant": job.variant,
        "seed": job.seed,
        "status": "failed",
        "failure_reason": reason,
        "inpaint_method": job.options.get("inpaint_method") if job.variant == DEPTH_INPAINTED else None,
        **{k: job.options.get(k) for k in RECORD_FIELDS},
        "timings": {"total_s": elapsed_s} if elapsed_s is not None else {},
        "job": job_description(job),
    }


def run_isolated(run_fn: RunFn, job: Job, write: bool = True) -> dict[str, Any]:
    """Run one job; never raises for the job's own errors. Returns the record, written atomically if ``write``.

    On Ray the driver writes the record (``write=False``), so records land where the batch was started even when
    workers run on other machines (a run's other files need a shared file system in that case).
    """
    t0 = time.perf_counter()
    try:
        record = run_fn(job)
        record.setdefault("status", "ok")
    except Exception as exc:  # noqa: BLE001 — any failure of one run is recorded, never fatal to the batch
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" ({tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno})" if tb else ""
        record = failed_record(job, f"{type(exc).__name__}: {exc}{where}", time.perf_counter() - t0)
    if write:
        write_json_atomic(job.record_path, record)
    return record


def reuse_verdict(job: Job, keep_failed: bool = False) -> str:
    """Whether ``job``'s existing record can stand: ``"reuse"``, or why it is (re)run: ``"missing"`` (no complete
    record), ``"failed"`` (a failed record, retried unless ``keep_failed``) or ``"stale"`` (made from other inputs:
    its input key differs from the job's)."""
    record = load_record(job.record_path)
    if record is None:
        return "missing"
    wanted = job.options.get(INPUT_KEY)
    if wanted is not None and record.get(INPUT_KEY) != wanted:
        return "stale"
    if record.get("status") != "ok" and not keep_failed:
        return "failed"
    return "reuse"


def pending_jobs(jobs: Iterable[Job], keep_failed: bool = False) -> tuple[list[Job], list[Job]]:
    """Split jobs into (done, pending): done = a reusable record exists (see :func:`reuse_verdict`)."""
    done, pending = [], []
    for job in jobs:
        (done if reuse_verdict(job, keep_failed) == "reuse" else pending).append(job)
    return done, pending


def _say_what_is_redone(jobs: Sequence[Job], keep_failed: bool) -> list[Job]:
    """The pending jobs; one line on stderr when records are redone because they failed or are stale."""
    import sys

    verdicts = [reuse_verdict(job, keep_failed) for job in jobs]
    n_stale, n_failed = verdicts.count("stale"), verdicts.count("failed")
    if n_stale:
        print(f"note: {n_stale} existing record(s) were made from other inputs (bag, GT, frames, config, method or "
              f"code version differ) and are recomputed", file=sys.stderr)
    if n_failed:
        print(f"note: {n_failed} failed record(s) are retried (--keep-failed keeps them)", file=sys.stderr)
    pending = [job for job, v in zip(jobs, verdicts) if v != "reuse"]
    for job in pending:  # a failed or stale record must not pass for this run's outcome if the run dies
        job.record_path.unlink(missing_ok=True)
    return pending


def run_jobs(jobs: Sequence[Job], run_fn: RunFn, executor: str = "local", workers: int | None = None,
             ray_address: str | None = None, progress: bool = True,
             keep_failed: bool = False) -> list[dict[str, Any]]:
    """Run every job without a reusable record (see :func:`reuse_verdict`); return all records in job order.

    Args:
        executor: ``local`` (process pool, default ``workers`` = all cores), ``serial`` (this process), or ``ray``.
        ray_address: for ``ray``: a cluster address (``ray://host:10001`` or ``auto``); None starts a local instance.
        keep_failed: reuse failed records instead of retrying them.
    """
    if executor not in EXECUTORS:
        raise AgrivioError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")
    # two inpainting methods of depth-inpainted are two jobs of the same sequence/variant/seed
    labels = [(job.label, job.options.get("inpaint_method")) for job in jobs]
    if len(set(labels)) != len(labels) or len({job.out_dir for job in jobs}) != len(jobs):
        raise AgrivioError("the batch holds duplicate jobs (same sequence/variant/inpainting method/seed or output "
                           "folder)")
    pending = _say_what_is_redone(jobs, keep_failed)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(pending), desc="runs", unit="run", disable=not progress)
    try:
        if pending:
            if executor == "serial":
                for job in pending:
                    run_isolated(run_fn, job)
                    bar.update(1)
            elif executor == "local":
                _run_process_pool(pending, run_fn, workers or os.cpu_count() or 1, bar)
            else:
                _run_ray(pending, run_fn, ray_address, bar)
    finally:
        bar.close()
    records = []
    for job in jobs:
        record = load_record(job.record_path)
        records.append(record if record is not None else failed_record(job, "no record was written"))
    return records


def _run_process_pool(pending: list[Job], run_fn: RunFn, workers: int, bar: tqdm) -> None:
    broken_jobs = _pool_pass(pending, run_fn, workers, bar)
    # The pool died under some job: which one is unknown when several ran at once, so each affected job that has
    # no record yet is retried alone in a fresh pool; a job that kills its worker when alone is recorded as failed.
    for job in broken_jobs:
        if load_record(job.record_path) is not None:
            bar.update(1)
        elif _pool_pass([job], run_fn, 1, bar):
            write_json_atomic(job.record_path, failed_record(job, "the worker process died (crash or out of memory)"))
            bar.update(1)


def _pool_pass(jobs: list[Job], run_fn: RunFn, workers: int, bar: tqdm) -> list[Job]:
    """Run ``jobs`` on one pool; return those whose futures failed because the pool broke."""
    broken: list[Job] = []
    with spawn_pool(min(workers, len(jobs))) as pool:
        futures: dict[Future, Job] = {pool.submit(run_isolated, run_fn, job): job for job in jobs}
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                fut.result()
                bar.update(1)
            except BrokenProcessPool:
                broken.append(job)
            except Exception as exc:  # noqa: BLE001 — e.g. the record could not be pickled back
                write_json_atomic(job.record_path, failed_record(job, f"{type(exc).__name__}: {exc}"))
                bar.update(1)
    return broken


def _run_ray(pending: list[Job], run_fn: RunFn, address: str | None, bar: tqdm) -> None:
    try:
        import ray
    except ImportError as exc:
        raise AgrivioError("the Ray executor needs the optional extra: pip install 'agrivio[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_isolated)
        refs = {remote.remote(run_fn, job, False): job for job in pending}
        remaining = list(refs)
        while remaining:
            ready, remaining = ray.wait(remaining, num_returns=1)
            for ref in ready:
                job = refs[ref]
                try:
                    record = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 — a worker crash on the cluster is one failed run
                    record = failed_record(job, f"ray task failed: {type(exc).__name__}: "
                                                f"{str(exc).splitlines()[0][:300]}")
                write_json_atomic(job.record_path, record)
                bar.update(1)
    finally:
        if started_here:
            ray.shutdown()
