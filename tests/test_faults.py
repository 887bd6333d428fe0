"""Faults survived (issue 13, "run integrity"): one test per fault, each failing without its fix.

Tiny generated bags (6 frames, a few hundred kB) and the ``odometry`` variant keep each test to seconds; the
runs go through the real CLI with the serial executor, so monkeypatched faults reach the run code in-process.
"""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.bag_reader import RosarioSequence
from pipeline.bag_writer import RosarioBagWriter
from pipeline.cli import main
from pipeline.synthetic_scene import write_synthetic_bag

T0_NS = 1_600_000_000_000_000_000


@pytest.fixture()
def cache(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv("AGRIVIO_CACHE", str(root))
    return root


def _bag(path: Path, seed: int = 3, n_frames: int = 6) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_synthetic_bag(path, n_frames=n_frames, seed=seed, overwrite=True)
    return path


def _gt(path: Path, t0_s: float = T0_NS / 1e9, n: int = 6, dt: float = 0.2) -> Path:
    lines = [f"{t0_s + i * dt:.6f} {0.1 * i:.3f} {0.02 * i * i:.4f} 0 0 0 0 1" for i in range(n)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _run(bag: Path, out: Path, *extra: str, variants: str = "odometry", runs: int = 1) -> int:
    return main(["run-sequence", str(bag), "--out", str(out), "--variants", variants, "--runs", str(runs),
                 "--executor", "serial", *extra])


def _error_line(err: str) -> str:
    """The one ``agrivio: error`` line of a command's stderr (warnings and progress bars aside); no traceback."""
    assert "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ln.startswith("agrivio: error")]
    return line


def _record(out: Path, seq: str = "seq", variant: str = "odometry", seed: int = 0) -> dict:
    return json.loads((out / seq / variant / f"seed{seed}" / "record.json").read_text())


# ---- 1. stale records -------------------------------------------------------------------------------------------
def test_01_records_of_other_inputs_are_recomputed_not_reused(tmp_path, cache, capsys):
    out = tmp_path / "runs"
    bag_a = _bag(tmp_path / "a" / "seq.bag", seed=3)
    bag_b = _bag(tmp_path / "b" / "seq.bag", seed=4, n_frames=5)  # another bag of the same name
    assert _run(bag_a, out) == 0
    first = _record(out)
    assert first["input_key"] and first["input_key_parts"]["bag"] == RosarioSequence(bag_a).identity()
    assert _run(bag_a, out) == 0
    assert _record(out)["timings"] == first["timings"]  # same inputs: reused, not rerun
    assert _run(bag_b, out) == 0
    second = _record(out)
    assert second["input_key_parts"]["bag"] == RosarioSequence(bag_b).identity() != first["input_key_parts"]["bag"]
    assert "recomputed" in capsys.readouterr().err
    assert _run(bag_b, out, "--max-frames", "3") == 0
    assert _record(out)["input_key_parts"]["max_frames"] == 3
    assert _record(out)["input_key"] in (out / "report" / "report.md").read_text()  # the key is in the report


# ---- 2. duplicated runs in compare ------------------------------------------------------------------------------
def _fake_record(folder: Path, variant: str, seed: int, rmse: float, key: str = "k1") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "record.json").write_text(json.dumps({
        "record_type": "run", "sequence": "s", "variant": variant, "seed": seed, "status": "ok",
        "inpaint_method": "paper" if variant == "depth-inpainted" else None, "input_key": f"{key}-{variant}-{seed}",
        "metrics": {"ate_rmse_m": rmse, "ate_mean_m": rmse}}))


def test_02_compare_counts_a_copied_run_folder_once_and_refuses_conflicts(tmp_path, capsys):
    runs = tmp_path / "runs"
    for seed, (raw, filled) in enumerate([(0.50, 0.30), (0.52, 0.31)]):
        _fake_record(runs / "a" / "depth-raw" / f"seed{seed}", "depth-raw", seed, raw)
        _fake_record(runs / "a" / "depth-inpainted" / f"seed{seed}", "depth-inpainted", seed, filled)
    shutil.copytree(runs / "a", runs / "copy")
    assert main(["compare", str(runs), "--no-trajectories"]) == 0
    captured = capsys.readouterr()
    assert "duplicate record" in captured.err
    md = (runs / "report" / "report.md").read_text()
    assert "2/2" in md and "4/4" not in md
    _fake_record(runs / "copy" / "depth-raw" / "seed0", "depth-raw", 0, 0.9)  # same run, other result
    assert main(["compare", str(runs), "--no-trajectories"]) == 2
    err = _error_line(capsys.readouterr().err)
    assert str(runs / "a" / "depth-raw" / "seed0") in err and str(runs / "copy" / "depth-raw" / "seed0") in err


# ---- 3. failed records are retried ------------------------------------------------------------------------------
def test_03_failed_runs_are_retried_on_the_next_invocation(tmp_path, cache, monkeypatch):
    out = tmp_path / "runs"
    bag = _bag(tmp_path / "seq.bag")
    import pipeline.run_job as rj

    real = rj.run_odometry_ekf

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rj, "run_odometry_ekf", disk_full)
    assert _run(bag, out) == 1
    assert "No space left" in _record(out)["failure_reason"]
    monkeypatch.setattr(rj, "run_odometry_ekf", real)  # the disk was cleaned up
    assert _run(bag, out, "--keep-failed") == 1  # asked to keep the failure: kept
    assert _record(out)["status"] == "failed"
    assert _run(bag, out) == 0  # by default a failed record is retried
    assert _record(out)["status"] == "ok"


