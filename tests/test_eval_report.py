"""Run records, five-run statistics, the before/after comparison, the report and the two CLI commands."""

from __future__ import annotations

import base64
import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from eval.compare import compare_groups, fmt_pm, table2_markdown, variants_markdown
from eval.errors import EvalInputError
from eval.records import RunRecord, config_hash
from eval.report import build_report, markdown_to_html
from eval.statistics import MetricSummary, bootstrap_relative_change, summarize, welch_test
from eval.synthetic import field_path, perturbed_estimate, synthetic_runset
from eval.trajectory import Trajectory, format_tum
from pipeline.cli import main


def _rec(seq: str, variant: str, seed: int, rmse: float | None, method: str | None = None,
         reason: str | None = None) -> RunRecord:
    if rmse is None:
        return RunRecord(seq, variant, seed, status="failed", failure_reason=reason or "diverged",
                         inpaint_method=method)
    return RunRecord(seq, variant, seed, inpaint_method=method,
                     metrics={"ate_rmse_m": rmse, "ate_mean_m": 0.9 * rmse,
                              "rpe": {"10": {"delta_m": 10.0, "trans_rmse_m": rmse / 4}}})


RECORDS = ([_rec("rosario-01", "depth-raw", s, v) for s, v in enumerate([0.60, 0.62, 0.64, 0.66])]
           + [_rec("rosario-01", "depth-raw", 4, None, reason="FilterDivergedError: NaN in state")]
           + [_rec("rosario-01", "depth-inpainted", s, v, "paper")
              for s, v in enumerate([0.24, 0.25, 0.26, 0.25, 0.27])]
           + [_rec("rosario-01", "depth-inpainted", s, v, "telea") for s, v in enumerate([0.5, 0.52])]
           + [_rec("rosario-01", "odometry", s, 3.0 + s) for s in range(2)]
           + [_rec("rosario-02", "stereo", 0, 1.0)])


def test_record_round_trip_and_batch_compatibility() -> None:
    rec = RunRecord("seq", "depth-inpainted", 3, inpaint_method="paper", config_hash=config_hash({"a": 1}),
                    code_version="git:abc", metrics={"ate_rmse_m": 0.5, "ate_mean_m": float("nan")},
                    timings={"total_s": 1.5}, estimate_path="estimate.tum", gt_path="../gt.tum",
                    extra={"host": "x"})
    d = json.loads(json.dumps(rec.to_dict()))
    assert d["record_type"] == "run" and d["schema_version"] == 1 and d["host"] == "x"
    back = RunRecord.from_dict(d)
    assert back.to_dict() == rec.to_dict()
    assert back.metric("ate_rmse_m") == 0.5 and back.metric("ate_mean_m") is None
    # the batch runner's failed record (pipeline.batch.failed_record) parses: the layout of an ok record
    batch = {"record_type": "run", "sequence": "s", "variant": "depth-inpainted", "seed": 2, "status": "failed",
             "failure_reason": "worker died", "inpaint_method": "telea", "timings": {},
             "job": {"source": "s.bag", "inpaint_method": "telea"}}
    fr = RunRecord.from_dict(batch)
    assert not fr.ok and fr.inpaint_method == "telea" and fr.display_variant() == "depth-inpainted[telea]"
    assert fr.extra["job"]["inpaint_method"] == "telea"
    with pytest.raises(EvalInputError, match="f.json: run record lacks variant"):
        RunRecord.from_dict({"record_type": "run", "sequence": "s"}, source="f.json")
    with pytest.raises(EvalInputError, match="status"):
        RunRecord("s", "v", 0, status="maybe")


def test_config_hash_is_stable() -> None:
    assert config_hash({"a": 1, "b": [1, 2]}) == config_hash({"b": (1, 2), "a": 1})
    assert config_hash({"a": np.float64(0.5)}) == config_hash({"a": 0.5})
    assert config_hash({"a": 1}) != config_hash({"a": 2})
    assert re.fullmatch(r"[0-9a-f]{16}", config_hash({}))


def test_summary_counts_failed_runs() -> None:
    groups = summarize(RECORDS)
    keys = [(g.sequence, g.variant) for g in groups]
    assert keys == [("rosario-01", "depth-raw"), ("rosario-01", "depth-inpainted"),
                    ("rosario-01", "depth-inpainted[telea]"), ("rosario-01", "odometry"), ("rosario-02", "stereo")]
    raw = groups[0]
    assert (raw.n_runs, raw.n_ok, raw.n_failed) == (5, 4, 1)
    assert raw.failures == ((4, "FilterDivergedError: NaN in state"),)
    s = raw.metrics["ate_rmse_m"]
    assert s.n == 4 and s.mean == pytest.approx(0.63) and s.min == 0.60 and s.max == 0.66
    assert s.std == pytest.approx(np.std([0.60, 0.62, 0.64, 0.66], ddof=1))
    single = MetricSummary.of([1.0])
    assert single.n == 1 and math.isnan(single.std)


