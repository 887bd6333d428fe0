"""The wheel-odometry + gyro EKF baseline tracks a known constant-turn trajectory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.errors import AgrivioError
from pipeline.odometry_ekf import OdometryEkfConfig, integrate_odometry, run_odometry_ekf

T0, T_MOVE, DURATION = 1000.0, 3.0, 63.0
V, W, YAW0 = 2.0, 0.1, 0.3
X0, Y0 = 5.0, -2.0


def _truth(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tm = np.clip(t - T0 - T_MOVE, 0.0, None)
    yaw = YAW0 + W * tm
    return X0 + V / W * (np.sin(yaw) - np.sin(YAW0)), Y0 - V / W * (np.cos(yaw) - np.cos(YAW0)), yaw


def _sensors(seed: int, gyro_bias: float = 0.003, wheel_yaw_bias: float = 0.02,
             R_base_imu: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """10 Hz odometry with noisy speed and a biased (slipping) yaw rate; 142 Hz IMU in Rosario axes (x up)."""
    rng = np.random.default_rng(seed)
    to = T0 + np.arange(0.0, DURATION, 0.1)
    x, y, yaw = _truth(to)
    moving = (to - T0) >= T_MOVE
    v = np.where(moving, V + rng.normal(0.0, 0.05, to.size), 0.0)
    wr = np.where(moving, W, 0.0) + wheel_yaw_bias + rng.normal(0.0, 0.01, to.size)
    odom = np.column_stack([to, x, y, yaw, v, wr])  # only the first pose and v, yaw_rate are used
    ti = T0 - 0.5 + np.arange(0.0, DURATION + 1.0, 1.0 / 142.0)
    w_true = np.where((ti - T0) >= T_MOVE, W, 0.0)
    if R_base_imu is None:  # Rosario IMU axes: x up, y right, z forward
        R_base_imu = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    omega_base = np.column_stack([np.zeros_like(ti), np.zeros_like(ti), w_true])
    f_base = np.tile([0.0, 0.0, 9.81], (ti.size, 1))
    gyro = omega_base @ R_base_imu + gyro_bias * R_base_imu[2] + rng.normal(0.0, 0.005, (ti.size, 3))
    acc = f_base @ R_base_imu + rng.normal(0.0, 0.05, (ti.size, 3))
    return odom, np.column_stack([ti, gyro, acc])


def _errors(traj, odom) -> np.ndarray:
    x, y, _ = _truth(odom[:, 0])
    return np.hypot(traj.positions[:, 0] - x, traj.positions[:, 1] - y)


@pytest.mark.parametrize("seed", [0, 1])
def test_tracks_constant_turn_with_gyro(seed: int) -> None:
    odom, imu = _sensors(seed)
    res = run_odometry_ekf(odom, imu)
    err = _errors(res.trajectory, odom)
    travelled = V * (DURATION - T_MOVE)  # 120 m, almost a full circle of radius 20 m
    assert res.used_imu and res.gyro_bias == pytest.approx(0.003, abs=5e-4)
    np.testing.assert_allclose(res.up_imu, [1.0, 0.0, 0.0], atol=1e-3)  # gravity along Rosario's IMU x
    assert err.max() < 0.01 * travelled  # < 1.2 m over 120 m
    yaw_true = _truth(odom[:, 0])[2]
    yaw = Rotation.from_quat(res.trajectory.quats_xyzw).as_euler("ZYX")[:, 0]
    assert np.max(np.abs(np.angle(np.exp(1j * (yaw - yaw_true))))) < 0.03
    assert np.all(res.trajectory.positions[:, 2] == 0.0) and res.trajectory.has_orientation
    # the wheel yaw rate is biased (slip): plain integration of the odometry drifts far more
    assert _errors(integrate_odometry(odom), odom).max() > 5.0 * err.max()


def test_explicit_extrinsics_and_no_imu() -> None:
    rot = Rotation.from_euler("xyz", [20, -35, 80], degrees=True).as_matrix()
    odom, imu = _sensors(2, R_base_imu=rot)
    res = run_odometry_ekf(odom, imu, R_base_imu=rot)
    assert _errors(res.trajectory, odom).max() < 1.2
    # without IMU the (biased) wheel yaw rate drives the yaw: it runs, and is as bad as the wheels
    no_imu = run_odometry_ekf(odom, None)
    assert not no_imu.used_imu and _errors(no_imu.trajectory, odom).max() > 5.0
    unbiased, _ = _sensors(3, wheel_yaw_bias=0.0)
    assert _errors(run_odometry_ekf(unbiased, None).trajectory, unbiased).max() < 1.5


def test_deterministic_and_bad_input() -> None:
    odom, imu = _sensors(4)
    a = run_odometry_ekf(odom, imu, config=OdometryEkfConfig())
    b = run_odometry_ekf(odom, imu)
    np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
    assert np.all(np.linalg.eigvalsh(a.covariances) > 0)
    with pytest.raises(AgrivioError, match=r"\(N, 6\)"):
        run_odometry_ekf(odom[:, :5], imu)
    with pytest.raises(AgrivioError, match="at least 2"):
        run_odometry_ekf(odom[:1], imu)
    with pytest.raises(AgrivioError, match="increase strictly"):
        run_odometry_ekf(odom[::-1], imu)
