"""End to end on a tiny simulated sequence: run-sequence with every variant and 2 runs, the report and a replay."""

from __future__ import annotations

import json

import pytest

from eval.variants import VARIANTS
from pipeline.cli import main
from pipeline.replay import recorded_entities


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory, sim_cache):
    cache = sim_cache
    out = tmp_path_factory.mktemp("runs")
    mp = pytest.MonkeyPatch()
    mp.setenv("AGRIVIO_CACHE", str(cache))
    try:
        code = main(["run-sequence", "tiny", "--out", str(out), "--runs", "2", "--variants", ",".join(VARIANTS),
                     "--workers", "2", "--inpaint", "telea"])
    finally:
        mp.undo()
    assert code == 0
    return out


def test_every_run_has_a_sane_record(runs_dir):
    records = [json.loads(p.read_text()) for p in sorted(runs_dir.glob("tiny/*/seed*/record.json"))]
    assert sorted((r["variant"], r["seed"]) for r in records) == sorted((v, s) for v in VARIANTS for s in (0, 1))
    for r in records:
        assert r["status"] == "ok", r.get("failure_reason")
        m = r["metrics"]
        # The tiny sequence drives well under a metre after 2.2 s standing still; errors must be far below that.
        assert 0.0 < m["ate_rmse_m"] < 0.5, (r["variant"], m["ate_rmse_m"])
        assert m["n_pairs"] >= 5  # 5 Hz GPS over the ~1.6 s after the static initialisation
        assert r["code_version"] and r["config_hash"]
        est = runs_dir / "tiny" / r["variant"] / f"seed{r['seed']}" / "estimate.tum"
        assert est.is_file() and len(est.read_text().splitlines()) > 10
    inpainted = [r for r in records if r["variant"] == "depth-inpainted"]
    assert all(r["inpaint_method"] == "telea" for r in inpainted)


def test_depth_runs_log_measured_and_filled_feature_depth_with_sigma(runs_dir):
    """Per feature the frame log says whether its depth was measured or filled and what σ the filter was given;
    only the inpainted run has filled depths, and fills are stated less certain than measurements."""
    import numpy as np

    summaries = {}
    for variant in ("depth-raw", "depth-inpainted"):
        folder = runs_dir / "tiny" / variant / "seed0"
        log = np.load(folder / "frames.npz")
        z, sig, meas = log["feature_depth_m"], log["feature_depth_sigma_m"], log["feature_depth_measured"]
        assert z.shape == sig.shape == meas.shape == log["feature_source"].shape
        has = np.isfinite(z)
        assert np.array_equal(has, log["feature_source"] > 0) and np.all(np.isfinite(sig[has]))
        assert not np.any(meas[~has])
        summaries[variant] = json.loads((folder / "record.json").read_text())["feature_depth"]
        gate = json.loads((folder / "record.json").read_text())["chi2_gate"]
        assert gate["features_gated"] > 0 and 0.0 <= gate["rejected_fraction"] < 0.5
        assert 0.0 < gate["gamma_per_dof_median"] and gate["gamma_per_dof_mean"] >= gate["gamma_per_dof_median"] / 10
    raw, inp = summaries["depth-raw"], summaries["depth-inpainted"]
    assert raw["filled_fraction"] == 0.0 and "sigma_rel_median_filled" not in raw
    assert inp["filled_fraction"] > 0.0
    assert 0.0 <= inp["far_open_fill_fraction"] <= 1.0 and "far_open_fill_fraction" not in raw
    assert 0.0 <= inp["occlusion_edge_fill_fraction"] <= 1.0 - inp["far_open_fill_fraction"]
    assert inp["sigma_rel_median_filled"] > 3 * inp["sigma_rel_median_measured"]


def test_report_holds_table2_and_all_variants(runs_dir):
    md = (runs_dir / "report" / "report.md").read_text()
    html = (runs_dir / "report" / "report.html").read_text()
    assert "Table 2" in md and "tiny" in md
    for v in VARIANTS:
        assert v in md
    assert "<img" in html and "data:image/png;base64" in html
    assert "Depth given to the filter and its χ² gate" in md and "| tiny | depth-inpainted[telea] | 2 |" in md
    manifest = json.loads((runs_dir / "tiny" / "sequence.json").read_text())
    assert 0.0 < manifest["depth"]["hole_ratio_median"] < 1.0


def test_replay_loads_back_with_rerun(runs_dir, tmp_path):
    out = tmp_path / "tiny.rrd"
    assert main(["replay", str(runs_dir / "tiny" / "depth-raw" / "seed0"),
                 str(runs_dir / "tiny" / "depth-inpainted" / "seed0"), "--out", str(out), "--every", "3"]) == 0
    rows = recorded_entities(out)
    for entity in ("/camera/left", "/camera/depth_raw", "/camera/depth_inpainted", "/camera/depth_raw/holes",
                   "/camera/depth_error", "/world/gt", "/world/depth-raw_seed0/trajectory",
                   "/metrics/ate/depth-inpainted_seed0/error_at_gt"):
        assert entity in rows, f"{entity} missing"


