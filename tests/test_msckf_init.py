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
