"""The depth oracle ladder (pipeline/depth_oracle*.py): tracked-point truth, the monotonicity verdict, and the
back-end replay of recorded tracks reproducing a real depth-raw run exactly."""

from __future__ import annotations

import numpy as np
import pytest

from eval.trajectory import read_tum
from pipeline.depth_oracle import (
    Rung,
    TrackedFrame,
    TrackLog,
    run_backend,
    snap_to_true_points,
    standard_rungs,
    true_track_depths,
)
from pipeline.depth_oracle_run import default_config, ladder_verdict, prepare_oracle, run_ladder

K = np.array([[350.0, 0.0, 336.0], [0.0, 350.0, 188.0], [0.0, 0.0, 1.0]])


def _pose(x: float) -> np.ndarray:
    """Camera moving sideways along +x, looking along +z (rectified-left → world)."""
    T = np.eye(4)
    T[0, 3] = x
    return T


def _project(p: np.ndarray, T: np.ndarray) -> np.ndarray:
    pc = T[:3, :3].T @ (p - T[:3, 3])
    uv = K @ pc
    return uv[:2] / uv[2]


def _log_with(points_px: dict[int, list[np.ndarray]], n: int) -> TrackLog:
    frames = []
    for k in range(n):
        ids = np.array(sorted(points_px), dtype=np.int64)
        px = np.stack([points_px[i][k] for i in ids])
        frames.append(TrackedFrame(0.1 * k, k, ids, np.zeros((len(ids), 2)), np.full(len(ids), k + 1, np.int32), px))
    return TrackLog(frames, np.zeros((0, 7)))


def test_tracked_point_truth_is_the_true_depth_and_sliding_tracks_get_none():
    n = 10
    poses = {k: _pose(0.05 * k) for k in range(n)}
    point = np.array([0.3, -0.2, 2.5])
    static = [_project(point, poses[k]) for k in range(n)]
    # drifts 0.8 px a frame across the direction of motion: no static point explains it
    sliding = [_project(point, poses[k]) + np.array([0.0, 0.8 * k]) for k in range(n)]
    log = _log_with({1: static, 2: sliding}, n)
    edge_map = np.full((376, 672), 2.9, np.float32)                     # an exact map that reads the background

    def exact(_i):
        return edge_map, np.ones_like(edge_map, bool), None

    stats = true_track_depths(log, K, poses, exact_map=None)
    for k in range(len(log.frames)):
        z_true = (poses[k][:3, :3].T @ (point - poses[k][:3, 3]))[2]
        assert log.truth[k][0] == pytest.approx(z_true, rel=1e-6) and log.truth_source[k][0] == 1
        assert np.isnan(log.truth[k][1]) and log.truth_source[k][1] == 0  # no consistent 3-D point: no truth
    assert stats["triangulated"] == pytest.approx(0.5)
    true_track_depths(log, K, poses, exact_map=exact)                 # with a fallback it is marked as such
    assert log.truth_source[0][1] == 2 and log.truth[0][1] == pytest.approx(2.9)


def test_tracked_point_truth_states_its_own_sigma():
    """``truth_sigma`` is the spread of the true-pose triangulation under ``pixel_sigma`` px of tracking noise."""
    n = 8
    poses = {k: _pose(0.03 * k) for k in range(n)}
    point = np.array([0.2, 0.1, 4.0])
    clean = [_project(point, poses[k]) for k in range(n)]
    rng = np.random.default_rng(3)
    z_last, stated = [], []
    for _ in range(300):
        noisy = [px + rng.normal(0.0, 0.5, 2) for px in clean]
        log = _log_with({1: noisy}, n)
        true_track_depths(log, K, poses, exact_map=None, pixel_sigma=0.5, max_rms_px=10.0, max_rel_sigma=1.0)
        z_last.append(log.truth[-1][0])
        stated.append(log.truth_sigma[-1][0])
    assert np.all(np.isfinite(stated))
    assert np.median(stated) == pytest.approx(np.std(z_last), rel=0.15)
    assert np.median(stated) / 4.0 > 0.002      # larger than the exact rungs' flat σ floor here: it is measured


