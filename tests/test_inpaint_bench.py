"""The inpainting benchmark: tables, JSON, figure and the CLI command, on tiny frames."""

import json

import numpy as np

from pipeline.cli import main
from pipeline.inpaint_bench import figure_png, procedural_frames, run_bench, to_json, to_markdown


def test_bench_tables_and_figure():
    frames = procedural_frames(2, seed=1, height=48, width=80)
    res = run_bench(frames, ["ns", "paper"], {"paper": {"fusion": "mean"}})
    md = to_markdown(res)
    assert "## RMSE (m, holes)" in md and "| **average** |" in md and "proc00" in md and "proc01" in md
    assert "Median time per frame" in md and "whole image" in md
    js = to_json(res)
    assert set(js["average"]) == {"ns", "paper"}
    m = js["frames"][0]["methods"]["ns"]
    assert m["rmse_hole"] > 0 and m["seconds"] > 0 and 0 <= m["ssim_hole"] <= 1
    assert js["median_seconds"]["paper"] > 0
    png = figure_png(res)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    # every method leaves known pixels as they were
    for f in frames:
        for meth in ("ns", "paper"):
            out = res.outputs[(f.name, meth)]
            assert np.array_equal(out[~f.mask], f.depth_gt[~f.mask])


def test_cli_writes_results(tmp_path, capsys):
    rc = main(["inpaint-bench", "--source", "procedural", "--frames", "1", "--methods", "ns,ipbasic",
               "--out", str(tmp_path), "--quiet"])
    assert rc == 0
    js = json.loads((tmp_path / "results.json").read_text())
    assert js["source"] == "procedural" and js["methods"] == ["ns", "ipbasic"]
    assert (tmp_path / "grid.png").stat().st_size > 0 and "RMSE" in (tmp_path / "results.md").read_text()


def test_cli_rejects_unknown_method(tmp_path, capsys):
    rc = main(["inpaint-bench", "--source", "procedural", "--frames", "1", "--methods", "deepfill",
               "--out", str(tmp_path), "--quiet"])
    assert rc == 2
    assert "unknown method" in capsys.readouterr().err


def test_method_specs_for_ablations():
    from pipeline.inpaint_bench import parse_method

    assert parse_method("ns") == ("ns", {})
    assert parse_method("paper:fusion=mean,single_scale=true,block=9,w_depth=0.5") == (
        "paper", {"fusion": "mean", "single_scale": True, "block": 9, "w_depth": 0.5})
    frames = procedural_frames(1, seed=2, height=48, width=80)
    res = run_bench(frames, ["paper:fusion=mean", "paper:fusion=best,single_scale=true"])
    assert set(to_json(res)["average"]) == {"paper:fusion=mean", "paper:fusion=best,single_scale=true"}


def test_sim_frames_use_real_sgbm_masks_on_rendered_ground_truth(tmp_path, monkeypatch):
    from pipeline.inpaint_bench import sim_frames

    monkeypatch.setenv("AGRIVIO_CACHE", str(tmp_path))
    (f,) = sim_frames(1, seed=0, presets=("tiny",))
    assert f.depth_gt.shape == (376, 672) and f.mask.shape == (376, 672)
    assert "SGBM" in f.source
    assert 0.05 < f.mask.mean() < 0.9  # stereo leaves holes, but not everywhere
    assert f.mask[:, :60].mean() > 0.9  # the unmatched left band of StereoSGBM
    assert (f.valid == np.isfinite(f.depth_gt)).all() and f.valid.mean() > 0.3
    res = run_bench([f], ["ns"])
    assert res.metrics[(f.name, "ns")].n_hole > 1000