def test_significance_helpers() -> None:
    t, p = welch_test([0.60, 0.62, 0.64, 0.66], [0.24, 0.25, 0.26, 0.25, 0.27])
    assert t < 0 and p < 1e-4
    assert welch_test([1.0], [2.0, 3.0]) is None
    lo, hi = bootstrap_relative_change([0.60, 0.62, 0.64, 0.66], [0.24, 0.25, 0.26, 0.25, 0.27], seed=0)
    assert -0.65 < lo < hi < -0.55
    assert bootstrap_relative_change([1.0, 2.0], [1.0, 2.0], seed=1) == bootstrap_relative_change([1.0, 2.0],
                                                                                                 [1.0, 2.0], seed=1)


def test_comparison_table_shows_failed_run() -> None:
    rows = compare_groups(summarize(RECORDS))
    assert [r.sequence for r in rows] == ["rosario-01"]
    row = rows[0]
    assert row.rmse_change == pytest.approx(0.254 / 0.63 - 1.0)
    assert row.welch is not None and row.welch[1] < 0.05
    assert "significant" in row.note and "1 failed run" in row.note
    md = table2_markdown(rows)
    assert "4/5 (**1 failed**)" in md and "0.630 ± 0.026" in md and "-59.7 %" in md
    allv = variants_markdown(summarize(RECORDS))
    assert "seed 4: FilterDivergedError: NaN in state" in allv
    assert "| rosario-02 | stereo | 1/1 | 0 | 0.900 | 1.000 |" in allv


def test_report_markdown_and_html() -> None:
    gt = field_path(duration_s=40.0, rate_hz=5.0)
    from eval.evaluate import evaluate

    gps = Trajectory.from_positions(gt.stamps_s, gt.positions)
    evs = {("rosario-01", "depth-raw"): evaluate(gps, perturbed_estimate(gt, seed=1)),
           ("rosario-01", "depth-inpainted"): evaluate(gps, perturbed_estimate(gt, seed=2, drift_m_per_sqrt_s=0.01))}
    bench = "| method | RMSE (m) |\n|---|---|\n| paper | 0.41 |\n| telea \\| ns | 0.52 |\n"
    report = build_report(RECORDS, evs, inpaint_bench_md=bench, notes=["x.json: unreadable record"])
    names = [f.name for f in report.figures]
    assert names == ["rosario-01_ate_box", "rosario-01_top_view", "rosario-01_error_time", "rosario-01_rpe",
                     "rosario-02_ate_box", "rosario-02_rpe"]
    for f in report.figures:
        assert f.png.startswith(b"\x89PNG\r\n\x1a\n")
    md = report.markdown("figures")
    assert "![rosario-01: ATE RMSE per run" in md and "(figures/rosario-01_ate_box.png)" in md
    assert "## Inpainting benchmark" in md and "| paper | 0.41 |" in md and "**1 failed**" in md
    html = report.html()
    assert html.startswith("<!DOCTYPE html>") and html.count("data:image/png;base64,") == len(report.figures)
    assert not re.search(r"(src|href)=['\"]https?:", html)  # self-contained
    assert "<strong>1 failed</strong>" in html and "class='failed'" in html
    assert "<td>telea | ns</td>" in html
    first = re.search(r"base64,([A-Za-z0-9+/=]+)'", html).group(1)
    assert base64.b64decode(first) == report.figures[0].png
    summary = json.loads(json.dumps(report.summary()))
    assert summary["groups"][0]["n_failed"] == 1
    # deterministic figures
    again = build_report(RECORDS, evs, inpaint_bench_md=bench)
    assert [f.png for f in again.figures] == [f.png for f in report.figures]


def test_markdown_to_html_basics() -> None:
    out = markdown_to_html("# Title\n\nsome **bold** `code`\n\n```\n<raw>\n```\n| a | b |\n|:--|--:|\n| 1 | 2 |\n")
    assert "<h3>Title</h3>" in out and "<strong>bold</strong>" in out and "<code>code</code>" in out
    assert "&lt;raw&gt;" in out and "<th>a</th>" in out and "<td>2</td>" in out