def test_exact_pixels_put_each_point_track_on_its_true_projection_and_leave_the_others():
    n = 10
    poses = {k: _pose(0.05 * k) for k in range(n)}
    point = np.array([0.3, -0.2, 2.5])
    rng = np.random.default_rng(5)
    tracked = [_project(point, poses[k]) + rng.normal(0.0, 0.3, 2) for k in range(n)]
    sliding = [_project(point, poses[k]) + np.array([0.0, 0.8 * k]) for k in range(n)]
    log = _log_with({1: tracked, 2: sliding}, n)
    true_track_depths(log, K, poses, exact_map=None)
    c, s = np.cos(0.02), np.sin(0.02)
    R_left = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])      # p_rect = R_left p_cam0
    before = [fr.rect_px[1].copy() for fr in log.frames]
    assert snap_to_true_points(log, K, R_left, poses) == n               # one point track, every frame
    p = log.truth_points[1]
    assert np.linalg.norm(p - point) < 0.05                              # the triangulated point, not the noise
    for k, fr in enumerate(log.frames):
        assert np.allclose(fr.rect_px[0], _project(p, poses[k]), atol=1e-9)
        ray = R_left @ np.array([fr.xy0[0, 0], fr.xy0[0, 1], 1.0])       # the raw cam0 ray, rectified
        assert np.allclose(ray[:2] / ray[2], (np.linalg.inv(K) @ np.append(fr.rect_px[0], 1.0))[:2], atol=1e-12)
        assert np.array_equal(fr.rect_px[1], before[k]) and np.array_equal(fr.xy0[1], np.zeros(2))


def _result(ate: dict[str, list[float]]) -> dict:
    chains = {"exact-everywhere": ("noise", 0), "exact+1%": ("noise", 1), "exact+10%": ("noise", 2),
              "exact@raw-valid": ("value", 0), "depth-raw@tracked-point": ("value", 1)}
    return {name: {"ate": dict(enumerate(v)), "failed": {}, "chain": chains[name][0], "order": chains[name][1]}
            for name, v in ate.items()}


def test_ladder_verdict_accepts_a_monotone_ladder_and_names_a_violation():
    good = _result({"exact-everywhere": [0.010, 0.011, 0.010], "exact+1%": [0.011, 0.011, 0.012],
                    "exact+10%": [0.020, 0.022, 0.021], "exact@raw-valid": [0.012, 0.013, 0.012],
                    "depth-raw@tracked-point": [0.015, 0.016, 0.015]})
    assert ladder_verdict({"s": good}) == (True, [])
    bad = _result({"exact-everywhere": [0.020, 0.021, 0.022], "exact+1%": [0.011, 0.011, 0.012],
                   "exact+10%": [0.020, 0.022, 0.021], "exact@raw-valid": [0.012, 0.013, 0.012],
                   "depth-raw@tracked-point": [0.015, 0.016, 0.015]})
    ok, why = ladder_verdict({"s": bad})
    assert not ok
    assert any("exact-everywhere" in w and "exact+1%" in w for w in why)
    assert any("exact-everywhere" in w and "exact@raw-valid" in w for w in why)   # the coverage chain


def test_ladder_verdict_is_not_monotone_when_nothing_was_compared():
    """One rung, or rungs without a common successful seed, show nothing: the verdict must not say yes."""
    one = _result({"exact+1%": [0.011, 0.012]})
    ok, why = ladder_verdict({"s": one})
    assert not ok and "nothing compared" in why[0]
    disjoint = _result({"exact@raw-valid": [0.012], "depth-raw@tracked-point": [0.015]})
    disjoint["depth-raw@tracked-point"]["ate"] = {5: 0.015}                   # no seed in common
    assert not ladder_verdict({"s": disjoint})[0]
    disjoint["depth-raw@tracked-point"]["ate"] = {0: 0.015}
    assert ladder_verdict({"s": disjoint}) == (True, [])