def test_rerun_keeps_finished_runs(runs_dir):
    """run-sequence again on the same folder: every record exists, so nothing is recomputed."""
    before = {p: p.stat().st_mtime_ns for p in runs_dir.glob("tiny/*/seed*/record.json")}
    from pipeline.batch import Job, pending_jobs
    jobs = [Job("tiny", "tiny", v, s, str(runs_dir / "tiny" / v / f"seed{s}")) for v in VARIANTS for s in (0, 1)]
    done, pending = pending_jobs(jobs)
    assert not pending and len(done) == 8
    assert {p: p.stat().st_mtime_ns for p in runs_dir.glob("tiny/*/seed*/record.json")} == before


def test_demo_command_small(sim_cache, tmp_path, monkeypatch, capsys):
    """The demo's wiring on the tiny preset (the real demo runs three 12 s sequences, 5 runs, all variants)."""
    monkeypatch.setenv("AGRIVIO_CACHE", str(sim_cache))
    out = tmp_path / "demo"
    assert main(["demo", "--presets", "tiny", "--runs", "1", "--variants", "depth-raw,odometry", "--no-bench",
                 "--out", str(out), "--workers", "1", "--ladder-seeds", "1"]) == 0
    printed = capsys.readouterr().out
    assert "report:" in printed and "replay:" in printed and "depth oracle ladder:" in printed
    assert (out / "report" / "report.html").is_file()
    assert (out / "replay" / "tiny.rrd").is_file()
    md = (out / "report" / "report.md").read_text()
    ladder = json.loads((out / "depth_oracle.json").read_text())
    assert set(ladder["results"]) == {"tiny"} and ladder["seeds"] == [0] and ladder["methods"] == ["paper"]
    assert {"depth-raw", "exact-everywhere", "inpainted[paper]", "stereo"} <= set(ladder["results"]["tiny"])
    verdict = "**ladder monotone: yes**" if ladder["monotone"] else "**ladder monotone: no**"
    assert md.index("## Before / after") < md.index(verdict) < md.index("## All variants")


def test_experiment_command_two_methods_one_matrix_and_resumes(sim_cache, tmp_path, monkeypatch, capsys):
    """`agrivio experiment` runs depth-inpainted with each method beside the others (the first is Table 2's
    "after"), in one matrix; started again with the same arguments it recomputes nothing."""
    monkeypatch.setenv("AGRIVIO_CACHE", str(sim_cache))
    out = tmp_path / "exp"
    argv = ["experiment", "--scale", "demo", "--duration", "3", "--presets", "tiny", "--runs", "1",
            "--variants", "depth-raw,depth-inpainted", "--methods", "telea,ns", "--out", str(out), "--workers", "1"]
    assert main(argv) == 0
    folders = sorted(p.parent.parent.name for p in out.glob("tiny/*/seed0/record.json"))
    assert folders == ["depth-inpainted", "depth-inpainted-ns", "depth-raw"]
    methods = {json.loads(p.read_text())["inpaint_method"] for p in out.glob("tiny/depth-inpainted*/seed0/record.json")}
    assert methods == {"telea", "ns"}
    md = (out / "report" / "report.md").read_text()
    assert "depth-inpainted[ns]" in md and "depth-inpainted[telea]" in md
    assert "inpainting method `telea`" in md  # Table 2 compares the first method
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("tiny/*/seed0/record.json")}
    capsys.readouterr()
    assert main(argv) == 0
    assert {p: p.stat().st_mtime_ns for p in out.glob("tiny/*/seed0/record.json")} == stamps


def test_experiment_refuses_bad_options(capsys):
    assert main(["experiment", "--runs", "0", "--presets", "tiny"]) == 2
    assert "--runs" in capsys.readouterr().err
    assert main(["experiment", "--presets", "tiny", "--methods", "nope", "--duration", "3"]) == 2
    assert "unknown inpainting method 'nope'" in capsys.readouterr().err


def test_experiment_refuses_an_unknown_preset_before_any_work(tmp_path, monkeypatch, capsys):
    """A misspelt preset is said at once (exit 2, naming it and the presets there are), before a valid one next to it
    is simulated and before a report of failed runs is written."""
    monkeypatch.setenv("AGRIVIO_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "exp"
    assert main(["experiment", "--presets", "tiny,rosario-like-09", "--duration", "3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "rosario-like-09: neither a bag file" in err and "tiny" in err
    assert not out.exists() and not (tmp_path / "cache" / "sim").exists()
