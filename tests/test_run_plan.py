"""The run plan (issue 15): settings resolved once, before any stage, and carried to the workers as objects."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

import pipeline.run_job as rj
import pipeline.run_sequence as rs
from msckf.config import MsckfConfig
from msckf.errors import MsckfInputError
from pipeline.batch import Job, failed_record, job_description
from pipeline.depth import DepthFrame, DepthParams, quantize
from pipeline.depth_cache import DepthCache
from pipeline.inpaint_stage import InpaintParams, inpainted_stream, uses_guide
from pipeline.run_plan import RunPlan
from pipeline.run_sequence import SequenceSpec, plan_jobs, prepare_sequence
from pipeline.synthetic_scene import write_synthetic_bag


@pytest.fixture()
def bag(tmp_path) -> Path:
    path = tmp_path / "seq.bag"
    write_synthetic_bag(path, n_frames=4, seed=3, overwrite=True)
    return path


def _no_stage(*args, **kwargs):
    raise AssertionError("a stage ran before the config was resolved")


def test_bad_config_fails_before_any_check_or_depth_work(tmp_path, bag, monkeypatch):
    bad = tmp_path / "bad.yaml"
    bad.write_text("no_such_key: 1\n")
    monkeypatch.setattr(rs, "check_sequence", _no_stage)
    monkeypatch.setattr(rs, "depth_stream", _no_stage)
    with pytest.raises(MsckfInputError, match="no_such_key"):
        prepare_sequence(SequenceSpec(str(bag)), ["depth-raw"], tmp_path / "cache", msckf_config=str(bad))
    with pytest.raises(MsckfInputError, match="no_such_key"):
        rs.run_matrix([SequenceSpec(str(bag))], ["depth-raw"], [0], tmp_path / "out", tmp_path / "cache",
                      msckf_config=str(bad), progress=False)


def _plan_with_config(tmp_path: Path, bag: Path, variants: list[str]) -> tuple[Path, list[Job]]:
    cfg = tmp_path / "msckf.yaml"
    cfg.write_text("feature_noise: 0.0003\n")
    prepared = prepare_sequence(SequenceSpec(str(bag)), variants, tmp_path / "cache", msckf_config=str(cfg),
                                progress=False)
    return cfg, plan_jobs(prepared, variants, [0], tmp_path / "out")


def test_plan_is_resolved_once_and_travels_pickled(tmp_path, bag):
    cfg, jobs = _plan_with_config(tmp_path, bag, ["stereo", "odometry"])
    plan = jobs[0].plan
    assert isinstance(plan, RunPlan) and isinstance(plan.msckf, MsckfConfig)
    assert plan.msckf.to_flat_dict()["feature_noise"] == 0.0003
    assert plan.key_parts["msckf"]["feature_noise"] == 0.0003 and plan.msckf_config_path == str(cfg)
    assert all(job.plan is plan for job in jobs)  # one plan per sequence, shared by its jobs
    back = pickle.loads(pickle.dumps(jobs[0]))  # what the process pool and Ray ship to a worker
    assert back.plan == plan and back.options == jobs[0].options
    assert plan.eval_options("odometry").interpolate and not plan.eval_options("stereo").interpolate


def test_worker_uses_the_planned_config_not_the_file(tmp_path, bag, monkeypatch):
    """The YAML changed, then removed, after planning: the job still runs with the config resolved at planning."""
    cfg, jobs = _plan_with_config(tmp_path, bag, ["stereo"])
    cfg.write_text("feature_noise: 0.5\n")
    cfg.unlink()
    seen: list[MsckfConfig] = []

    class Stop(Exception):
        pass

    def fake_msckf(config, rig, variant="stereo", seed=0):
        seen.append(config)
        raise Stop

    monkeypatch.setattr(rj, "Msckf", fake_msckf)
    with pytest.raises(Stop):
        rj.run_job(jobs[0])
    assert seen and seen[0].to_flat_dict()["feature_noise"] == 0.0003


def test_run_job_refuses_a_job_without_plan(tmp_path):
    from pipeline.errors import AgrivioError

    with pytest.raises(AgrivioError, match="no run plan"):
        rj.run_job(Job("s", "s.bag", "stereo", 0, str(tmp_path / "r")))


def test_ok_and_failed_records_share_the_job_layout(tmp_path, bag):
    _, jobs = _plan_with_config(tmp_path, bag, ["odometry"])
    record = rj.run_job(jobs[0])
    failed = failed_record(jobs[0], "boom")
    assert record["job"] == json.loads(json.dumps(failed["job"])) == json.loads(json.dumps(job_description(jobs[0])))
    for key in ("input_key", "input_key_parts", "data_quality", "simulated"):
        assert json.loads(json.dumps(failed[key])) == record[key]


def test_inpainted_stream_serves_what_the_cache_reads(tmp_path, bag):
    """Fresh inpainted frames (no PNG decode round trip) equal what a later read of the cache gives."""
    from pipeline.bag_reader import RosarioSequence

    seq = RosarioSequence(bag)
    params = InpaintParams(method="telea")
    fresh = list(inpainted_stream(seq, params, tmp_path / "cache", progress=False, workers=1))
    store = DepthCache(tmp_path / "cache", seq.identity(), params)
    assert len(fresh) == 4
    for f in fresh:
        c = store.get(f.index)
        np.testing.assert_array_equal(f.depth_m, c.depth_m)
        np.testing.assert_array_equal(f.valid, c.valid)
        np.testing.assert_array_equal(f.left_rect_grey, c.left_rect_grey)


def test_no_method_gets_an_unused_guide():
    from inpaint import METHODS

    assert not any(uses_guide(m) for m in METHODS)


def test_depth_is_rounded_once_like_before():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.3, 80.0, (8, 9)).astype(np.float32)
    d[0, 0] = np.nan
    frame = DepthFrame(1, 0, d, np.isfinite(d), np.zeros((8, 9), np.uint8))
    from pipeline.depth import encode_depth_mm, quantize_mm

    q, mm = quantize_mm(frame)
    np.testing.assert_array_equal(mm, encode_depth_mm(q.depth_m))  # rounding the rounded map changes nothing
    np.testing.assert_array_equal(q.depth_m, quantize(frame).depth_m)
    assert DepthParams().key() == DepthParams().key()


def test_same_inputs_reuse_and_a_changed_config_recomputes(tmp_path, bag, monkeypatch, capsys):
    """Through the CLI: the same --config again reuses the record; another --config (same path) recomputes it."""
    from pipeline.cli import main

    monkeypatch.setenv("AGRIVIO_CACHE", str(tmp_path / "cache"))
    cfg = tmp_path / "msckf.yaml"
    cfg.write_text("feature_noise: 0.0003\n")
    out = tmp_path / "runs"
    argv = ["run-sequence", str(bag), "--out", str(out), "--variants", "stereo", "--runs", "1",
            "--executor", "serial", "--config", str(cfg), "--keep-failed"]  # 4 frames: the run fails, kept
    main(argv)
    record = out / "seq" / "stereo" / "seed0" / "record.json"
    first = json.loads(record.read_text())
    stamp = record.stat().st_mtime_ns
    capsys.readouterr()
    main(argv)
    assert record.stat().st_mtime_ns == stamp and "other inputs" not in capsys.readouterr().err
    cfg.write_text("feature_noise: 0.0004\n")
    main(argv)
    assert "1 existing record(s) were made from other inputs" in capsys.readouterr().err
    second = json.loads(record.read_text())
    assert second["input_key"] != first["input_key"]
    assert second["input_key_parts"]["msckf"]["feature_noise"] == 0.0004