def test_markdown_to_html_turns_consecutive_dash_lines_into_one_list() -> None:
    out = markdown_to_html("**verdict**\n\n- first `a`\n- second\n\nafter\n")
    assert "<ul><li>first <code>a</code></li><li>second</li></ul>" in out
    assert out.index("<strong>verdict</strong>") < out.index("<ul>") < out.index("<p>after</p>")


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    files = synthetic_runset(sequences=("sim-01",), variants=("depth-raw", "depth-inpainted", "odometry"),
                             n_seeds=3, failed=(("sim-01", "depth-raw", 1),), duration_s=60.0)
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    (root / "notes.json").write_text('{"not": "a record"}')
    (root / "broken_record.json").write_text("{truncated")
    (root / "inpaint_bench.md").write_text("| method | hole RMSE (m) |\n|---|---|\n| paper | 0.123 |\n")
    return root


def test_compare_command(runs_dir: Path, capsys) -> None:
    out = runs_dir / "out"
    assert main(["compare", str(runs_dir), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "9 run record(s) (1 failed)" in printed and "unreadable record" in printed
    md = (out / "report.md").read_text()
    assert "| sim-01 | 2/3 (**1 failed**) |" in md and "| paper | 0.123 |" in md
    assert "seed 1: FilterDivergedError" in md
    figures = sorted(p.name for p in (out / "figures").iterdir())
    assert figures == ["sim-01_ate_box.png", "sim-01_error_time.png", "sim-01_rpe.png", "sim-01_top_view.png"]
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4
    summary = json.loads((out / "summary.json").read_text())
    assert [g["variant"] for g in summary["groups"]] == ["depth-raw", "depth-inpainted", "odometry"]
    assert summary["groups"][0]["n_failed"] == 1 and summary["groups"][0]["n_ok"] == 2
    # running again over the same folder ignores the report it wrote (summary.json is not a run record)
    assert main(["compare", str(runs_dir), "--out", str(out), "--no-trajectories"]) == 0
    assert "9 run record(s)" in capsys.readouterr().out


def test_compare_errors(tmp_path, capsys) -> None:
    assert main(["compare", str(tmp_path / "missing")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["compare", str(tmp_path)]) == 2
    assert "no run records" in capsys.readouterr().err


def test_evaluate_command(tmp_path, capsys) -> None:
    gt = field_path(duration_s=60.0, rate_hz=5.0)
    est = perturbed_estimate(field_path(duration_s=60.0, rate_hz=15.0), seed=0, time_offset_s=0.003)
    (tmp_path / "gt.tum").write_text(format_tum(Trajectory.from_positions(gt.stamps_s, gt.positions)))
    (tmp_path / "est.tum").write_text(format_tum(est))
    assert main(["evaluate", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum"), "--align", "sim3", "--rpe", "5",
                 "10", "--json", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "(position only)" in out and "alignment    sim3" in out and "ATE translation (m)" in out
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["metrics"]["align"] == "sim3" and set(m["metrics"]["rpe"]) == {"5", "10"}
    (tmp_path / "bad.tum").write_text("1.0 0 0 0 0 0 0 1\nx\n")
    assert main(["evaluate", str(tmp_path / "bad.tum"), str(tmp_path / "gt.tum")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'bad.tum'}:2:" in err and "Traceback" not in err
    late = Trajectory(est.stamps_s + 1000.0, est.positions, est.quats_xyzw)
    (tmp_path / "late.tum").write_text(format_tum(late))
    assert main(["evaluate", str(tmp_path / "late.tum"), str(tmp_path / "gt.tum")]) == 2
    assert "no overlap in time" in capsys.readouterr().err


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


@pytest.mark.skipif(_chromium() is None, reason="headless Chromium not installed (apt-get install chromium)")
def test_report_renders_in_headless_chromium(runs_dir: Path, tmp_path) -> None:
    out = runs_dir / "out_chromium"
    assert main(["compare", str(runs_dir), "--out", str(out), "--no-trajectories"]) == 0
    shot = tmp_path / "shot.png"
    script = Path(__file__).resolve().parents[1] / "scripts" / "screenshot_report.sh"
    proc = subprocess.run(["bash", str(script), str(out / "report.html"), str(shot)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert shot.read_bytes().startswith(b"\x89PNG") and shot.stat().st_size > 20_000


def test_mean_std_keeps_two_significant_digits_of_a_small_spread():
    tight = MetricSummary.of([0.0290, 0.0292, 0.0289, 0.0291, 0.0290])
    assert fmt_pm(tight) == "0.029 ± 0.00011"  # std 1.14e-4 m: not "± 0.000"
    assert fmt_pm(MetricSummary.of([0.60, 0.65, 0.63])) == "0.627 ± 0.025"
    assert fmt_pm(MetricSummary.of([0.5, 0.5])) == "0.500 ± 0.000"
    same = MetricSummary.of([0.4805, 0.4805, 0.4805, 0.4805, 0.4805])  # identical runs: std is float noise, if any
    assert fmt_pm(same).endswith("± 0.000")
    noise = MetricSummary(n=5, mean=0.481, std=1.1e-17, min=0.481, max=0.481, values=(0.481,) * 5)
    assert fmt_pm(noise) == "0.481 ± 0.000"
    assert fmt_pm(MetricSummary.of([0.4])) == "0.400"


def test_variants_table_gives_ate_as_a_share_of_the_distance_driven():
    """Long sequences are judged by drift over distance: the variants table states ATE RMSE as % of the
    reference path length (derived from each record, so older records get it too)."""
    from eval.compare import variants_table
    from eval.records import RunRecord
    from eval.statistics import summarize

    recs = [RunRecord("s", "stereo", k, metrics={"ate_rmse_m": 0.5 + 0.1 * k, "ref_path_length_m": 100.0})
            for k in range(3)]
    recs.append(RunRecord("s", "depth-raw", 0, metrics={"ate_rmse_m": 0.5}))          # no path length: no share
    assert recs[0].metric("ate_rmse_pct_distance") == pytest.approx(0.5)
    header, body = variants_table(summarize(recs))
    col = header.index("ATE RMSE (% of distance)")
    rows = {r[1]: r for r in body}
    assert rows["stereo"][col] == "0.60 %" and rows["depth-raw"][col] == "–"


def test_long_sequence_rpe_table_per_distance_and_its_report_section() -> None:
    from eval.rpe_table import rpe_table

    def rec(variant: str, seed: int, e10: float, e50: float | None) -> RunRecord:
        rpe = {"10": {"delta_m": 10.0, "trans_rmse_m": e10, "drift_mean_pct": 10 * e10}}
        if e50 is not None:
            rpe["50"] = {"delta_m": 50.0, "trans_rmse_m": e50, "drift_mean_pct": 2 * e50}
        return RunRecord("field", variant, seed, metrics={"ate_rmse_m": 1.0, "ate_mean_m": 0.9, "rpe": rpe,
                                                          "ref_path_length_m": 120.0 + seed})
    records = [rec("depth-raw", 0, 0.2, 1.0), rec("depth-raw", 1, 0.4, 1.4), rec("stereo", 0, 0.1, None),
               RunRecord("field", "stereo", 1, status="failed", failure_reason="diverged")]
    header, body = rpe_table(records)
    assert header[-2:] == ["RPE 10 m (m, drift %)", "RPE 50 m (m, drift %)"]  # no run reached 100 m segments
    rows = {r[1]: r for r in body}
    assert rows["depth-raw"][2:] == ["2", "120", "0.300 ± 0.141 (3.00 %)", "1.200 ± 0.283 (2.40 %)"]
    assert rows["stereo"][2:] == ["1", "120", "0.100 (1.00 %)", "–"]  # the failed run is not a sample
    md = build_report(records).markdown("figures")
    assert "## Relative pose error over distance" in md and "0.300 ± 0.141 (3.00 %)" in md
    # short clips (RPE only at fractions of their path) get no such table
    assert rpe_table([_rec("s", "stereo", 0, 0.1)]) is not None  # 10 m present in _rec
    short = RunRecord("s", "stereo", 0, metrics={"ate_rmse_m": 0.1, "rpe": {"0.4": {"delta_m": 0.4,
                                                                                   "trans_rmse_m": 0.01}}})
    assert rpe_table([short]) is None


def test_figures_switch_to_a_log_axis_when_variants_differ_by_orders_of_magnitude() -> None:
    """Wheel odometry's ≈ 10 m next to the VIO's ≈ 0.1 m: a linear axis flattens the VIO variants onto zero."""
    import io

    from matplotlib.image import imread

    from eval.plots import plot_ate_boxplot, wants_log_scale

    assert wants_log_scale([np.array([0.15, 0.16]), np.array([0.6, 0.9]), np.array([8.4, 8.4])])
    assert not wants_log_scale([np.array([0.15, 0.16]), np.array([0.6, 0.9])])          # 5×: stays linear
    assert not wants_log_scale([np.array([0.0, np.nan]), np.array([9.0])])              # one usable series
    wide = plot_ate_boxplot({"stereo": [0.15, 0.16], "odometry": [8.4, 8.5]})
    close = plot_ate_boxplot({"stereo": [0.15, 0.16], "odometry": [0.3, 0.31]})
    assert imread(io.BytesIO(wide)).ndim == 3 and imread(io.BytesIO(close)).ndim == 3  # both render
