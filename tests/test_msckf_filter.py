"""The MSCKF back end on a simulated feature world: consistency (NEES), convergence from a perturbed start,
static start, divergence detection, online reset, determinism and input errors."""

import numpy as np
import pytest
from scipy.stats import chi2

from msckf.errors import FilterDivergedError, MsckfInputError
from msckf.filter import MsckfFilter
from msckf.rotation import so3_exp, so3_log
from msckf.synthetic import (
    SIM_NOISE,
    Trajectory,
    anees_bounds,
    iterate,
    make_world,
    matched_config,
    nees_run,
    perturbed_filter,
)
from msckf.types import DepthSource, FeatureObservations

P0_DIAG = np.r_[[1e-4] * 3, [1e-6] * 3, [1e-3] * 3, [1e-4] * 3, [1e-4] * 3, [3.0462e-4] * 3, [2.5e-5] * 3]


def test_nees_of_position_and_orientation_is_consistent():
    """Monte-Carlo NEES (Bar-Shalom): the run-averaged NEES of the 3-d position and orientation errors must lie
    in the two-sided 95 % χ²(3N)/N interval — on average over the run and at ≥ 90 % of the frames."""
    n_runs = 6
    nees_p, nees_t = [], []
    for seed in range(n_runs):
        w = make_world(seed=seed, world_seed=0, duration=6.0, max_features=120)
        flt = perturbed_filter(w, matched_config(), P0_DIAG, np.random.default_rng(500 + seed))
        ep_run, et_run = nees_run(w, flt)
        nees_p.append(ep_run)
        nees_t.append(et_run)
    lo, hi = anees_bounds(n_runs)
    for name, nees in (("position", nees_p), ("orientation", nees_t)):
        anees = np.mean(nees, axis=0)
        assert lo < anees.mean() < hi, f"{name}: mean ANEES {anees.mean():.2f} outside [{lo:.2f}, {hi:.2f}]"
        inside = np.mean((anees > lo) & (anees < hi))
        assert inside >= 0.9, f"{name}: ANEES inside the 95 % bounds at only {inside:.0%} of the frames"


def test_converges_from_a_perturbed_start():
    """Start 0.3 m/s, 2° tilt and biases off (S-MSCKF initial covariances): the filter pulls them in."""
    w = make_world(seed=11, duration=8.0, max_features=150, gyro_bias0=np.array([0.01, -0.02, 0.015]),
                   acc_bias0=np.array([0.08, -0.05, 0.1]))
    cfg = matched_config(gyro_bias_cov=0.01, acc_bias_cov=0.01, velocity_cov=0.25)
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    dth = np.deg2rad([2.0, -2.0, 0.0])
    P0 = np.diag(np.r_[[np.deg2rad(3.0) ** 2] * 3, [0.01] * 3, [0.25] * 3, [0.01] * 3, [1e-6] * 3,
                       [3.0462e-4] * 3, [2.5e-5] * 3])
    flt.initialize(w.t0, w.R0 @ so3_exp(-w.R0.T @ dth), w.p0, w.v0 + np.array([0.3, -0.3, 0.2]),
                   np.zeros(3), np.zeros(3), 9.81, covariance=P0)
    v_err, tilt_err, tilt_nees = [], [], []
    for m, _ in iterate(w, flt):
        v_err.append(np.linalg.norm(flt.state.v - w.v_w[m]))
        e = so3_log(w.R_w_i[m] @ flt.state.R_w_i.T)[:2]            # world-frame roll/pitch error, rad
        S = (flt.state.R_w_i @ flt.P[0:3, 0:3] @ flt.state.R_w_i.T)[:2, :2]
        tilt_err.append(np.degrees(np.linalg.norm(e)))
        tilt_nees.append(e @ np.linalg.solve(S, e))
    assert v_err[0] > 0.4 and tilt_err[0] > 2.5
    assert np.max(v_err[-15:]) < 0.05
    # Tilt trades off against the accelerometer bias (0.1 m/s² ≈ 0.6°) until rotations separate them: it must
    # shrink a lot and stay within the filter's own 99 % uncertainty (χ²(2)).
    assert np.max(tilt_err[-15:]) < 0.25 * tilt_err[0]
    assert np.max(tilt_nees[-15:]) < chi2.ppf(0.99, 2)
    assert np.linalg.norm(flt.state.b_g - w.b_g[-1]) < 0.004      # from 0.027 rad/s off
    assert np.linalg.norm(flt.state.p - w.p_w[-1]) < 0.25          # after ~8 m