def test_ate_against_truth_samples_the_truth_at_the_estimates_own_stamps():
    """The truth (IMU rate) is interpolated at the estimate's stamps: the true trajectory, rigidly moved and sampled
    at other stamps, scores 0; one that runs 20 ms late scores what 20 ms of motion is; a rung's estimate outside
    the truth's span is not compared."""
    from scipy.spatial.transform import Rotation

    from eval.trajectory import Trajectory
    from pipeline.depth_oracle import ate_against_truth
    from pipeline.oracle_truth import TrueImuPoses

    t = np.arange(0.0, 10.0, 1.0 / 142.0)
    p = np.stack([0.03 * t ** 2, np.sin(0.5 * t), 0.05 * t], axis=1)      # speeding up to 0.6 m/s, weaving
    truth = TrueImuPoses(t, p, np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
    ts = np.arange(0.013, 9.9, 1.0 / 15.0)
    R = Rotation.from_euler("z", 40, degrees=True)

    def est(shift_s: float) -> Trajectory:
        q = np.stack([np.interp(ts - shift_s, t, p[:, k]) for k in range(3)], axis=1)
        return Trajectory(ts, R.apply(q) + [3.0, -2.0, 1.0], np.tile([0.0, 0.0, 0.0, 1.0], (len(ts), 1)))

    assert ate_against_truth(est(0.0), truth) < 2e-4                    # linear interpolation at 142 Hz
    late = ate_against_truth(est(0.02), truth)
    assert 2e-3 < late < 0.02 * 0.8                                    # a 20 ms lag at ≤ 0.8 m/s: mm, not 0
    longer = Trajectory(np.r_[ts, 12.0], np.r_[est(0.0).positions, [[0.0, 0.0, 0.0]]],
                        np.tile([0.0, 0.0, 0.0, 1.0], (len(ts) + 1, 1)))
    assert ate_against_truth(longer, truth) < 2e-4                       # the stamp past the truth is left out


def test_replayed_raw_rung_reproduces_the_pipeline_depth_raw_run(sim_cache, tmp_path, monkeypatch):
    """The ladder is only meaningful if its back-end replay of recorded tracks *is* the depth-raw run: with the
    same configuration the raw rung's trajectory equals the run's estimate.tum exactly."""
    from pipeline.cli import main
    from pipeline.sim_source import simulate_cached

    monkeypatch.setenv("AGRIVIO_CACHE", str(sim_cache))
    out = tmp_path / "runs"
    code = main(["run-sequence", "tiny", "--out", str(out), "--runs", "1", "--variants", "depth-raw",
                 "--workers", "1"])
    assert code == 0
    run_est = read_tum(out / "tiny" / "depth-raw" / "seed0" / "estimate.tum")
    src = simulate_cached("tiny", cache_root=sim_cache, progress=False)
    config = default_config()
    prep = prepare_oracle(src.sim_dir, sim_cache, [], config, [0])
    raw = Rung("depth-raw", lambda log, i: (log.frames[i].z_rect["raw"], log.frames[i].sigma_rect.get("raw")))
    traj, failure, stats = run_backend(prep["logs"][0], raw, config, prep["rig"])
    assert failure is None and stats["depth_fraction"] > 0.1
    assert len(traj.stamps_s) == len(run_est.stamps_s)
    np.testing.assert_array_equal(np.round(traj.positions, 6), np.round(run_est.positions, 6))
    # and the whole ladder runs on it (values are not checked here: 0.8 s of motion is too short)
    res = run_ladder(prep, config)
    assert set(res) >= {"depth-raw", "exact-everywhere", "exact+10%"} and not res["depth-raw"]["failed"]
    # every rung that ran has the NEES of its pose against the simulator's truth
    assert all(np.isfinite(r["nees_position"]) and r["nees_position"] > 0 for r in res.values() if r["ate"])
    assert all(np.isfinite(r["nees_tilt"]) and np.isfinite(r["nees_yaw"]) for r in res.values() if r["ate"])


def test_true_acc_bias_prep_feeds_the_back_end_the_imu_without_the_simulators_bias(sim_cache):
    """The --true-acc-bias diagnostic: the tracks are the same recording, the back end's accelerometer samples are
    the bag's minus the simulator's true bias at each stamp, the gyro untouched; pinned, the run still goes."""
    from pipeline.oracle_truth import PINNED_ACC_BIAS
    from pipeline.sim.sequence import SimulatedSequence
    from pipeline.sim_source import simulate_cached

    src = simulate_cached("tiny", cache_root=sim_cache, progress=False)
    plain = prepare_oracle(src.sim_dir, sim_cache, [], default_config(), [0])
    config = default_config(PINNED_ACC_BIAS)
    prep = prepare_oracle(src.sim_dir, sim_cache, [], config, [0], true_acc_bias=True)
    a, b = plain["logs"][0], prep["logs"][0]
    truth = SimulatedSequence(src.sim_dir).truth
    t_true = truth["imu_stamp_ns"] / 1e9
    bias = np.stack([np.interp(a.imu[:, 0], t_true, truth["bias_accel"][:, j]) for j in range(3)], axis=1)
    assert np.abs(bias).max() > 1e-3                                     # the tiny preset's IMU has a bias
    np.testing.assert_allclose(a.imu[:, 4:7] - b.imu[:, 4:7], bias, atol=1e-12)
    np.testing.assert_array_equal(a.imu[:, :4], b.imu[:, :4])
    np.testing.assert_array_equal(a.frames[3].xy0, b.frames[3].xy0)
    res = run_ladder(prep, config, rungs=[r for r in standard_rungs([]) if r.name == "exact-everywhere"])
    assert not res["exact-everywhere"]["failed"]


def test_per_track_noise_rung_gives_each_track_one_error_in_every_frame():
    """The ``exact+L%/track`` rungs perturb the tracked point's true depth by one relative error per track id
    (the same in every frame that sees it), unlike the per-frame rungs; σ is stated as for those."""
    n, ids = 6, np.array([3, 8, 11], np.int64)
    frames = [TrackedFrame(0.1 * k, k, ids, np.zeros((3, 2)), np.full(3, k + 1, np.int32), np.zeros((3, 2)))
              for k in range(n)]
    truth = [np.array([2.0, 4.0, 8.0]) * (1 + 0.01 * k) for k in range(n)]
    log = TrackLog(frames, np.zeros((0, 7)), seed=1, truth=truth, truth_source=[np.ones(3, np.uint8)] * n)
    rungs = {r.name: r for r in standard_rungs(track_noise_levels=(0.03,))}
    track, frame = rungs["exact+3%/track"], rungs["exact+3%"]
    assert track.chain == "track-noise"
    ratios = np.stack([track.depth(log, k)[0] / truth[k] for k in range(n)])
    np.testing.assert_allclose(ratios, np.broadcast_to(ratios[0], ratios.shape), rtol=1e-12)
    assert len(np.unique(np.round(ratios[0], 12))) == 3 and np.all(np.abs(ratios[0] - 1) < 0.2)
    per_frame = np.stack([frame.depth(log, k)[0] / truth[k] for k in range(n)])
    assert np.ptp(per_frame, axis=0).min() > 1e-6
    np.testing.assert_allclose(track.depth(log, 0)[1], frame.depth(log, 0)[1])


def test_structure_rungs_keep_the_raw_errors_but_break_their_structure():
    """``structure_rungs``: the in-frame shuffle permutes each frame's σ-normalised raw errors among the same
    features, the sign flip keeps every error's size at its feature, the Gaussian rung has no raw error in it;
    features without a raw depth or a tracked-point truth get no depth, and every rung states the raw σ."""
    from pipeline.depth_oracle import structure_rungs

    n, k = 4, 40
    ids = np.arange(k, dtype=np.int64)
    rng = np.random.default_rng(5)
    truth = [rng.uniform(2.0, 9.0, k) for _ in range(n)]
    frames = []
    for j in range(n):
        fr = TrackedFrame(0.1 * j, j, ids, np.zeros((k, 2)), np.full(k, j + 1, np.int32), np.zeros((k, 2)))
        sigma = 0.013 * truth[j] ** 2
        z = truth[j] + sigma * np.linspace(-2.0, 3.0, k)                  # known normalised errors
        z[0] = np.nan                                                    # a hole: no depth in any rung
        fr.z_rect["raw"], fr.sigma_rect["raw"] = z, sigma
        frames.append(fr)
    source = [np.ones(k, np.uint8) for _ in range(n)]
    source[1][1] = 0                                                     # no tracked-point truth
    log = TrackLog(frames, np.zeros((0, 7)), seed=2, truth=truth, truth_source=source)
    rungs = {r.name: r for r in structure_rungs()}
    assert all(r.chain == "" for r in rungs.values())
    for j in range(n):
        raw, s_raw, t = frames[j].z_rect["raw"], frames[j].sigma_rect["raw"], truth[j]
        ok = np.isfinite(raw) & (source[j] == 1)
        e_raw = np.sort(((raw - t) / s_raw)[ok])
        for name, rung in rungs.items():
            z, s = rung.depth(log, j)
            assert np.array_equal(np.isfinite(z), ok), name
            np.testing.assert_allclose(s[ok], s_raw[ok])
        z, _ = rungs["raw-shuffled-in-frame"].depth(log, j)
        e = (z[ok] - t[ok]) / s_raw[ok]
        np.testing.assert_allclose(np.sort(e), e_raw, atol=1e-9)          # the same errors …
        assert not np.allclose(e, ((raw - t) / s_raw)[ok])               # … on other features
        z, _ = rungs["raw-sign-flipped"].depth(log, j)
        np.testing.assert_allclose(np.abs(z - t)[ok], np.abs(raw - t)[ok], rtol=1e-9)
        z, _ = rungs["gauss@raw-sigma"].depth(log, j)
        e = (z[ok] - t[ok]) / s_raw[ok]
        assert abs(np.mean(e)) < 0.6 and 0.5 < np.std(e) < 1.6 and not np.allclose(np.sort(e), e_raw)
    # the in-run shuffle draws from all frames' errors
    z, _ = rungs["raw-shuffled-in-run"].depth(log, 2)
    ok = np.isfinite(frames[2].z_rect["raw"]) & (source[2] == 1)
    e = (z[ok] - truth[2][ok]) / frames[2].sigma_rect["raw"][ok]
    assert np.all((e > -2.0 - 1e-9) & (e < 3.0 + 1e-9))


def test_non_point_rungs_split_depth_raw_by_track_class():
    """``non_point_rungs``: ``raw+map@non-point`` is depth-raw with the exact map's value on the non-point tracks
    (truth source 2) and the raw σ everywhere; ``raw@non-point`` keeps only the non-point tracks' raw readings; a
    hole stays a hole in both, and both mark SGBM's readings as measured."""
    from pipeline.depth_oracle import non_point_rungs

    k = 6
    fr = TrackedFrame(0.0, 0, np.arange(k, dtype=np.int64), np.zeros((k, 2)), np.ones(k, np.int32), np.zeros((k, 2)))
    fr.z_rect["raw"] = np.array([2.0, 3.0, np.nan, 4.0, 5.0, 6.0])
    fr.sigma_rect["raw"] = np.full(k, 0.1)
    truth = np.array([2.1, 3.3, 3.9, 4.4, np.nan, 6.6])
    source = np.array([1, 2, 2, 2, 0, 1], np.uint8)                      # point, non-point ×3, none, point
    log = TrackLog([fr], np.zeros((0, 7)), seed=0, truth=[truth], truth_source=[source])
    rungs = {r.name: r for r in non_point_rungs()}
    assert all(r.chain == "" for r in rungs.values())
    z, s = rungs["raw+map@non-point"].depth(log, 0)
    np.testing.assert_array_equal(z, [2.0, 3.3, np.nan, 4.4, 5.0, 6.0])
    np.testing.assert_array_equal(s, np.full(k, 0.1))
    z, s = rungs["raw@non-point"].depth(log, 0)
    np.testing.assert_array_equal(z, [np.nan, 3.0, np.nan, 4.0, 5.0, np.nan])
    np.testing.assert_array_equal(np.isfinite(s), [False, True, True, True, True, False])
    for r in rungs.values():
        np.testing.assert_array_equal(r.measured(log, 0), np.isfinite(fr.z_rect["raw"]))


def test_perfect_fill_rung_is_sgbm_where_measured_the_truth_in_the_holes_and_says_which_are_fills():
    """``inpainted[exact]``: raw depth and σ where SGBM measured, the tracked point's truth (σ 0.2 %) in its holes
    where the track is a 3-D point, nothing elsewhere; the measured flag is the raw validity, so the filter's fill
    policy applies as to any inpainting; and the verdict holds it to ``inpainted[exact] ≤ depth-raw``."""
    ids = np.arange(4, dtype=np.int64)
    fr = TrackedFrame(0.0, 0, ids, np.zeros((4, 2)), np.ones(4, np.int32), np.zeros((4, 2)))
    fr.z_rect["raw"] = np.array([2.0, np.nan, np.nan, 5.0])
    fr.sigma_rect["raw"] = np.array([0.05, np.nan, np.nan, 0.4])
    log = TrackLog([fr], np.zeros((0, 7)), truth=[np.array([2.1, 3.0, 4.0, 5.2])],
                   truth_source=[np.array([1, 1, 0, 1], np.uint8)])
    rung = {r.name: r for r in standard_rungs()}["inpainted[exact]"]
    z, s = rung.depth(log, 0)
    np.testing.assert_array_equal(z, [2.0, 3.0, np.nan, 5.0])          # the hole without a 3-D point stays empty
    np.testing.assert_allclose(s, [0.05, 0.006, np.nan, 0.4])
    np.testing.assert_array_equal(rung.measured(log, 0), [True, False, False, True])
    res = {"inpainted[exact]": {"ate": {0: 0.05, 1: 0.06}, "failed": [], "chain": "", "order": 0},
           "depth-raw": {"ate": {0: 0.03, 1: 0.031}, "failed": [], "chain": "", "order": 0}}
    ok, bad = ladder_verdict({"seq": res})
    assert not ok and "inpainted[exact]" in bad[0]
    res["inpainted[exact]"]["ate"] = {0: 0.029, 1: 0.03}
    assert ladder_verdict({"seq": res})[0]
