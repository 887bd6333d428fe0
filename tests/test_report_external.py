"""``agrivio compare --external NAME=path.tum``: another system's trajectory as a row and a path of the report,
evaluated with the runs' association and alignment, marked as external; bad specs are one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from eval.evaluate import EvalOptions, evaluate
from eval.synthetic import field_path, perturbed_estimate, synthetic_runset
from eval.trajectory import format_tum, read_tum
from pipeline.cli import main


def _runs(root: Path, sequences: tuple[str, ...] = ("sim-01",)) -> Path:
    files = synthetic_runset(sequences=sequences, variants=("depth-raw", "depth-inpainted"), n_seeds=2, failed=(),
                             duration_s=30.0)
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def _external(path: Path, gt_path: Path) -> Path:
    gt = read_tum(gt_path)
    body = field_path(duration_s=gt.duration_s, rate_hz=20.0, row_length_m=30.0, t0_s=float(gt.stamps_s[0]))
    path.write_text(format_tum(perturbed_estimate(body, seed=7, noise_m=0.03)))
    return path


def test_compare_adds_external_rows(tmp_path, capsys):
    runs = _runs(tmp_path / "runs")
    ext = _external(tmp_path / "openvins.tum", runs / "sim-01" / "gt.tum")
    out = tmp_path / "report"
    assert main(["compare", str(runs), "--out", str(out), "--external", f"openvins={ext}"]) == 0
    capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    groups = {g["variant"]: g for g in summary["groups"]}
    assert "external: openvins" in groups
    # the same association and alignment as the runs (the record's options: SE(3), 20 ms)
    expected = evaluate(read_tum(runs / "sim-01" / "gt.tum"), read_tum(ext), EvalOptions()).ate.trans.rmse
    got = groups["external: openvins"]["metrics"]["ate_rmse_m"]["mean"]
    assert got == pytest.approx(expected, rel=1e-9)
    md = (out / "report.md").read_text()
    assert "| sim-01 | external: openvins | 1/1 |" in md
    assert "is an external estimate" in md and str(ext) in md
    html = (out / "report.html").read_text()
    assert "external: openvins" in html


@pytest.mark.parametrize("spec, message", [
    ("openvins", "expected NAME=path.tum"),
    ("=x.tum", "expected NAME=path.tum"),
    ("x=MISSING", "not found"),
    ("x=BAD", "BAD:2:"),
    ("x@nope=GOOD", "no successful run of sequence 'nope'"),
])
def test_compare_external_errors_are_one_line(tmp_path, capsys, spec, message):
    runs = _runs(tmp_path / "runs")
    bad = tmp_path / "bad.tum"
    bad.write_text("1.0 0 0 0 0 0 0 1\nnot a pose\n")
    good = _external(tmp_path / "good.tum", runs / "sim-01" / "gt.tum")
    spec = spec.replace("MISSING", str(tmp_path / "missing.tum")).replace("BAD", str(bad)).replace("GOOD", str(good))
    message = message.replace("BAD", str(bad))
    assert main(["compare", str(runs), "--out", str(tmp_path / "r"), "--external", spec]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_external_needs_a_sequence_when_there_are_several(tmp_path, capsys):
    runs = _runs(tmp_path / "runs", ("sim-01", "sim-02"))
    ext = _external(tmp_path / "e.tum", runs / "sim-01" / "gt.tum")
    assert main(["compare", str(runs), "--out", str(tmp_path / "r"), "--external", f"e={ext}"]) == 2
    assert "name one: e@SEQUENCE=" in capsys.readouterr().err
    assert main(["compare", str(runs), "--out", str(tmp_path / "r"), "--external", f"e@sim-01={ext}"]) == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert [g["sequence"] for g in summary["groups"] if g["variant"] == "external: e"] == ["sim-01"]
    assert np.isfinite(next(g for g in summary["groups"] if g["variant"] == "external: e")
                       ["metrics"]["ate_rmse_m"]["mean"])
