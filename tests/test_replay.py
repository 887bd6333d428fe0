"""The rerun replay: the .rrd loads back with rerun's own reader, estimates lie on the ground truth within their
recorded ATE, every time-indexed entity is on the three timelines, features carry their depth source."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from eval.alignment import apply_lever_arm
from eval.association import match_stamps
from eval.evaluate import EvalOptions, evaluate
from eval.synthetic import field_path, perturbed_estimate
from eval.trajectory import Trajectory, format_tum
from msckf.types import DepthSource
from pipeline import replay_layout as lay
from pipeline.replay import ReplayFrame, ReplayRun, recorded_entities, write_replay
from pipeline.replay_features import feature_classes
from pipeline.replay_stage import load_run

K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
LEVER = (0.47, 0.03, -0.40)  # the simulated Rosario antenna in the IMU frame, ≈ 0.6 m


def _run(name: str, n: int, rng: np.random.Generator) -> ReplayRun:
    t = 100.0 + np.arange(n) / 15.0
    pos = np.stack([t - t[0], 0.1 * (t - t[0]), np.zeros(n)], axis=1)
    feats = {i: (rng.uniform(0, 60, (30, 2)), rng.integers(1, 30, 30), rng.integers(0, 4, 30).astype(np.uint16))
             for i in range(n)}
    return ReplayRun(name=name, stamps_s=t, positions=pos, quats_xyzw=np.tile([0, 0, 0, 1.0], (n, 1)),
                     T_body_cam=np.eye(4), gt_stamps_s=t[::3], gt_errors_m=np.linspace(0.01, 0.1, len(t[::3])),
                     ate_rmse_m=0.05, frame_stamps_s=t, n_features=np.full(n, 30), n_with_depth=np.full(n, 12),
                     frame_ms=np.full(n, 12.0), features=feats)


def _columns(path: Path) -> dict[str, list]:
    """entity → list of pyarrow record batches of its chunks."""
    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def _timed(batches: list, column: str) -> tuple[dict[str, np.ndarray], list]:
    """The timeline columns and the values of ``column`` of the non-static batches of one entity."""
    times: dict[str, list] = {}
    values: list = []
    for rb in batches:
        if column not in rb.schema.names or "time" not in rb.schema.names:
            continue
        for tl in ("frame", "seconds", "time"):
            times.setdefault(tl, []).extend(rb.column(tl).cast("int64").to_pylist())
        values.extend(rb.column(column).to_pylist())
    return {k: np.asarray(v) for k, v in times.items()}, values


def test_replay_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    n, h, w = 6, 48, 64
    runs = [_run("depth-raw seed0", n, rng), _run("depth-inpainted seed0", n, rng)]
    depth = rng.uniform(1, 10, (h, w)).astype(np.float32)
    holes = rng.random((h, w)) < 0.2
    raw = np.where(holes, np.nan, depth).astype(np.float32)
    exact = depth + 0.1
    frames = (ReplayFrame(i, 100.0 + i / 15.0, rng.integers(0, 255, (h, w, 3), dtype=np.uint8), raw, depth, holes,
                          exact) for i in range(n))
    out = write_replay(tmp_path / "run.rrd", runs, frames, gt_positions=runs[0].positions, K_left=K,
                       image_size=(w, h))
    rows = recorded_entities(out)
    for entity in ("/camera/left", "/camera/depth_raw", "/camera/depth_raw/holes", "/camera/depth_inpainted",
                   "/camera/depth_error", "/world/gt", "/world/depth-raw_seed0/trajectory",
                   "/world/depth-inpainted_seed0/camera", "/world/depth-raw_seed0/label",
                   "/camera/left/features/depth-raw_seed0", "/metrics/ate/depth-inpainted_seed0/error_at_gt",
                   "/metrics/ate/depth-inpainted_seed0/rmse_so_far", "/metrics/features/depth-raw_seed0/tracked",
                   "/metrics/features/depth-raw_seed0/with_depth", "/metrics/frame_ms/depth-raw_seed0",
                   "/metrics/hole_ratio/raw", "/legend"):
        assert entity in rows, f"{entity} missing from {sorted(rows)}"
    assert rows["/camera/left"] == n  # every frame's image (no stride)
    assert not list(tmp_path.glob(".run.rrd*")), "temporary file left behind"
    cols = _columns(out)
    # every time-indexed entity is on frame, seconds (from 0) and time, and poses/metrics are on `frame` too
    for entity in ("/camera/left", "/world/depth-raw_seed0/trajectory", "/metrics/ate/depth-raw_seed0/error_at_gt",
                   "/metrics/frame_ms/depth-raw_seed0", "/metrics/hole_ratio/raw"):
        names = {n for rb in cols[entity] if not rb.num_rows == 0 for n in rb.schema.names}
        assert {"frame", "seconds", "time"} <= names, (entity, names)
    times, _ = _timed(cols["/world/depth-raw_seed0/trajectory"], "Points3D:positions")
    assert times["seconds"][0] == 0 and np.array_equal(times["frame"], np.arange(n))
    times, ate = _timed(cols["/metrics/ate/depth-raw_seed0/error_at_gt"], "Scalars:scalars")
    assert np.array_equal(times["frame"], np.arange(0, n, 3)) and np.all(np.isfinite(np.concatenate(ate)))
    # one colour per run, the same in 3-D and in every plot
    for i, ent in enumerate(("depth-raw_seed0", "depth-inpainted_seed0")):
        packed = int.from_bytes(bytes(lay.run_colour(i)) + b"\xff", "big")
        for entity, col in ((f"/world/{ent}/path", "LineStrips3D:colors"),
                            (f"/metrics/ate/{ent}/rmse_so_far", "SeriesLines:colors"),
                            (f"/metrics/features/{ent}/tracked", "SeriesLines:colors"),
                            (f"/metrics/frame_ms/{ent}", "SeriesLines:colors")):
            got = [v for rb in cols[entity] if col in rb.schema.names for v in rb.column(col).to_pylist()]
            assert got == [[packed]], (entity, got)
    # features are coloured by their class, not by a colour override
    feat = cols["/camera/left/features/depth-raw_seed0"]
    assert all("Points2D:colors" not in rb.schema.names for rb in feat)
    assert any("Points2D:class_ids" in rb.schema.names for rb in feat)


def _write_run_folder(root: Path, variant: str, seed: int) -> Path:
    """A run folder as run_job writes it: IMU-frame estimate, antenna GT, eval options with the lever arm."""
    body = field_path(duration_s=40.0, rate_hz=15.0, row_length_m=12.0)  # with turns: the lever arm swings
    antenna = apply_lever_arm(body, np.array(LEVER))
    gt = Trajectory.from_positions(antenna.stamps_s[::3], antenna.positions[::3])  # 5 Hz, position only
    est = perturbed_estimate(body, seed=seed, noise_m=0.01, drift_m_per_sqrt_s=0.005)
    options = EvalOptions(align="se3", max_diff_s=0.02, lever_arm_m=LEVER)
    metrics = evaluate(gt, est, options).metrics()
    (root / "gt.tum").write_text(format_tum(gt))
    run_dir = root / variant / f"seed{seed}"
    run_dir.mkdir(parents=True)
    (run_dir / "estimate.tum").write_text(format_tum(est))
    record = {"record_type": "run", "schema_version": 1, "sequence": "synthetic", "variant": variant, "seed": seed,
              "status": "ok", "metrics": metrics, "estimate_path": "estimate.tum",
              "gt_path": str((root / "gt.tum").resolve()), "eval_options": options.to_dict(), "job": {"options": {}}}
    (run_dir / "record.json").write_text(json.dumps(record))
    return run_dir


def test_logged_estimates_lie_on_the_logged_gt_within_their_ate(tmp_path):
    """Issue 14.1: the replay once applied the alignment fitted on the lever-arm-shifted estimate to the unshifted
    one, drawing every path ≈ the lever arm (0.6 m) off the ground truth while the ATE said a few cm."""
    dirs = [_write_run_folder(tmp_path, v, s) for v, s in (("depth-raw", 0), ("depth-inpainted", 1))]
    loaded = [load_run(d) for d in dirs]
    out = write_replay(tmp_path / "ate.rrd", [lr.run for lr in loaded], [], loaded[0].gt.positions, K, (64, 48))
    cols = _columns(out)
    gt_strip = np.asarray(cols["/world/gt"][0].column("LineStrips3D:strips").to_pylist()[0][0], dtype=np.float64)
    gt = loaded[0].gt
    assert np.allclose(gt_strip, gt.positions, atol=1e-4)
    for d, lr in zip(dirs, loaded):
        rec = json.loads((d / "record.json").read_text())
        ate_rmse, ate_max = rec["metrics"]["ate_rmse_m"], rec["metrics"]["ate_max_m"]
        assert ate_rmse < 0.1
        ent = lay.entity_name(lr.run.name)
        times, pos = _timed(cols[f"/world/{ent}/trajectory"], "Points3D:positions")
        est_t = times["time"] * 1e-9
        est_p = np.asarray([p[0] for p in pos], dtype=np.float64)
        i_gt, i_est = match_stamps(gt.stamps_s, est_t, 0.02)
        err = np.linalg.norm(est_p[i_est] - gt_strip[i_gt], axis=1)
        assert len(err) == rec["metrics"]["n_pairs"]
        assert np.sqrt(np.mean(err ** 2)) == pytest.approx(ate_rmse, rel=1e-3, abs=1e-4)
        assert err.max() <= ate_max + 1e-4
        # the whole drawn path (not only its associated poses) is near the ground-truth line
        path = np.asarray(cols[f"/world/{ent}/path"][0].column("LineStrips3D:strips").to_pylist()[0][0])
        nearest = np.min(np.linalg.norm(path[:, None, :] - gt_strip[None, :, :], axis=2), axis=1)
        assert nearest.max() < ate_max + 0.1  # 0.1 m: half the GT fix spacing at 1 m/s
        # the ATE series: finite errors at the GT fixes, and its running RMSE ends at the recorded ATE RMSE
        _, running = _timed(cols[f"/metrics/ate/{ent}/rmse_so_far"], "Scalars:scalars")
        assert running[-1][0] == pytest.approx(ate_rmse, rel=1e-6)


def test_feature_classes_tell_inpainted_from_measured_depth(rosario_rig):
    uv = np.array([[100.0, 100.0], [300.0, 200.0], [500.0, 300.0], [50.0, 50.0]])
    src = np.array([DepthSource.DEPTH_MAP, DepthSource.DEPTH_MAP, DepthSource.MONO, DepthSource.STEREO_MATCH],
                   dtype=np.uint8)
    assert feature_classes(src, uv).tolist() == [lay.MEASURED_DEPTH, lay.MEASURED_DEPTH, lay.MONO, lay.STEREO]
    w, h = rosario_rig.left.size
    valid = np.ones((h, w), dtype=bool)
    rect = rosario_rig.rectify_left_pixels(uv[1:2])[0]
    u, v = int(round(rect[0])), int(round(rect[1]))
    valid[v - 1:v + 2, u - 1:u + 2] = False  # the second feature's pixel was a hole of the raw map
    got = feature_classes(src, uv, valid, rosario_rig)
    assert got.tolist() == [lay.MEASURED_DEPTH, lay.INPAINTED_DEPTH, lay.MONO, lay.STEREO]
    # the run's own flags (frames.npz: feature_depth_measured) decide when the log has them
    flags = np.array([False, True, False, False])
    got = feature_classes(src, uv, valid, rosario_rig, measured=flags)
    assert got.tolist() == [lay.INPAINTED_DEPTH, lay.MEASURED_DEPTH, lay.MONO, lay.STEREO]


def test_fit_eye_frames_the_points():
    pts = np.array([[0.0, 0.0, 0.0], [10.0, 2.0, 0.5]])
    eye = lay.fit_eye(pts)
    assert eye is not None and np.allclose(eye.look_target, [5.0, 1.0, 0.25])
    d = np.linalg.norm(np.subtract(eye.position, eye.look_target))
    assert 3.0 <= d < 20.0 and eye.position[2] > eye.look_target[2]
    assert lay.fit_eye(np.zeros((0, 3))) is None


def test_external_estimate_is_aligned_like_the_runs(tmp_path):
    from pipeline.external_tracks import load_external
    from pipeline.replay_stage import external_run

    run_dir = _write_run_folder(tmp_path, "depth-raw", 0)
    lr = load_run(run_dir)
    ext_path = tmp_path / "openvins.tum"
    ext_path.write_text((run_dir / "estimate.tum").read_text())  # the same estimate, from "another system"
    (track,) = load_external([f"openvins={ext_path}"])
    ext = external_run(track, lr.gt, lr.eval_options)
    assert ext.name == "external: openvins" and ext.kind == "external"
    assert np.allclose(ext.positions, lr.run.positions, atol=1e-9)
    assert ext.ate_rmse_m == pytest.approx(lr.run.ate_rmse_m, rel=1e-6)


def test_feature_markers_grow_with_the_stated_depth_sigma():
    from pipeline.replay import feature_radii

    r = feature_radii(np.array([np.nan, 0.02, 0.15, 0.9]), 4)
    assert r.tolist() == pytest.approx([3.0, 3.4, 6.0, 9.0])        # no depth, measured, filled, capped
    assert feature_radii(None, 3).tolist() == [3.0, 3.0, 3.0]      # old logs: one size


def test_replay_reads_the_depth_caches_named_by_the_records(tmp_path):
    """Issue 15.1: the replay opens the caches the runs read (their recorded keys), not caches rebuilt from default
    parameters; with non-default depth and no inpainted run there is no inpainted view."""
    from pipeline.depth import DepthFrame, DepthParams
    from pipeline.depth_cache import DepthCache
    from pipeline.inpaint_stage import InpaintParams
    from pipeline.replay_stage import _recorded_caches

    depth = DepthParams(num_disparities=32)
    inpaint = InpaintParams(depth=depth, method="telea")
    frame = DepthFrame(0, 0, np.full((4, 6), 2.0, np.float32), np.ones((4, 6), bool), None)
    for params in (depth, inpaint, DepthParams(), InpaintParams()):
        store = DepthCache(tmp_path / "cache", "bag-z", params)
        store.put(frame)
        store.flush()
    dirs = {}
    for variant, seed in (("depth-raw", 0), ("depth-inpainted", 1)):
        d = _write_run_folder(tmp_path, variant, seed)
        rec = json.loads((d / "record.json").read_text())
        rec["job"] = {"cache_root": str(tmp_path / "cache")}
        rec["input_key_parts"] = {"depth": depth.key(), **({"inpaint": inpaint.key()} if seed else {})}
        (d / "record.json").write_text(json.dumps(rec))
        dirs[variant] = d
    both = [load_run(dirs["depth-raw"]), load_run(dirs["depth-inpainted"])]
    raw, filled = _recorded_caches(both, "bag-z")
    assert raw.directory == DepthCache(tmp_path / "cache", "bag-z", depth).directory
    assert filled.directory == DepthCache(tmp_path / "cache", "bag-z", inpaint).directory
    raw_only, none = _recorded_caches(both[:1], "bag-z")
    assert raw_only.directory == raw.directory and none is None