def test_static_start_initialises_and_tracks():
    traj = Trajectory(start_still=2.0)
    w = make_world(seed=5, duration=9.0, max_features=150, trajectory=traj, gyro_bias0=np.array([0.004, -0.003, 0.002]))
    flt = MsckfFilter(matched_config(gyro_bias_cov=1e-4), w.T_cam0_imu, w.T_cam1_cam0)
    poses = list(iterate(w, flt))
    n_init = sum(p is None for _, p in poses)
    assert 0 < n_init < 25                                        # 200 samples at 150 Hz ≈ 1.33 s
    res = flt.init_result
    # mean of 200 samples of white noise with density 0.002 rad/s/√Hz at 150 Hz: σ ≈ 0.0017 rad/s per axis
    sigma_mean = SIM_NOISE["gyro_noise"] * np.sqrt(150.0) / np.sqrt(200)
    assert np.all(np.abs(res.gyro_bias - w.b_g0) < 4 * sigma_mean)
    assert abs(res.gravity_norm - 9.81) < 4 * SIM_NOISE["acc_noise"] * np.sqrt(150.0) / np.sqrt(200)
    # The filter's world frame has an arbitrary yaw and its origin at the start: compare motion in a
    # yaw-aligned frame (rotation about z fitted on the trajectory).
    est = np.array([p.p_world for _, p in poses if p is not None])
    tru = w.p_w[n_init:] - w.p0
    d_est, d_tru = est[-1] - est[0], tru[-1] - tru[0]
    assert np.linalg.norm(d_tru) > 6.0
    assert abs(np.linalg.norm(d_est) - np.linalg.norm(d_tru)) < 0.1
    assert abs(d_est[2] - d_tru[2]) < 0.1


def test_moving_start_is_reported():
    w = make_world(seed=6, duration=3.0, max_features=50)        # driving and weaving from t = 0
    flt = MsckfFilter(matched_config(), w.T_cam0_imu, w.T_cam1_cam0)
    with pytest.raises(MsckfInputError, match="not static"):
        list(iterate(w, flt))


