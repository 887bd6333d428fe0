"""Static initialisation: gravity and gyro bias from a still window; a moving start is detected and named."""

import numpy as np
import pytest

from msckf.config import MsckfConfig
from msckf.errors import MsckfInputError
from msckf.init import NonStaticStartError, static_initialize
from msckf.rotation import so3_exp

LIMITS = MsckfConfig().init
RATE, N = 142.0, 200


def _window(R_w_i, bias, rng, gyro=None, acc_world=None, acc_sigma=0.05, gyro_sigma=0.005):
    t = np.arange(N) / RATE
    w = np.zeros((N, 3)) if gyro is None else gyro(t)
    a_w = np.zeros((N, 3)) if acc_world is None else acc_world(t)
    f = (a_w + np.array([0.0, 0.0, 9.81])) @ R_w_i           # specific force in the IMU frame (R_i_w f_w)
    return t, w + bias + rng.normal(0, gyro_sigma, (N, 3)), f + rng.normal(0, acc_sigma, (N, 3))


def test_gravity_direction_and_gyro_bias_from_a_still_window():
    rng = np.random.default_rng(0)
    R_w_i = so3_exp(np.array([1.2, -0.4, 0.7]))              # any tilt (Rosario's IMU has x up)
    bias = np.array([0.002, -0.001, 0.0015])
    t, g, a = _window(R_w_i, bias, rng)
    res = static_initialize(t, g, a, LIMITS)
    assert np.allclose(res.gyro_bias, bias, atol=4 * 0.005 / np.sqrt(N))
    assert abs(res.gravity_norm - 9.81) < 4 * 0.05 / np.sqrt(N)
    up = res.R_w_i @ a.mean(axis=0)
    assert np.allclose(up / np.linalg.norm(up), [0.0, 0.0, 1.0], atol=1e-12)
    # tilt agrees with the truth up to the (unobservable) yaw
    z_true = R_w_i.T @ np.array([0.0, 0.0, 1.0])
    z_est = res.R_w_i.T @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(np.clip(z_true @ z_est, -1, 1))) < 0.1


@pytest.mark.parametrize("motion, words", [
    ("turning", "mean angular rate"),
    ("starting", "first and last quarter"),
    ("bumpy", "specific-force std"),
    ("wobbling", "angular-rate std"),
    ("stopping_turn", "changed by .* rad/s"),
])
def test_a_moving_start_is_detected_and_named(motion, words):
    rng = np.random.default_rng(1)
    R_w_i = so3_exp(np.array([0.3, 0.2, -0.1]))
    kw = {
        "turning": dict(gyro=lambda t: np.tile([0.0, 0.0, 0.3], (len(t), 1))),                  # 17°/s yaw
        "starting": dict(acc_world=lambda t: np.outer(t / t[-1], [1.0, 0.0, 0.0])),             # speeding up
        "bumpy": dict(acc_world=lambda t: np.outer(np.sin(2 * np.pi * 8 * t), [0.3, 0.2, 1.5])),  # driving
        "wobbling": dict(gyro=lambda t: np.outer(np.sin(2 * np.pi * 3 * t), [0.3, 0.3, 0.0])),
        "stopping_turn": dict(gyro=lambda t: np.outer(t < 0.1, [0.0, 0.0, 0.4])),                # 0.1 s of turn
    }[motion]
    t, g, a = _window(R_w_i, np.zeros(3), rng, **kw)
    with pytest.raises(NonStaticStartError, match=words) as exc:
        static_initialize(t, g, a, LIMITS)
    assert isinstance(exc.value, MsckfInputError)
    assert "not static" in str(exc.value) and "200 IMU samples" in str(exc.value)


