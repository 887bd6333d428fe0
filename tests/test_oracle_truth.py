"""The truth of oracle runs in a VIO's own world frame, and the NEES the filter reports against it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msckf.rotation import so3_exp
from pipeline.oracle_truth import AnchoredTruth, TrueImuPoses


def _circle_truth() -> TrueImuPoses:
    t = np.linspace(0.0, 10.0, 2001)
    p = np.stack([5 * np.cos(0.2 * t), 5 * np.sin(0.2 * t), 0.1 * t], axis=1)
    q = Rotation.from_euler("zyx", np.stack([0.2 * t + np.pi / 2, 0.02 * np.sin(t), 0.03 * np.cos(t)], axis=1))
    return TrueImuPoses(t, p, q.as_quat())


def test_truth_is_interpolated_between_samples_and_refuses_times_outside():
    tr = _circle_truth()
    R, p = tr.at(3.0025)  # half-way between two samples
    R0, p0 = tr.at(3.0)
    R1, p1 = tr.at(3.005)
    np.testing.assert_allclose(p, (p0 + p1) / 2, atol=1e-12)
    half = Rotation.from_matrix(R0.T @ R1).as_rotvec() / 2
    np.testing.assert_allclose(R, R0 @ Rotation.from_rotvec(half).as_matrix(), atol=1e-12)
    with pytest.raises(ValueError, match="outside the truth's span"):
        tr.at(10.5)


def test_anchor_takes_the_estimates_yaw_and_origin_but_not_its_roll_and_pitch():
    """A run whose world is the truth's turned by 40° about the vertical and shifted: the anchored truth equals the
    estimate wherever the estimate is exact; an initial tilt error of the estimate stays an error."""
    tr = _circle_truth()
    yaw = np.deg2rad(40.0)
    R_W_E = so3_exp(np.array([0.0, 0.0, yaw]))
    t_W_E = np.array([1.0, -2.0, 0.5])
    anch = AnchoredTruth(tr)
    for t_s in (0.5, 4.0, 9.0):
        R_E, p_E = tr.at(t_s)
        R_true, p_true = anch(t_s, R_W_E @ R_E, R_W_E @ p_E + t_W_E)
        np.testing.assert_allclose(R_true, R_W_E @ R_E, atol=1e-12)
        np.testing.assert_allclose(p_true, R_W_E @ p_E + t_W_E, atol=1e-12)
    tilted = AnchoredTruth(tr)
    R_E, p_E = tr.at(0.5)
    tilt = so3_exp(np.array([0.01, 0.0, 0.0]))
    R_true, _ = tilted(0.5, R_W_E @ R_E @ tilt, R_W_E @ p_E)
    err = Rotation.from_matrix((R_W_E @ R_E @ tilt).T @ R_true).magnitude()
    assert 0.009 < err < 0.011


def test_nees_accumulator_leaves_frames_without_a_defined_nees_out_and_counts_them():
    """A frame whose covariance block is singular (a filter right after an online reset claims zero position
    uncertainty) has no NEES: the run's means skip it instead of crashing, and say how many were skipped."""
    from msckf.config import load_config
    from msckf.filter import MsckfFilter
    from pipeline.depth_oracle import NeesAccumulator

    tr = _circle_truth()
    R0, p0 = tr.at(0.0)
    flt = MsckfFilter(load_config(None), np.eye(4), np.eye(4))
    flt.initialize(0.0, R0, p0, covariance=np.eye(21) * 1e-2)
    acc = NeesAccumulator(tr)
    acc.add(flt, 0.0)
    flt.P[12:15, 12:15] = 0.0
    acc.add(flt, 0.0)
    st = acc.stats()
    assert st["nees_undefined_frames"] == 1.0
    assert st["nees_position_mean"] == pytest.approx(0.0) and np.isfinite(st["nees_orientation_mean"])
    assert np.isfinite(st["nees_tilt_mean"]) and np.isfinite(st["nees_yaw_mean"])


def test_tilt_yaw_nees_splits_the_orientation_error_in_the_world_frame():
    """The orientation error is turned into the world frame before it is split: with the estimate yawed by 90°, the
    IMU's x axis points along world y, so a world-y (tilt) error is weighed by the IMU-x variance and a world-z error
    by the IMU-z variance; a yaw error leaves the tilt NEES at zero and vice versa."""
    from pipeline.oracle_truth import tilt_yaw_nees

    R_est = so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    P = np.diag([0.01 ** 2, 0.04 ** 2, 0.02 ** 2])                      # IMU-frame x, y, z variances, rad²
    tilt_err = so3_exp(np.array([0.0, 0.03, 0.0])) @ R_est               # 0.03 rad about world y
    tilt, yaw = tilt_yaw_nees(R_est, P, tilt_err)
    assert tilt == pytest.approx((0.03 / 0.01) ** 2, rel=1e-6) and yaw == pytest.approx(0.0, abs=1e-12)
    yaw_err = so3_exp(np.array([0.0, 0.0, 0.05])) @ R_est                # 0.05 rad about world z
    tilt, yaw = tilt_yaw_nees(R_est, P, yaw_err)
    assert yaw == pytest.approx((0.05 / 0.02) ** 2, rel=1e-6) and tilt == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(tilt_yaw_nees(R_est, np.zeros((3, 3)), yaw_err)[1])


def test_imu_without_true_acc_bias_subtracts_the_interpolated_bias_from_the_accelerometer_only():
    from pipeline.oracle_truth import imu_without_true_acc_bias

    t_true = np.array([0.0, 1.0, 2.0])
    truth = {"imu_stamp_ns": (t_true * 1e9).astype(np.int64),
             "bias_accel": np.array([[0.0, 0.1, -0.2], [0.2, 0.1, 0.0], [0.4, 0.1, 0.2]])}
    imu = np.zeros((3, 7))
    imu[:, 0] = [0.5, 1.0, 1.75]
    imu[:, 1:4] = 0.3
    imu[:, 4:7] = [0.0, 0.0, 9.8]
    out = imu_without_true_acc_bias(imu, truth)
    np.testing.assert_allclose(out[:, 4:7], [[-0.1, -0.1, 9.9], [-0.2, -0.1, 9.8], [-0.35, -0.1, 9.65]], atol=1e-12)
    np.testing.assert_array_equal(out[:, :4], imu[:, :4])
    assert imu[0, 4] == 0.0                                              # the input is not modified