# ---- 4. exit status when runs failed ----------------------------------------------------------------------------
def test_04_run_sequence_exits_nonzero_when_a_run_failed(tmp_path, cache, capsys):
    out = tmp_path / "runs"
    bag = _bag(tmp_path / "seq.bag")
    # 6 frames (0.4 s) are far too short for the MSCKF's static initialisation: that run fails
    assert _run(bag, out, variants="odometry,depth-raw") == 1
    assert "1 of 2 run(s) failed" in capsys.readouterr().err
    assert (out / "report" / "report.html").is_file()  # the report is still written


# ---- 13. --max-frames reaches every stage -----------------------------------------------------------------------
def test_13_max_frames_limits_depth_and_inpainting_too(tmp_path, cache):
    out = tmp_path / "runs"
    bag = _bag(tmp_path / "seq.bag")
    _run(bag, out, "--max-frames", "2", "--inpaint", "telea", variants="depth-inpainted")
    manifest = json.loads((out / "seq" / "sequence.json").read_text())
    assert manifest["depth"]["frames"] == 2
    assert manifest["depth"]["inpainted_frames"] == {"computed": 2, "cached": 0}
    assert manifest["depth"]["depth_frames"] == {"computed": 2, "cached": 0}
    record = _record(out, variant="depth-inpainted")
    assert record["input_key_parts"]["max_frames"] == 2
    assert "depth cache is missing" not in (record.get("failure_reason") or "")


# ---- 6. the MSCKF config is validated up front ------------------------------------------------------------------
@pytest.mark.parametrize("text, word", [("no_such_key: 1\n", "no_such_key"), ("feature_noise: -1\n", "feature_noise"),
                                        ("max_cam_state_size: many\n", "max_cam_state_size")])
def test_06_bad_msckf_config_is_refused_before_any_compute(tmp_path, cache, capsys, text, word):
    bag = _bag(tmp_path / "seq.bag")
    config = tmp_path / "msckf.yaml"
    config.write_text(text)
    assert _run(bag, tmp_path / "runs", "--config", str(config), variants="depth-raw") == 2
    err = _error_line(capsys.readouterr().err)
    assert str(config) in err and word in err
    assert not (cache / "depth").exists()  # no depth computed
    assert not list((tmp_path / "runs").rglob("record.json"))


