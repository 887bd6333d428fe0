"""``agrivio simulate`` / ``sim-realism`` command lines and the config round trip."""

from __future__ import annotations

import json

import pytest

from pipeline.cli import main
from pipeline.errors import AgrivioError
from pipeline.sim import open_sequence
from pipeline.sim.config import SimConfig
from pipeline.sim.presets import get_preset, preset_names


def test_config_round_trips_through_json() -> None:
    for name in preset_names():
        cfg = get_preset(name)
        back = SimConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
        assert back == cfg
    with pytest.raises(ValueError, match="unknown"):
        SimConfig.from_dict({"field": {"row_spacing": 0.5}})
    tilts = {n: get_preset(n).camera.tilt_deg for n in ("rosario-like-01", "rosario-like-02", "rosario-like-03")}
    assert tilts == {"rosario-like-01": 19.0, "rosario-like-02": 12.0, "rosario-like-03": 7.0}


def test_simulate_command_with_config_patch(tmp_path, capsys) -> None:
    patch = tmp_path / "patch.json"
    patch.write_text(json.dumps({"camera": {"tilt_deg": 15.0}, "lighting": {"cloud_cover": 0.6}}))
    out = tmp_path / "seq"
    code = main(["simulate", "tiny", "--config", str(patch), "--duration", "2.3", "--max-frames", "1", "--out",
                 str(out), "--workers", "1", "--quiet", "--seed", "4", "--ae-warmup", "1"])
    assert code == 0
    seq = open_sequence(out)
    assert seq.config.camera.tilt_deg == 15.0 and seq.config.lighting.cloud_cover == 0.6
    assert seq.n_frames == 1 and seq.bag_path.is_file()
    assert "tiny.bag" in capsys.readouterr().out


def test_user_errors_exit_2(tmp_path, capsys) -> None:
    assert main(["simulate", "no-such-preset", "--out", str(tmp_path / "x")]) == 2
    assert "unknown simulator preset" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"field": {"nope": 1}}')
    assert main(["simulate", "tiny", "--config", str(bad), "--out", str(tmp_path / "y")]) == 2
    assert "nope" in capsys.readouterr().err
    with pytest.raises(AgrivioError, match="not a finished simulated sequence"):
        open_sequence(tmp_path / "missing")