def test_garbage_imu_is_reported_as_divergence():
    w = make_world(seed=7, duration=2.0, max_features=60)
    flt = MsckfFilter(matched_config(), w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    rng = np.random.default_rng(0)
    with pytest.raises(FilterDivergedError) as exc:
        i = 0
        for obs in w.frames:
            while i < len(w.imu_t) and w.imu_t[i] <= obs.stamp_s:
                flt.feed_imu(w.imu_t[i], rng.normal(0, 5.0, 3), rng.normal(0, 400.0, 3))   # garbage
                i += 1
            flt.feed_features(obs)
    assert "speed" in exc.value.reason
    assert exc.value.stamp_s is not None


@pytest.mark.filterwarnings("ignore:invalid value encountered")
def test_broken_covariance_and_state_are_reported():
    w = make_world(seed=8, duration=1.0, max_features=40)
    for corrupt, words in (("nan_state", "non-finite"), ("nan_cov", "non-finite"),
                           ("indefinite", "positive semi-definite|negative variance")):
        flt = MsckfFilter(matched_config(), w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81, covariance=np.diag(P0_DIAG))
        it = iterate(w, flt)
        for _ in range(3):
            next(it)
        if corrupt == "nan_state":
            flt.state.v[0] = np.nan
        elif corrupt == "nan_cov":
            flt.P[5, 7] = np.inf
        else:
            flt.P[6, 6], flt.P[6, 7], flt.P[7, 6], flt.P[7, 7] = 1e-3, 1.0, 1.0, 1e-3
        with pytest.raises(FilterDivergedError, match=words):
            next(it)


def test_online_reset_when_position_uncertainty_explodes():
    w = make_world(seed=9, duration=3.0, max_features=60)
    flt = MsckfFilter(matched_config(position_std_threshold=0.02), w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    resets = []
    for _, pose in iterate(w, flt):
        resets.append(flt.last_stats.online_reset)
        assert pose is not None
    assert any(resets) and flt.n_online_resets == sum(resets)
    assert np.linalg.norm(flt.state.p - w.p_w[-1]) < 0.5             # dead-reckons on, keeps going


def test_same_inputs_give_bit_identical_outputs():
    w = make_world(seed=10, duration=3.0, max_features=100, mono_fraction=0.2, outlier_fraction=0.02)
    outs = []
    for _ in range(2):
        flt = MsckfFilter(matched_config(), w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        outs.append(np.array([np.r_[p.p_world, p.q_world_imu_xyzw, p.v_world, p.cov_diag] for _, p in iterate(w, flt)]))
    assert np.array_equal(outs[0], outs[1])


@pytest.mark.parametrize("variant", ["mono", "depth", "depth_row"])  # "depth": the virtual-stereo model
def test_monocular_and_depth_observations_track(variant):
    kw = dict(mono_fraction=1.0) if variant == "mono" else dict(depth_mode=True, depth_rel_sigma=0.01)
    w = make_world(seed=12, duration=6.0, max_features=150, **kw)
    cfg = matched_config(depth_row=variant == "depth_row", depth_rel_sigma=0.01, depth_inv_sigma=1e-3,
                         depth_keep_mono=variant == "mono")       # a monocular world needs its mono observations
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    for _ in iterate(w, flt):
        pass
    assert np.linalg.norm(flt.state.p - w.p_w[-1]) < 0.15           # after ~6 m


def test_input_errors_are_clear():
    w = make_world(seed=13, duration=1.0, max_features=20)
    flt = MsckfFilter(matched_config(), w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    flt.feed_imu(0.01, np.zeros(3), np.array([0, 0, 9.81]))
    with pytest.raises(MsckfInputError, match="backwards"):
        flt.feed_imu(0.005, np.zeros(3), np.zeros(3))
    with pytest.raises(MsckfInputError, match="non-finite"):
        flt.feed_imu(0.02, np.array([np.nan, 0, 0]), np.zeros(3))
    with pytest.raises(MsckfInputError, match="3 values"):
        flt.feed_imu(0.02, np.zeros(2), np.zeros(3))
    obs = w.frames[0]
    flt.feed_features(obs)
    with pytest.raises(MsckfInputError, match="increase"):
        flt.feed_features(obs)
    dup = FeatureObservations(obs.stamp_s + 1, np.array([1, 1]), np.zeros((2, 2)), np.zeros((2, 2)),
                              np.full(2, np.nan), np.full(2, DepthSource.STEREO_MATCH, np.uint8), np.ones(2, np.int32))
    with pytest.raises(MsckfInputError, match="duplicate"):
        flt.feed_features(dup)
    with pytest.raises(MsckfInputError, match="4x4"):
        MsckfFilter(matched_config(), np.eye(3), w.T_cam1_cam0)


def _with_biased_depth(w, every: int, factor: float):
    """The world's frames with the depth of every ``every``-th track scaled by ``factor`` in all its frames (a
    bad fill shared along the track) and the virtual cam1 coordinate re-derived from that depth."""
    from dataclasses import replace
    R_10, t_10 = w.T_cam1_cam0[:3, :3], w.T_cam1_cam0[:3, 3]
    frames = []
    for obs in w.frames:
        bad = (obs.ids % every == 0) & (obs.source == DepthSource.DEPTH_MAP)
        z = np.where(bad, obs.depth_m * factor, obs.depth_m)
        q1 = (np.concatenate([obs.cam0_xy, np.ones((len(z), 1))], axis=1) * z[:, None]) @ R_10.T + t_10
        c1 = np.where(bad[:, None], q1[:, :2] / q1[:, 2:3], obs.cam1_xy)
        frames.append(replace(obs, depth_m=z, cam1_xy=c1))
    return replace(w, frames=frames)


def _gate_counts_and_error(w, **overrides) -> tuple[int, int, float]:
    """Run the filter over world ``w`` with a tight depth σ (plus ``overrides``): (features gated out, features
    accepted by the depth fallback, final position error in m)."""
    cfg = matched_config(depth_rel_sigma=0.01, depth_inv_sigma=1e-3, **overrides)
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    n_out = n_fb = 0
    for _ in iterate(w, flt):
        n_out += flt.last_stats.n_gated_out
        n_fb += flt.last_stats.n_depth_fallback
    return n_out, n_fb, float(np.linalg.norm(flt.state.p - w.p_w[-1]))


def test_depth_fallback_keeps_the_pixels_of_a_feature_whose_depth_fails_the_gate():
    """A track whose (filled) depth is 60 % off fails the gate as a whole; with ``depth_fallback`` its cam0
    pixels are gated again alone and used, so fewer features are lost and the estimate does not get worse
    (measured: 136 rejected → 66 rejected + 71 back; final error 0.101 → 0.102 m after ≈ 5 m)."""
    w = _with_biased_depth(make_world(seed=5, duration=5.0, max_features=150, depth_mode=True,
                                      depth_rel_sigma=0.01), every=4, factor=1.6)
    res = {fallback: _gate_counts_and_error(w, depth_fallback=fallback) for fallback in (False, True)}
    (out0, fb0, err0), (out1, fb1, err1) = res[False], res[True]
    assert fb0 == 0 and out0 > 50                       # the biased tracks are rejected without the fallback
    assert fb1 > 0.4 * out0 and out1 < 0.6 * out0       # … and half of them come back without their depth
    assert fb1 + out1 <= out0 + 10                      # the fallback re-gates rejected features only
    assert err1 < 0.15 and err1 <= err0 * 1.05, res     # pixels used that were lost: not worse


def test_depth_fallback_leaves_measured_depths_alone():
    """Only filled depths are dropped on a retry: a feature whose biased depth is flagged as *measured* stays
    rejected (the fallback never turns a failed measurement into a mono feature)."""
    from dataclasses import replace
    w = _with_biased_depth(make_world(seed=5, duration=3.0, max_features=150, depth_mode=True,
                                      depth_rel_sigma=0.01), every=4, factor=1.6)
    w = replace(w, frames=[replace(f, depth_measured=np.isfinite(f.depth_m)) for f in w.frames])
    poses = {}
    for fallback in (False, True):
        cfg = matched_config(depth_rel_sigma=0.01, depth_inv_sigma=1e-3, depth_fallback=fallback)
        flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        outs = [np.r_[p.p_world, p.cov_diag] for _, p in iterate(w, flt) if p is not None]
        poses[fallback] = np.array(outs)
    assert np.array_equal(poses[False], poses[True])


def test_depth_fallback_measured_also_drops_measured_depths_on_a_retry():
    """With ``depth_fallback_measured`` a feature whose *measured* depth is 60 % off is gated again from its
    pixels alone, as a filled one is: rejected features come back, and the estimate is not worse."""
    from dataclasses import replace
    w = _with_biased_depth(make_world(seed=5, duration=5.0, max_features=150, depth_mode=True,
                                      depth_rel_sigma=0.01), every=4, factor=1.6)
    w = replace(w, frames=[replace(f, depth_measured=np.isfinite(f.depth_m)) for f in w.frames])
    res = {measured: _gate_counts_and_error(w, depth_fallback=True, depth_fallback_measured=measured)
           for measured in (False, True)}
    (out0, fb0, err0), (out1, fb1, err1) = res[False], res[True]
    assert fb0 == 0 and out0 > 50                       # measured depths: no retry without the option
    assert fb1 > 0.4 * out0 and out1 < 0.6 * out0, res  # with it, the pixels of half of them come back
    assert err1 < 0.15 and err1 <= err0 * 1.05, res


def test_whiten_depth_shared_with_two_terms_gives_the_nominal_chi2():
    """Depth rows whose errors are white + a per-feature constant (√β each) + a per-feature scale term a_i (its
    own size per reading): whitened with both terms their χ² has the nominal mean; one term alone leaves it
    inflated; a zero term changes nothing."""
    from msckf.update import FeatureBatch, whiten_depth_shared

    rng = np.random.default_rng(5)
    k, n, beta = 3000, 6, 0.5
    rows = np.zeros((k, n, 5), bool)
    rows[:, :, 4] = True
    a = rng.uniform(0.5, 3.0, size=(k, n))
    err = rng.normal(size=(k, n)) + np.sqrt(beta) * rng.normal(size=(k, 1)) + a * rng.normal(size=(k, 1))
    r = np.zeros((k, n, 5))
    r[:, :, 4] = err
    b = FeatureBatch(np.zeros((k, n), np.int64), np.zeros((k, n, 5, 6)), np.zeros((k, n, 5, 3)), r, rows)
    both = whiten_depth_shared(b, np.stack([np.full((k, n), np.sqrt(beta)), a], axis=-1))
    only_track = whiten_depth_shared(b, np.full((k, n), np.sqrt(beta)))
    chi2 = {name: np.sum(x.r[:, :, 4] ** 2, axis=1).mean() / n for name, x in
            (("both", both), ("track", only_track))}
    assert 0.93 < chi2["both"] < 1.07, chi2
    assert chi2["track"] > 2.0, chi2
    assert whiten_depth_shared(b, np.zeros((k, n))) is b


def test_depth_keep_mono_false_ignores_monocular_observations_exactly():
    """``depth_keep_mono: false``: a world with 40 % monocular observations gives bit-identical poses to the same
    world with those observations removed before the filter (and different ones with them kept)."""
    from dataclasses import replace
    w = make_world(seed=2, duration=2.0, max_features=150, depth_mode=True, depth_rel_sigma=0.01,
                   mono_fraction=0.4)
    w_cut = replace(w, frames=[f.subset(f.source != DepthSource.MONO) for f in w.frames])
    assert sum(len(f) for f in w_cut.frames) < 0.7 * sum(len(f) for f in w.frames)
    runs = {}
    for name, world, keep in (("ignored", w, False), ("removed", w_cut, True), ("kept", w, True)):
        flt = MsckfFilter(matched_config(depth_keep_mono=keep), w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        runs[name] = np.array([np.r_[p.p_world, p.cov_diag] for _, p in iterate(world, flt) if p is not None])
    assert np.array_equal(runs["ignored"], runs["removed"])
    assert not np.array_equal(runs["ignored"], runs["kept"])


def test_pose_nees_weighs_the_pose_error_by_the_filters_covariance():
    """``pose_nees``: position error against the p block, orientation error (R̂ᵀR_true) against the θ block."""
    from msckf.config import load_config

    flt = MsckfFilter(load_config(None), np.eye(4), np.eye(4))
    P0 = np.diag(np.r_[[1e-4] * 3, [1e-6] * 3, [1e-2] * 3, [1e-4] * 3, [4e-2] * 3, [1e-5] * 3, [1e-5] * 3])
    R0, p0 = so3_exp(np.array([0.0, 0.0, 0.3])), np.array([1.0, 2.0, 0.5])
    flt.initialize(0.0, R0, p0, covariance=P0)
    e_p, e_t = flt.pose_nees(R0 @ so3_exp(np.array([0.0, 0.02, 0.0])), p0 + np.array([0.0, 0.4, 0.0]))
    assert e_p == pytest.approx(0.4 ** 2 / 4e-2)
    assert e_t == pytest.approx(0.02 ** 2 / 1e-4)
    flt.P[12:15, 12:15] = 0.0                      # as right after an online reset: no position uncertainty claimed
    e_p, e_t = flt.pose_nees(R0, p0 + np.array([0.0, 0.4, 0.0]))
    assert np.isnan(e_p) and e_t == pytest.approx(0.0)


def _with_track_scaled_depth(w, rel_sigma: float, seed: int):
    """The world's frames with every track's depth multiplied by one factor 1 + N(0, rel_sigma) of its own, the
    same in all its frames (the per-track disagreement between a tracked point and the map measured on the
    simulator), and the virtual cam1 coordinate re-derived from that depth."""
    from dataclasses import replace
    rng = np.random.default_rng(seed)
    top = max(int(f.ids.max()) for f in w.frames if len(f.ids)) + 1
    factor = 1.0 + rel_sigma * rng.standard_normal(top)
    R_10, t_10 = w.T_cam1_cam0[:3, :3], w.T_cam1_cam0[:3, 3]
    frames = []
    for obs in w.frames:
        z = obs.depth_m * factor[obs.ids]
        q1 = (np.concatenate([obs.cam0_xy, np.ones((len(z), 1))], axis=1) * z[:, None]) @ R_10.T + t_10
        frames.append(replace(obs, depth_m=z, cam1_xy=q1[:, :2] / q1[:, 2:3]))
    return replace(w, frames=frames)


def test_depth_shared_rel_sigma_makes_the_filter_less_overconfident_with_per_track_depth_errors():
    """Depths that are precise within a track (0.2 %) but off by one 3 % factor per track: told they are
    independent, the filter is overconfident (ANEES of position above the 95 % bound); with
    ``depth_shared_rel_sigma`` at the true 3 % it is less so. Measured (stop 40): ANEES 9.1 → 7.9, final error
    8.3 → 9.6 cm; since the features are triangulated again before each update (stop 47): 8.1 → 6.0, 8.7 → 8.2
    cm — the model does *not* reach consistency (the same term on depths without shared errors raises the ANEES
    5.2 → 7.5 from this perturbed start, 1.5 → 4.2 from the true one): open, see the README."""
    runs = 4
    res = {}
    for s in (0.0, 0.03):
        nees, err = [], []
        for seed in range(runs):
            w = _with_track_scaled_depth(make_world(seed=seed, world_seed=0, duration=6.0, max_features=120,
                                                    depth_mode=True, depth_rel_sigma=0.002), 0.03, seed)
            cfg = matched_config(depth_row=True, depth_rel_sigma=0.002, depth_inv_sigma=1e-6,
                                 depth_shared_rel_sigma=s)
            flt = perturbed_filter(w, cfg, P0_DIAG, np.random.default_rng(500 + seed))
            ep, _ = nees_run(w, flt)
            nees.append(np.mean(ep))
            err.append(np.linalg.norm(flt.state.p - w.p_w[-1]))
        res[s] = (float(np.mean(nees)), float(np.mean(err)))
    _, hi = anees_bounds(runs)
    assert res[0.0][0] > 1.3 * hi, res                   # independent readings: overconfident
    assert res[0.03][0] < 0.95 * res[0.0][0], res        # the shared term: less so


def _with_filled_frames(w, shift_px: float, all_filled_every: int = 0):
    """The world's frames with, for tracks ``id % 3 == 0``, every other observation flagged *filled* and moved by
    ``shift_px`` (the pixel by that many px, the depth by shift_px × 10 %: what a point inside SGBM's hole gets), the
    rest measured; with ``all_filled_every`` > 0, tracks ``id % all_filled_every == 1`` filled in every frame (and
    moved the same way)."""
    from dataclasses import replace
    out = []
    for k, f in enumerate(w.frames):
        mixed = (f.ids % 3 == 0) & (k % 2 == 0)
        only = (f.ids % all_filled_every == 1) if all_filled_every else np.zeros(len(f.ids), dtype=bool)
        filled = (mixed | only) & np.isfinite(f.depth_m)
        c0 = f.cam0_xy + np.where(filled[:, None], shift_px / 351.06, 0.0)
        z = np.where(filled, f.depth_m * (1.0 + shift_px / 10.0), f.depth_m)
        out.append(replace(f, cam0_xy=c0, depth_m=z, depth_measured=~filled & np.isfinite(f.depth_m)))
    return replace(w, frames=out)


def _depth_run(world, stop_after: int | None = None, **cfg_overrides):
    """Poses (position + covariance diagonal) and every frame's gate statistics of one run on ``world``."""
    cfg = matched_config(**cfg_overrides)
    flt = MsckfFilter(cfg, world.T_cam0_imu, world.T_cam1_cam0)
    flt.initialize(world.t0, world.R0, world.p0, world.v0, world.b_g0, world.b_a0, 9.81)
    poses, gammas = [], []
    for _, p in iterate(world, flt, stop_after=stop_after):
        if p is not None:
            poses.append(np.r_[p.p_world, p.cov_diag])
        gammas.append(np.concatenate(flt.last_stats.gate_gamma) if flt.last_stats.gate_gamma else np.zeros(0))
    return np.array(poses), gammas


def test_fills_only_unmeasured_ignores_the_filled_observations_of_measured_tracks():
    """With ``depth_fills_only_unmeasured`` the filled observations of a track that has a measured depth in the
    window are not used at all (whatever they hold, the estimate is bit-identical); a track with only filled depths
    still uses them; without the option both kinds change the estimate."""
    w = make_world(seed=3, duration=3.0, max_features=120, depth_mode=True, depth_rel_sigma=0.01)

    def run(world, on: bool) -> np.ndarray:
        return _depth_run(world, depth_rel_sigma=0.01, depth_inv_sigma=1e-3, depth_fills_only_unmeasured=on)[0]

    a, b = _with_filled_frames(w, 2.0), _with_filled_frames(w, -1.0)
    assert np.array_equal(run(a, True), run(b, True))           # the mixed tracks' fills are not used
    assert not np.array_equal(run(a, False), run(b, False))     # … and are without the option
    c, d = _with_filled_frames(w, 2.0, all_filled_every=7), _with_filled_frames(w, -1.0, all_filled_every=7)
    assert not np.array_equal(run(c, True), run(d, True))       # a track with only filled depths keeps them


def test_depth_min_rel_sigma_raises_a_stated_sigma_to_the_floor_and_leaves_larger_ones():
    """``depth_min_rel_sigma`` f: a reading that states σ_Z < f·Z is used exactly as one that states f·Z (the same
    estimate, bit for bit); a reading that states more is untouched; without the floor the small σ counts."""
    from dataclasses import replace
    w = make_world(seed=4, duration=2.0, max_features=100, depth_mode=True, depth_rel_sigma=0.005)

    def stating(rel: float):
        return replace(w, frames=[replace(f, depth_sigma_m=rel * f.depth_m) for f in w.frames])

    floored, _ = _depth_run(stating(0.005), depth_min_rel_sigma=0.03)
    told, _ = _depth_run(stating(0.03))
    own, _ = _depth_run(stating(0.005))
    assert len(floored) > 10
    np.testing.assert_array_equal(floored, told)
    assert not np.allclose(floored, own, rtol=1e-6, atol=1e-9)
    above, _ = _depth_run(stating(0.05), depth_min_rel_sigma=0.03)
    np.testing.assert_array_equal(above, _depth_run(stating(0.05))[0])


def test_depth_sigma_scale_weighs_depth_rows_at_k_sigma_in_the_update_only():
    """``depth_sigma_scale`` k: the update (and triangulation) weigh every depth reading as if its σ were k × its
    own — the same estimate as a filter told k × σ, when neither gates anything — while the χ² gate tests the
    reading at its own σ (the first update's γ's are those of k = 1, not those of the filter told k × σ)."""
    w = make_world(seed=4, duration=2.0, max_features=100, depth_mode=True, depth_rel_sigma=0.01)
    common = dict(depth_motion_rel_sigma=10.0, gate_depth_scale=0.0)
    no_gate = dict(common, chi2_quantile=1.0 - 1e-12)
    scaled, _ = _depth_run(w, depth_inv_sigma=1e-3, depth_rel_sigma=0.01, depth_sigma_scale=4.0, **no_gate)
    told, _ = _depth_run(w, depth_inv_sigma=4e-3, depth_rel_sigma=0.04, **no_gate)
    own, _ = _depth_run(w, depth_inv_sigma=1e-3, depth_rel_sigma=0.01, **no_gate)
    assert len(scaled) > 10
    np.testing.assert_allclose(scaled, told, rtol=1e-6, atol=1e-9)
    assert not np.allclose(scaled, own, rtol=1e-6, atol=1e-9)
    # the gate: γ at the first update with a depth row is computed with the reading's own σ
    _, g_scaled = _depth_run(w, stop_after=12, depth_inv_sigma=1e-3, depth_rel_sigma=0.01, depth_sigma_scale=4.0,
                             **common)
    _, g_own = _depth_run(w, stop_after=12, depth_inv_sigma=1e-3, depth_rel_sigma=0.01, **common)
    _, g_told = _depth_run(w, stop_after=12, depth_inv_sigma=4e-3, depth_rel_sigma=0.04, **common)
    first = next(i for i, g in enumerate(g_own) if len(g))
    # equal up to the triangulated linearisation point (its depth is weighed at k σ: measured 1.5e-4 apart)
    np.testing.assert_allclose(g_scaled[first], g_own[first], rtol=1e-3)
    assert np.all(np.abs(g_told[first] / g_own[first] - 1.0) > 0.05)


def test_features_are_triangulated_again_from_their_current_observations_before_an_update():
    """A position triangulated earlier (from observations the window has since dropped, or with a depth it no longer
    holds) is stale: with tight depth rows its second-order error passes the null-space projection as a bogus
    correction (stop 47: one such feature, triangulated with a SGBM depth 20 % off and later updated with exact
    fills, moved the accelerometer bias by 0.02 m/s² in one update). With ``update.retriangulate`` (default) every
    feature that enters an update is triangulated again from its current observations; S-MSCKF (off) keeps the
    cached position."""
    from scipy.spatial import cKDTree

    from msckf.filter import FrameStats

    w = make_world(seed=3, duration=3.0, depth_mode=True, depth_rel_sigma=0.002)
    tree = cKDTree(w.landmarks)
    for flag in (True, False):
        flt = MsckfFilter(matched_config(retriangulate=flag), w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        list(iterate(w, flt, stop_after=25))
        fs, cl = flt.features, flt.clones
        rows = fs.alive_rows()
        rows = rows[fs.initialized[rows]]
        assert len(rows) > 50                        # pruning has triangulated many features that are still tracked
        cam = cl.p[flt._order()[-1]]

        def rel_err(p: np.ndarray, cam: np.ndarray = cam) -> np.ndarray:   # nearest landmark / range from camera
            return tree.query(p)[0] / np.linalg.norm(p - cam, axis=1)

        assert np.median(rel_err(fs.pos[rows])) < 0.02        # right before: close to the landmarks
        before = fs.pos[rows].copy()
        fs.pos[rows] = cam + 1.25 * (before - cam)   # stale: 25 % too far along the ray from the newest camera
        used = flt._positions_for_update(rows, FrameStats())
        moved = np.linalg.norm(fs.pos[used] - before[np.isin(rows, used)], axis=1) / np.linalg.norm(
            before[np.isin(rows, used)] - cam, axis=1)
        if flag:
            assert len(used) > 0.9 * len(rows) and np.median(moved) < 0.02 and np.median(rel_err(fs.pos[used])) < 0.02
        else:
            assert len(used) == len(rows) and np.allclose(moved, 0.25)


def test_zero_velocity_update_fires_while_the_robot_stands_and_only_then():
    """A robot that stands loses no track and its window does not prune until full: nothing but the IMU constrains
    the state. The zero-velocity update (``update.zupt_max_flow``; here at every still image, ``zupt_only_at_start``
    off, which also fires on a robot creeping at a few cm/s, README) fires on the images whose features did not move
    — nearly every image of the stand — and on none once the robot drives; it pins the velocity (σ ≤ 1 cm/s after the
    stand) where, off, the velocity is left to the IMU."""
    from msckf.filter import FrameStats

    traj = Trajectory(start_still=2.5)
    # 0.2 px of white pixel noise: a KLT track's frame-to-frame jitter (stop 20: 0.08–0.2 px), not the 1 px default
    w = make_world(seed=4, duration=5.0, max_features=150, trajectory=traj, depth_mode=True, depth_rel_sigma=0.01,
                   pixel_sigma=0.2)
    moving_from = 2.5                                           # the ramp starts at start_still
    for zupt in (0.001, 0.0):
        flt = MsckfFilter(matched_config(zupt_max_flow=zupt, velocity_cov=0.25, zupt_only_at_start=False),
                          w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        fired, still_frames, v_sigma_end_of_stand = [], 0, None
        for m, _ in iterate(w, flt):
            st: FrameStats = flt.last_stats
            t = w.frame_t[m]
            if m >= 1:
                fired.append((t, st.zupt))
            if t < moving_from:
                still_frames += 1
                v_sigma_end_of_stand = float(np.sqrt(np.max(np.diag(flt.P[6:9, 6:9]))))
        if zupt > 0:
            on_still = [f for t, f in fired if t < moving_from]
            on_moving = [f for t, f in fired if t > moving_from + 0.5]   # 0.5 s into the ramp: clearly moving
            # (an image may miss it: the pruning's clone choice or the χ² gate; the ramp's first 0.3 s, below
            # 3 cm/s, still looks still)
            assert np.mean(on_still) >= 0.85 and len(on_still) >= still_frames - 2
            assert not any(on_moving)
            assert v_sigma_end_of_stand < 0.01
        else:
            assert not any(f for _, f in fired)
            assert v_sigma_end_of_stand > 0.05                     # the IMU alone leaves it loose


class _StopAndGo(Trajectory):
    """Stands, drives at ``speed`` and stands again: the time warp's rate s'(t) ramps 0 → 1 over ``go`` and
    1 → 0 over ``stop`` (each (start s, duration s), smoothstep C², as ``Trajectory``'s start)."""

    go: tuple[float, float] = (1.5, 1.5)
    stop: tuple[float, float] = (4.0, 1.5)

    def _s(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        s, sd, sdd = np.zeros_like(t), np.zeros_like(t), np.zeros_like(t)
        for (t0, T), step in ((self.go, 1.0), (self.stop, -1.0)):
            u = np.clip((t - t0) / T, 0.0, 1.0)
            s += step * (T * (u**6 - 3 * u**5 + 2.5 * u**4) + np.maximum(t - t0 - T, 0.0))
            sd += step * (6 * u**5 - 15 * u**4 + 10 * u**3)
            sdd += step * np.where((u > 0) & (u < 1), (30 * u**4 - 60 * u**3 + 30 * u**2) / T, 0.0)
        return s, sd, sdd


def test_zero_velocity_update_only_at_start_ends_once_the_robot_moved():
    """``update.zupt_only_at_start`` (default): the zero-velocity update fires while the robot stands at the start
    and never again once it was seen moving — not in a second stand either (a per-image flow test cannot tell a
    robot creeping at a few cm/s from a standing one, README); with it off the second stand gets it too."""
    traj = _StopAndGo()
    # 0.1 px white pixel noise: median image motion ≈ 0.17 px while standing, half the 0.001 (0.35 px at this
    # world's fx) threshold — one image above it would (correctly) end the zero-velocity updates here
    w = make_world(seed=4, duration=7.5, max_features=150, trajectory=traj, depth_mode=True, depth_rel_sigma=0.01,
                   pixel_sigma=0.1)
    _, v, _ = traj.position(w.frame_t)
    speed = np.linalg.norm(v, axis=1)
    first_stand = w.frame_t < traj.go[0]
    second_stand = w.frame_t > sum(traj.stop)
    assert np.all(speed[first_stand | second_stand] < 1e-9) and speed.max() > 0.9
    fired = {}
    for only_at_start in (True, False):
        flt = MsckfFilter(matched_config(zupt_max_flow=0.001, velocity_cov=0.25, zupt_only_at_start=only_at_start),
                          w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        f = np.zeros(len(w.frame_t), dtype=bool)
        for m, _ in iterate(w, flt):
            f[m] = flt.last_stats.zupt
        fired[only_at_start] = f
        assert flt.has_moved
    for f in fired.values():
        assert np.mean(f[first_stand][1:]) >= 0.85            # the first image has no image before it
    moving = w.frame_t > traj.go[0] + 0.5                      # the ramp's first 0.5 s (< 5 cm/s) may look still
    assert not fired[True][moving].any()
    assert np.mean(fired[False][second_stand]) >= 0.85


def test_extrinsics_after_motion_holds_the_extrinsics_while_the_robot_stands():
    """``update.extrinsics_after_motion``: while the robot stands at the start (unobservable there) the camera–IMU
    extrinsics keep their value and a zero covariance; at the first image that shows motion their prior covariance
    comes back, uncorrelated; off, they carry their prior and are updated during the stand."""
    traj = _StopAndGo()
    w = make_world(seed=4, duration=3.5, max_features=150, trajectory=traj, depth_mode=True, depth_rel_sigma=0.01,
                   pixel_sigma=0.1)
    prior = 3.0462e-4
    for on in (True, False):
        flt = MsckfFilter(matched_config(zupt_max_flow=0.001, velocity_cov=0.25, extrinsics_after_motion=on,
                                         extrinsic_rotation_cov=prior), w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        R0 = flt.state.R_c_i.copy()
        var_stand, var_release, moved_at = [], None, None
        for m, _ in iterate(w, flt):
            v = np.diag(flt.P[15:18, 15:18]).max()
            if not flt.has_moved:
                var_stand.append(v)
                drift = np.linalg.norm(so3_log(flt.state.R_c_i @ R0.T))
            elif moved_at is None:
                moved_at, var_release = w.frame_t[m], np.diag(flt.P[15:18, 15:18])
        assert moved_at is not None and moved_at < traj.go[0] + 1.0
        if on:
            assert max(var_stand) < 1e-12 and drift < 1e-9
            assert np.all(var_release > 0.5 * prior)                # restored (one image's updates may shrink it)
            assert np.abs(flt.P[15:18, :15]).max() > 0.0            # and correlated again by the later updates
        else:
            assert min(var_stand) > 0.1 * prior


def test_gate_verdicts_name_each_gated_feature_and_what_the_gate_did_with_it():
    """``FrameStats.gate_ids`` / ``gate_verdict`` line up with ``gate_gamma``; their counts are the frame's
    ``n_gated_out`` (verdict 0) and ``n_depth_fallback`` (verdict 2); the tracks given a 60 % wrong depth are turned
    away or taken back without their depth far more often than the others."""
    w = _with_biased_depth(make_world(seed=5, duration=5.0, max_features=150, depth_mode=True,
                                      depth_rel_sigma=0.01), every=4, factor=1.6)
    cfg = matched_config(depth_rel_sigma=0.01, depth_inv_sigma=1e-3, depth_fallback=True)
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    ids_all, verdict_all = [], []
    for _ in iterate(w, flt):
        st = flt.last_stats
        assert len(st.gate_ids) == len(st.gate_verdict) == len(st.gate_gamma)
        for ids, v, g in zip(st.gate_ids, st.gate_verdict, st.gate_gamma):
            assert ids.shape == v.shape == np.shape(g)
        v = np.concatenate(st.gate_verdict) if st.gate_verdict else np.zeros(0, np.int8)
        assert np.count_nonzero(v == 0) == st.n_gated_out
        assert np.count_nonzero(v == 2) == st.n_depth_fallback
        ids_all += list(st.gate_ids)
        verdict_all += list(st.gate_verdict)
    ids, verdict = np.concatenate(ids_all), np.concatenate(verdict_all)
    assert set(np.unique(verdict)) <= {0, 1, 2}
    biased = ids % 4 == 0
    turned_away = verdict != 1
    # measured: 79 of 721 gated biased features turned away (11 %), 54 of 2316 others (2.3 %): a depth error shared
    # along a track moves the feature's position and shows only through parallax, so the gate catches few of them
    assert turned_away[biased].mean() > 2.5 * turned_away[~biased].mean(), (turned_away[biased].mean(),
                                                                           turned_away[~biased].mean())
    assert np.count_nonzero(verdict[biased] == 2) > 0