# ---- 7. the GT file is validated up front -----------------------------------------------------------------------
def test_07_bad_ground_truth_is_refused_before_any_compute(tmp_path, cache, capsys):
    bag = _bag(tmp_path / "seq.bag")
    malformed = _gt(tmp_path / "gt_bad.txt")
    lines = malformed.read_text().splitlines()
    lines[3] = "1600000000.6 0.3 0 0 0 0 oops 1"
    malformed.write_text("\n".join(lines) + "\n")
    header = tmp_path / "gt_header.txt"
    header.write_text("timestamp x y z qx qy qz qw\n" + _gt(tmp_path / "g.txt").read_text())
    bom = tmp_path / "gt_bom.txt"
    bom.write_bytes(b"\xef\xbb\xbf" + _gt(tmp_path / "g2.txt").read_bytes())
    far = _gt(tmp_path / "gt_far.txt", t0_s=T0_NS / 1e9 + 3600.0)
    short = _gt(tmp_path / "gt_short.txt", n=2)
    for gt, where in ((malformed, f"{malformed}:4"), (header, f"{header}:1"), (bom, f"{bom}:1"),
                      (far, "no time overlap"), (short, "at least 3")):
        assert _run(bag, tmp_path / "runs", "--gt", str(gt), variants="depth-raw") == 2, gt
        err = _error_line(capsys.readouterr().err)
        assert where in err, err
    assert not (cache / "depth").exists()
    assert _run(bag, tmp_path / "runs", "--gt", str(_gt(tmp_path / "good.txt"))) == 0


# ---- 8. batch YAML types and ranges -----------------------------------------------------------------------------
@pytest.mark.parametrize("line, key", [("runs: two", "runs"), ("workers: many", "workers"),
                                       ("max_frames: '20'", "max_frames"), ("max_frames: -5", "max_frames"),
                                       ("seeds: 3", "seeds")])
def test_08_batch_yaml_types_and_ranges_are_checked(tmp_path, cache, capsys, line, key):
    config = tmp_path / "batch.yaml"
    config.write_text(f"out: runs\nsequences: [tiny]\n{line}\n")
    assert main(["batch", str(config)]) == 2
    err = _error_line(capsys.readouterr().err)
    assert str(config) in err and key in err
    config.write_text("out: runs\nsequences: tiny\n")
    assert main(["batch", str(config)]) == 2
    assert "'sequences' must be a list" in capsys.readouterr().err


# ---- 9. one bad bag does not stop a batch -----------------------------------------------------------------------
def test_09_a_truncated_bag_fails_its_sequence_and_the_batch_goes_on(tmp_path, cache, capsys):
    good = _bag(tmp_path / "good.bag")
    data = good.read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2])
    config = tmp_path / "batch.yaml"
    config.write_text("out: runs\nruns: 1\nvariants: [odometry]\nexecutor: serial\n"
                      "sequences: [{source: cut.bag}, {source: good.bag}]\n")
    assert main(["batch", str(config)]) == 1
    assert "1 of 2 run(s) failed" in capsys.readouterr().err
    assert _record(tmp_path / "runs", "good")["status"] == "ok"
    bad = _record(tmp_path / "runs", "cut")
    assert bad["status"] == "failed" and "truncated" in bad["failure_reason"]


# ---- 5. disk full / unwritable output ---------------------------------------------------------------------------
def test_05_disk_full_while_writing_the_report_is_one_line_and_keeps_the_runs(tmp_path, cache, capsys, monkeypatch):
    out = tmp_path / "runs"
    bag = _bag(tmp_path / "seq.bag")
    import pipeline.report_stage as compare
    from pipeline.atomic import atomic_path

    def full(target, text):
        with atomic_path(target) as tmp:
            tmp.write_text(text[:10])
            raise OSError(errno.ENOSPC, "No space left on device")  # what write() raises: no file name

    monkeypatch.setattr(compare, "write_text_atomic", full)
    assert _run(bag, out) == 2
    err = capsys.readouterr().err.strip()
    line = _error_line(err)
    assert "No space left on device" in line and str(out / "report") in line
    assert _record(out)["status"] == "ok"  # the run is kept
    assert not list((out / "report").glob(".report*"))  # no temporary left behind

    import pipeline.validate as validate

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", kwargs.get("dir"))

    monkeypatch.setattr(validate.tempfile, "mkstemp", denied)
    assert _run(bag, tmp_path / "ro") == 2
    assert "not writable" in capsys.readouterr().err


