"""The batch runner: isolation of failing runs, resumption after a kill, the local and Ray executors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from pipeline.batch import Job, load_record, run_jobs
from tests import batch_fakes

REPO = Path(__file__).resolve().parent.parent


def _jobs(root: Path, n: int, **options) -> list[Job]:
    return [Job("seqA", "tiny", "stereo", seed, str(root / f"seed{seed}"), dict(options)) for seed in range(n)]


def test_failing_run_is_recorded_and_the_batch_goes_on(tmp_path):
    jobs = _jobs(tmp_path, 3)
    jobs[1] = Job("seqA", "tiny", "stereo", 1, str(tmp_path / "seed1"), {"fail": True})
    records = run_jobs(jobs, batch_fakes.quick_run, executor="serial", progress=False)
    assert [r["status"] for r in records] == ["ok", "failed", "ok"]
    assert "diverged on purpose (seed 1)" in records[1]["failure_reason"]
    assert records[2]["metrics"]["ate_rmse_m"] == pytest.approx(0.3)
    assert load_record(jobs[1].record_path)["status"] == "failed"


def test_process_pool_survives_a_crashing_worker(tmp_path):
    jobs = _jobs(tmp_path, 4)
    jobs[2] = Job("seqA", "tiny", "stereo", 2, str(tmp_path / "seed2"), {"crash": True})
    records = run_jobs(jobs, batch_fakes.crash_run, executor="local", workers=2, progress=False)
    status = {r["seed"]: r["status"] for r in records}
    assert status == {0: "ok", 1: "ok", 2: "failed", 3: "ok"}
    assert "worker process died" in records[2]["failure_reason"]


def test_done_runs_are_not_redone(tmp_path):
    jobs = _jobs(tmp_path, 3)
    run_jobs(jobs[:2], batch_fakes.quick_run, executor="serial", progress=False)
    before = {j.seed: j.record_path.stat().st_mtime_ns for j in jobs[:2]}
    time.sleep(0.01)
    records = run_jobs(jobs, batch_fakes.quick_run, executor="serial", progress=False)
    assert all(r["status"] == "ok" for r in records)
    assert {j.seed: j.record_path.stat().st_mtime_ns for j in jobs[:2]} == before


def test_partial_record_file_counts_as_unfinished(tmp_path):
    job = _jobs(tmp_path, 1)[0]
    job.record_path.parent.mkdir(parents=True)
    job.record_path.write_text('{"status": "o')  # a torn write (cannot happen with atomic writes, but be safe)
    assert load_record(job.record_path) is None
    assert run_jobs([job], batch_fakes.quick_run, executor="serial", progress=False)[0]["status"] == "ok"


def test_kill_and_resume(tmp_path):
    """Kill a running batch mid-way; the restart redoes only the unfinished runs and keeps the finished ones."""
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        from pathlib import Path
        from pipeline.batch import Job, run_jobs
        from tests import batch_fakes
        root = Path({str(tmp_path)!r})
        jobs = [Job("seqA", "tiny", "stereo", s, str(root / f"seed{{s}}"), {{"sleep_s": 0.4}}) for s in range(8)]
        run_jobs(jobs, batch_fakes.slow_run, executor="serial", progress=False)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)
    deadline = time.time() + 60
    while time.time() < deadline and len(list(tmp_path.glob("seed*/record.json"))) < 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = sorted(tmp_path.glob("seed*/record.json"))
    assert 2 <= len(finished) < 8, "the batch should have been killed mid-way"
    stamps = {p: p.stat().st_mtime_ns for p in finished}
    assert all(json.loads(p.read_text())["status"] == "ok" for p in finished)  # atomic: no torn record

    jobs = [Job("seqA", "tiny", "stereo", s, str(tmp_path / f"seed{s}"), {"sleep_s": 0.0}) for s in range(8)]
    records = run_jobs(jobs, batch_fakes.slow_run, executor="serial", progress=False)
    assert [r["status"] for r in records] == ["ok"] * 8
    assert {p: p.stat().st_mtime_ns for p in finished} == stamps  # finished runs untouched


def test_ray_executor_on_a_local_instance(tmp_path, monkeypatch):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install 'agrivio[ray]')")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    jobs = _jobs(tmp_path, 3)
    jobs[0] = Job("seqA", "tiny", "stereo", 0, str(tmp_path / "seed0"), {"fail": True})
    records = run_jobs(jobs, batch_fakes.quick_run, executor="ray", progress=False)
    assert [r["status"] for r in records] == ["failed", "ok", "ok"]
    assert all(load_record(j.record_path) is not None for j in jobs)