def test_filter_can_wait_for_a_still_period_after_a_moving_start():
    """A caller may catch the error and keep feeding: the window slides and initialisation succeeds later."""
    from msckf.filter import MsckfFilter
    from msckf.synthetic import rosario_extrinsics

    T_ci, T_10 = rosario_extrinsics()
    flt = MsckfFilter(MsckfConfig(), T_ci, T_10)
    rng = np.random.default_rng(2)
    R_w_i = so3_exp(np.array([0.0, -1.4, 0.1]))
    bias = np.array([0.003, 0.001, -0.002])
    errors = 0
    for k in range(int(4 * RATE)):                       # 1.5 s turning, then standing still
        t = k / RATE
        w = bias + rng.normal(0, 0.005, 3) + (np.array([0.0, 0.0, 0.4]) if t < 1.5 else 0.0)
        f = R_w_i.T @ np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.05, 3)
        try:
            flt.feed_imu(t, w, f)
        except NonStaticStartError:
            errors += 1
    assert errors >= 1 and flt.initialized
    assert flt.init_result.t_end > 1.5 + (N - 1) / RATE - 1e-9   # the accepted window is all still
    assert np.allclose(flt.init_result.gyro_bias, bias, atol=4 * 0.005 / np.sqrt(N))


def _initialised_filter(R_w_i, gyro_bias, acc_bias, rng, **init_overrides):
    """A filter statically initialised on a still window whose accelerometer reads ``acc_bias`` too."""
    from dataclasses import replace

    from msckf.filter import MsckfFilter

    cfg = MsckfConfig()
    # the window's IMU has a constant bias: (next to) no random walk in the filter's model either
    cfg = replace(cfg, init=replace(cfg.init, **init_overrides), imu_noise=replace(cfg.imu_noise, gyro_bias_noise=1e-9))
    flt = MsckfFilter(cfg, np.eye(4), np.eye(4))
    t, g, a = _window(R_w_i, gyro_bias, rng)
    for k in range(N):
        flt.feed_imu(t[k], g[k], a[k] + acc_bias)
    assert flt.state is not None
    return flt


def test_static_initial_covariance_covers_the_errors_the_window_leaves():
    """Right after a static initialisation the stated covariance must match the actual errors (NEES ≈ dof):
    the gyro bias is the window's mean rate (its variance is that mean's), roll/pitch carry the accelerometer bias
    the window cannot separate from gravity (δθ = [u]× b_a / g), the velocity is that of a robot standing still.
    S-MSCKF's covariance (zero tilt, σ 0.1 rad/s gyro bias) fails this: the tilt NEES is undefined/huge."""
    from msckf.state import BG, TH, VEL

    rng = np.random.default_rng(7)
    sigma_ba = np.sqrt(MsckfConfig().init.acc_bias_cov)
    nees_tilt, nees_bg = [], []
    for _ in range(60):
        R_w_i = so3_exp(rng.normal(0.0, 0.5, 3))
        bias = rng.normal(0.0, 0.003, 3)
        b_a = rng.normal(0.0, sigma_ba, 3)
        flt = _initialised_filter(R_w_i, bias, b_a, rng)
        P = flt.P
        # tilt error in the IMU frame (R_true = R_est · Exp(δθ)), yaw (about the up axis u) removed: it is the gauge
        u = flt.state.R_w_i.T @ np.array([0.0, 0.0, 1.0])
        R_err = flt.state.R_w_i.T @ R_w_i
        d = np.array([R_err[2, 1] - R_err[1, 2], R_err[0, 2] - R_err[2, 0], R_err[1, 0] - R_err[0, 1]]) / 2.0
        d = d - (d @ u) * u
        basis = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2]         # the two horizontal axes
        e, S = basis.T @ d, basis.T @ P[TH, TH] @ basis
        nees_tilt.append(e @ np.linalg.solve(S, e))
        eb = flt.state.b_g - bias
        nees_bg.append(eb @ np.linalg.solve(P[BG, BG], eb))
        assert np.allclose(np.diag(P[VEL, VEL]), 1e-4)
    # χ²(2) and χ²(3) means; 60 draws: a mean within ±50 % of the dof is consistent
    assert 1.0 < np.mean(nees_tilt) < 3.0
    assert 1.5 < np.mean(nees_bg) < 4.5
    flt = _initialised_filter(so3_exp(np.array([0.3, -0.2, 0.1])), np.zeros(3), np.full(3, sigma_ba), rng,
                              static_bias_from_window=False, static_velocity_cov=0.0,
                              static_tilt_from_acc_bias=False)
    assert np.all(flt.P[TH, TH] == 0.0)                                      # S-MSCKF: the tilt stated exact
    assert np.allclose(np.diag(flt.P[BG, BG]), 0.01) and np.allclose(np.diag(flt.P[VEL, VEL]), 0.25)