# ---- 11. depth frames are joined by stamp -----------------------------------------------------------------------
def test_11_depth_frames_are_joined_to_bag_frames_by_stamp(tmp_path, cache):
    import dataclasses

    from pipeline.depth import DepthParams
    from pipeline.depth_cache import DepthCache, depth_stream

    out = tmp_path / "runs"
    bag = _bag(tmp_path / "seq.bag")
    seq = RosarioSequence(bag)
    frames = list(depth_stream(seq, DepthParams(), progress=False, cache_root=cache))
    store = DepthCache(cache, seq.identity(), DepthParams())
    for f in frames:  # a cache whose frames are one frame late (index k holds frame k+1's stamp)
        store.put(dataclasses.replace(f, stamp_ns=f.stamp_ns + 66_666_667))
    store.flush()
    _run(bag, out, variants="depth-raw")
    reason = _record(out, variant="depth-raw")["failure_reason"]
    assert "at stamp" in reason and "it holds" in reason


# ---- 14. a corrupt depth-cache chunk is recomputed --------------------------------------------------------------
def test_14_corrupt_depth_cache_chunk_is_reported_and_recomputed(tmp_path, cache, capsys):
    from pipeline.depth import DepthParams
    from pipeline.depth_cache import depth_stream

    seq = RosarioSequence(_bag(tmp_path / "seq.bag"))
    first = list(depth_stream(seq, DepthParams(), progress=False, cache_root=cache))
    (chunk,) = list((cache / "depth").rglob("chunk_*.npz"))
    data = chunk.read_bytes()
    chunk.write_bytes(data[: len(data) // 2])  # truncated
    again = list(depth_stream(seq, DepthParams(), progress=False, cache_root=cache))
    assert "corrupt depth-cache chunk" in capsys.readouterr().err
    assert len(again) == len(first) and all(np.array_equal(a.valid, b.valid) for a, b in zip(first, again))
    chunk.write_bytes(data[:200] + bytes(b ^ 0xFF for b in data[200:400]) + data[400:])  # garbled
    again = list(depth_stream(seq, DepthParams(), progress=False, cache_root=cache))
    assert len(again) == len(first)
    from pipeline.png_chunks import read_chunk

    assert read_chunk(chunk).blob("depth", 0).size  # rewritten whole


def test_14_corrupt_inpainted_cache_chunk_is_reported_and_recomputed(tmp_path, cache, capsys):
    from pipeline.inpaint_stage import InpaintParams, inpainted_stream

    seq = RosarioSequence(_bag(tmp_path / "seq.bag"))
    params = InpaintParams(method="telea")
    first = list(inpainted_stream(seq, params, cache, progress=False, workers=1))
    chunks = [c for c in (cache / "depth").rglob("chunk_*.npz") if "inpaint-telea" in str(c)]
    assert len(chunks) == 1
    data = chunks[0].read_bytes()
    chunks[0].write_bytes(data[: len(data) // 3])  # truncated (disk full, killed writer)
    again = list(inpainted_stream(seq, params, cache, progress=False, workers=1))
    assert "corrupt depth-cache chunk" in capsys.readouterr().err
    assert len(again) == len(first)
    assert all(np.array_equal(a.depth_m, b.depth_m, equal_nan=True) for a, b in zip(first, again))


def test_11_image_and_imu_stamps_are_converted_to_seconds_the_same_way(tmp_path):
    """Image and IMU seconds both come from integer ns by one conversion (``ns / 1e9``; ``ns * 1e-9`` differs by
    one ulp for many stamps), and the reader hands out the IMU's integer stamps beside them."""
    stamps = T0_NS + np.arange(0, 2_000_000_000, 7_000_001, dtype=np.int64)
    assert np.any(stamps * 1e-9 != stamps / 1e9)                     # the two conversions do differ
    seq = RosarioSequence(_bag(tmp_path / "seq.bag"))
    imu = seq.imu_array()
    imu_ns, data = seq.imu_samples()
    assert imu_ns.dtype == np.int64
    assert np.array_equal(imu_ns, np.array([s.stamp_ns for s in seq.imu()], dtype=np.int64))
    assert np.array_equal(imu[:, 0], imu_ns / 1e9) and np.array_equal(imu[:, 1:], data)


def test_11_imu_samples_are_ordered_against_frames_in_integer_ns():
    """An IMU sample 100 ns after a frame belongs to the next frame. In float seconds the two stamps are the same
    double (2017 epoch: one ulp ≈ 238 ns), so a float comparison fed it before the frame."""
    from pipeline.run_job import imu_samples_through

    frame_ns = 1_500_000_000_123_456_789
    imu_ns = np.array([frame_ns - 5_000_000, frame_ns - 100, frame_ns, frame_ns + 100, frame_ns + 5_000_000],
                      dtype=np.int64)
    assert (frame_ns + 100) / 1e9 == frame_ns / 1e9                   # seconds cannot tell them apart
    assert imu_samples_through(imu_ns, frame_ns) == 3                 # up to and including the frame's stamp
    assert imu_samples_through(imu_ns, frame_ns, start=4) == 4        # never goes back before ``start``
    assert imu_samples_through(imu_ns, frame_ns + 5_000_000) == 5


# ---- 10. stereo pairing is measured and a systematic offset refused ---------------------------------------------
def _offset_bag(path: Path, rig, right_offset_ns: int, n: int = 20, imu_gap_s: float = 0.0,
                nan_at: int | None = None, repeat: int = 0) -> Path:
    img = np.full((376, 672, 3), 90, np.uint8)
    with RosarioBagWriter(path) as w:
        w.set_camera_info(rig)
        for i in range(n):
            t = T0_NS + i * 66_666_667
            w.write_left(t, img)
            w.write_right(t + right_offset_ns, img)
        t_imu = T0_NS + np.arange(int(n * 66.7 / 5)) * 5_000_000
        if imu_gap_s:
            t_imu = t_imu[(t_imu < T0_NS + 200_000_000) | (t_imu >= T0_NS + 200_000_000 + int(imu_gap_s * 1e9))]
        for k, t in enumerate(t_imu):
            accel = np.array([np.nan if k == nan_at else 9.8, 0.0, 0.0])
            w.write_imu(int(t), np.zeros(3), accel)
            if k < repeat:
                w.write_imu(int(t), np.zeros(3), accel)
    return path


def test_10_stereo_pairs_are_counted_and_an_offset_is_named(tmp_path, cache, capsys, rosario_rig):
    bag = _offset_bag(tmp_path / "late.bag", rosario_rig, right_offset_ns=30_000_000)
    assert main(["info", str(bag)]) == 0
    assert "stereo pairs: 0 of 20" in capsys.readouterr().out
    assert _run(bag, tmp_path / "runs", variants="depth-raw") == 2
    err = capsys.readouterr().err
    assert "+30.0 ms" in err and str(bag) in err
    assert not (cache / "depth").exists()


# ---- 12. IMU gaps, repeated stamps and NaN samples are reported -------------------------------------------------
def test_12_imu_gaps_repeats_and_nan_are_reported(tmp_path, cache, rosario_rig):
    from pipeline.data_quality import measure
    from pipeline.errors import BagError

    bag = _offset_bag(tmp_path / "gap.bag", rosario_rig, 0, imu_gap_s=0.3, repeat=4)
    q = measure(RosarioSequence(bag))
    assert q["imu"]["gaps"] == 1 and q["imu"]["max_gap_s"] == pytest.approx(0.305, abs=0.006)
    assert q["imu"]["repeated_stamps"] == 4
    from pipeline.data_quality import frame_gaps

    stamps = T0_NS + np.delete(np.arange(20), [5, 11, 12]) * 66_666_667  # three camera frames dropped
    assert frame_gaps(stamps)["dropped"] == 3
    bag_nan = _offset_bag(tmp_path / "nan.bag", rosario_rig, 0, nan_at=7)
    with pytest.raises(BagError, match=r"nan\.bag: /imu sample at stamp 1600000000035000000 ns"):
        measure(RosarioSequence(bag_nan))
    # the counts reach the records and the report
    out = tmp_path / "runs"
    bag_seq = _bag(tmp_path / "seq.bag")
    assert _run(bag_seq, out) == 0
    assert _record(out)["data_quality"]["imu"]["gaps"] == 0
    assert "IMU: " in (out / "report" / "report.md").read_text()


# ---- 15. a simulated folder is a source; records say only what applies ------------------------------------------
def test_15_simulated_folder_is_a_source_and_records_say_only_what_applies(tmp_path, cache):
    from pipeline.sources import resolve_source

    folder = tmp_path / "sim"
    folder.mkdir()
    bag = _bag(folder / "sim.bag")
    _gt(folder / "sim_gt.txt")
    shutil.copy(Path(__file__).resolve().parent.parent / "data" / "rosario_camchain.yaml", folder / "camchain.yaml")
    (folder / "meta.json").write_text(json.dumps({"simulator_version": 4, "preset": "x", "files": {
        "bag": "sim.bag", "gt": "sim_gt.txt", "camchain": "camchain.yaml"}}))
    src = resolve_source(str(folder))
    assert src.simulated and src.bag == bag and src.gt == folder / "sim_gt.txt"
    assert resolve_source(str(bag)).simulated  # the bag of a simulated folder, named directly
    out = tmp_path / "runs"
    assert _run(folder, out) == 0
    record = _record(out, seq="sim")
    assert record["simulated"] is True and record["inpaint_method"] is None
    assert "inpaint_method" not in record["job"]


# ---- 18. no rotation ATE that the alignment cannot determine ----------------------------------------------------
def test_18_rotation_ate_on_a_straight_path_is_not_the_alignments_roll(tmp_path, capsys):
    from scipy.spatial.transform import Rotation

    from eval.trajectory import Trajectory, format_tum

    rng = np.random.default_rng(0)
    n = 300
    t = 100.0 + 0.1 * np.arange(n)
    p = np.column_stack([np.linspace(0.0, 30.0, n), 0.01 * np.sin(np.arange(n) / 20.0), np.zeros(n)])
    q = Rotation.from_euler("xyz", np.column_stack([0.02 * np.sin(t), 0.01 * np.cos(t), 0.1 + 0.01 * t])).as_quat()
    gt, est = tmp_path / "gt.tum", tmp_path / "est.tum"
    gt.write_text(format_tum(Trajectory(t, p, q, has_orientation=True)))
    est.write_text(format_tum(Trajectory(t, p + rng.normal(0.0, 0.02, p.shape), q, has_orientation=True)))
    assert main(["evaluate", str(est), str(gt), "--json", str(tmp_path / "m.json")]) == 0
    printed = capsys.readouterr().out
    assert "after a posyaw alignment" in printed and "undetermined" in printed
    metrics = json.loads((tmp_path / "m.json").read_text())["metrics"]
    assert metrics["ate_rot_align"] == "posyaw" and metrics["ate_rot_rmse_deg"] < 0.5


# ---- 17. an inconsistent camchain is said, with which transform is used ------------------------------------------
def test_17_inconsistent_camchain_is_warned_about_once(tmp_path, capsys, monkeypatch, rosario_rig):
    import pipeline.calibration as calibration
    from pipeline.paths import ROSARIO_CAMCHAIN

    calibration._WARNED.clear()
    monkeypatch.delenv(calibration._WARNED_ENV, raising=False)
    calibration.read_camchain(ROSARIO_CAMCHAIN)
    calibration.read_camchain(ROSARIO_CAMCHAIN)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(ROSARIO_CAMCHAIN) in line and "0.29°" in line and "using cam0/T_cam_imu and cam1/T_cn_cnm1" in line
    consistent = tmp_path / "camchain.yaml"
    calibration.write_camchain(rosario_rig, consistent)  # cam1/T_cam_imu = T_cn_cnm1 · cam0/T_cam_imu
    calibration.read_camchain(consistent)
    assert capsys.readouterr().err == ""


# ---- 16. the EuRoC export's IMU noise describes the data --------------------------------------------------------
def test_16_euroc_imu_noise_figures_include_the_simulated_vibration(tmp_path, rosario_rig):
    import yaml

    from pipeline.sim.config import ImuConfig
    from pipeline.sim.export import EurocWriter

    imu = ImuConfig()
    writer = EurocWriter(tmp_path / "euroc", rosario_rig, imu, 15.0, max_speed_m_s=0.9)
    writer.close()
    meta = yaml.safe_load((tmp_path / "euroc" / "mav0" / "imu0" / "sensor.yaml").read_text())
    per_sample = meta["accelerometer_noise_density"] * np.sqrt(meta["rate_hz"])  # m/s² per sample
    assert per_sample >= 0.9 * imu.vibration_acc_rms * 0.9  # the vibration seen while moving is covered
    assert meta["agrivio_accelerometer_noise_density_sensor"] == imu.acc_noise_density
    assert "vibration" in meta["comment"]


def test_16_euroc_imu_noise_figures_describe_the_simulated_data():
    """Through the simulator: the accelerometer error of the samples a simulated sequence writes, while the robot
    drives near its top speed, is what ``imu0/sensor.yaml`` says (per-sample σ = density · √rate), where the
    sensor-only density would claim less than half of it."""
    import dataclasses

    from pipeline.calibration import rig_from_camchain
    from pipeline.paths import ROSARIO_CAMCHAIN
    from pipeline.sim.export import imu_sensor_yaml
    from pipeline.sim.imu import ImuSimulator
    from pipeline.sim.mount import mount_transform
    from pipeline.sim.presets import get_preset
    from pipeline.sim.sequence import top_planned_speed
    from pipeline.sim.terrain import Terrain
    from pipeline.sim.trajectory import RobotTrajectory

    cfg = get_preset("rosario-like-02")
    cfg = dataclasses.replace(cfg, duration_s=12.0)
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    traj = RobotTrajectory(cfg, Terrain(cfg.field, 3, (40.0, 45.0)),
                           mount_transform(rig, cfg.camera.tilt_deg, cfg.camera.imu_position_m), 3)
    top = top_planned_speed(traj, cfg.duration_s)
    meta = imu_sensor_yaml(cfg.imu, top)
    out = ImuSimulator(cfg.imu, traj, seed=3).next(int(cfg.duration_s * cfg.imu.rate_hz))
    moving = traj.planned_speed(out.t) >= 0.9 * top
    assert moving.sum() > 200
    err = (out.accel - traj.kinematics(out.t).specific_force - out.bias_accel)[moving]
    seen = float(np.sqrt(np.mean(err ** 2)))                          # m/s² per sample, all axes
    rate = meta["rate_hz"]
    stated = meta["accelerometer_noise_density"] * np.sqrt(rate)
    sensor_only = meta["agrivio_accelerometer_noise_density_sensor"] * np.sqrt(rate)
    assert 0.85 * seen <= stated <= 1.25 * seen, (seen, stated)     # the file describes the data …
    assert sensor_only < 0.6 * seen                                  # … where the sensor's own figure does not
