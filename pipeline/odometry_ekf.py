"""The ``odometry`` baseline: a planar wheel-odometry + gyro EKF (filterpy ``ExtendedKalmanFilter``).

State ``x = [x, y, yaw, v]`` of base_link in the odometry frame (m, m, rad, m/s). Every report shows this
dead-reckoning baseline next to the VIO variants.

* Prediction, from one wheel-odometry stamp to the next (≈10 Hz on Rosario): the yaw follows the integrated
  **gyro** yaw rate (IMU, ≈142 Hz; the component about the vertical), the position follows the heading at IMU
  resolution at constant speed ``v``::

      yaw' = yaw + Δψ,   x' = x + v·(cos(yaw)·a − sin(yaw)·b),   y' = y + v·(sin(yaw)·a + cos(yaw)·b),   v' = v

  with ``Δψ = ∫ω dt``, ``a = ∫cos(ψ(t) − ψ(t_k)) dt`` and ``b = ∫sin(ψ(t) − ψ(t_k)) dt`` over the interval
  (gyro held piecewise constant between samples; the sums are vectorised over the whole sequence, so the
  filter loop runs once per odometry message, not per IMU sample).
* Update: the wheel speed ``twist.linear.x`` as a measurement of ``v``.
* Without IMU data, the wheel odometry's own yaw rate (``twist.angular.z``) drives the yaw instead.
* The gyro's vertical axis: ``R_base_imu`` (IMU → base_link rotation) if given, else the direction of the mean
  accelerometer reading at the static start (gravity reaction = up; Rosario's IMU axes are x up, y right,
  z forward). The gyro bias about that axis is the mean over the static start (speed below
  ``static_speed_mps`` for at least ``min_static_s``), else 0.

Output: a :class:`eval.trajectory.Trajectory` at the odometry stamps, z = 0, yaw-only quaternions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.spatial.transform import Rotation

from eval.trajectory import Trajectory
from pipeline.errors import AgrivioError

__all__ = ["OdometryEkfConfig", "OdometryEkfResult", "run_odometry_ekf", "gyro_vertical", "integrate_odometry"]


@dataclass(frozen=True)
class OdometryEkfConfig:
    """Noise and start-up settings (defaults in brackets).

    gyro_noise [0.005 rad/s/√Hz]: gyro white-noise density → yaw process noise σ² = n²·Δt.
    gyro_bias_rw [1e-4 rad/s²/√Hz]: bias drift folded into the yaw noise as (rw·Δt)²·Δt.
    accel_noise [0.5 m/s²/√Hz]: speed random walk between odometry samples (σ² = n²·Δt).
    position_noise [0.02 m/√s]: extra planar noise (wheel slip, lateral drift) (σ² = n²·Δt).
    speed_noise [0.05 m/s]: std of the wheel-speed measurement.
    init_yaw_std [0.01 rad], init_pos_std [0.01 m], init_speed_std [0.1 m/s]: initial uncertainty.
    static_speed_mps [0.02] and min_static_s [1.0]: what counts as the static start for the gyro bias and axis.
    estimate_bias [True]: subtract the static-start gyro bias.
    """

    gyro_noise: float = 0.005
    gyro_bias_rw: float = 1e-4
    accel_noise: float = 0.5
    position_noise: float = 0.02
    speed_noise: float = 0.05
    init_yaw_std: float = 0.01
    init_pos_std: float = 0.01
    init_speed_std: float = 0.1
    static_speed_mps: float = 0.02
    min_static_s: float = 1.0
    estimate_bias: bool = True


@dataclass(frozen=True, eq=False)
class OdometryEkfResult:
    """The filtered trajectory and what the filter found.

    trajectory: base_link poses in the odometry frame. covariances: (N, 4, 4) state covariance after each update.
    gyro_bias: rad/s subtracted from the vertical rate. up_imu: (3,) unit vertical axis in IMU coordinates (or
    None without IMU). used_imu: whether the gyro drove the yaw.
    """

    trajectory: Trajectory
    covariances: np.ndarray
    gyro_bias: float
    up_imu: np.ndarray | None
    used_imu: bool


class _PlanarEkf(ExtendedKalmanFilter):
    """filterpy EKF whose ``predict_x`` applies the nonlinear planar motion (the increments are set per step)."""

    def __init__(self) -> None:
        super().__init__(dim_x=4, dim_z=1)
        self.step = (0.0, 0.0, 0.0)  # (Δψ, a, b) of the current interval

    def predict_x(self, u: object = 0) -> None:
        dpsi, a, b = self.step
        x, y, yaw, v = self.x[:, 0]
        c, s = np.cos(yaw), np.sin(yaw)
        self.x = np.array([[x + v * (c * a - s * b)], [y + v * (s * a + c * b)], [yaw + dpsi], [v]])


def _hx(x: np.ndarray) -> np.ndarray:
    return np.array([[x[3, 0]]])


def _hjac(x: np.ndarray) -> np.ndarray:
    return np.array([[0.0, 0.0, 0.0, 1.0]])


def _static_end(odom_t: np.ndarray, odom_v: np.ndarray, speed: float) -> float:
    """Time at which the robot first moves (first odometry speed above ``speed``), or the last stamp."""
    moving = np.flatnonzero(np.abs(odom_v) > speed)
    return float(odom_t[moving[0]]) if moving.size else float(odom_t[-1])


def gyro_vertical(imu: np.ndarray, R_base_imu: np.ndarray | None, static_until_s: float,
                  min_static_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The gyro rate about the vertical (rad/s) for every IMU sample, and the IMU-frame up axis used.

    Args:
        imu: (M, 7) ``[t_s, gx, gy, gz, ax, ay, az]`` (s, rad/s, m/s², gravity included).
        R_base_imu: (3, 3) rotation IMU → base_link (base z up), or None to use gravity at the static start.
        static_until_s: end of the static start (s).
        min_static_s: the static start must last this long to define the up axis from gravity.
    """
    if R_base_imu is not None:
        up = np.asarray(R_base_imu, dtype=np.float64).reshape(3, 3)[2, :]  # base z expressed in IMU coordinates
    else:
        static = imu[:, 0] <= static_until_s
        if not static.any() or imu[static, 0][-1] - imu[0, 0] < min_static_s:
            static = imu[:, 0] <= imu[0, 0] + min_static_s  # fall back to the first second, moving or not
        acc = imu[static, 4:7].mean(axis=0)
        if np.linalg.norm(acc) < 1.0:
            raise AgrivioError("odometry EKF: the accelerometer shows no gravity at the start (|a| < 1 m/s²); "
                               "pass R_base_imu")
        up = acc
    up = up / np.linalg.norm(up)
    return imu[:, 1:4] @ up, up


def _yaw_increments(t_grid_src: np.ndarray, rate: np.ndarray, stamps: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per odometry interval k → k+1: (Δψ_k, a_k, b_k) from a piecewise-constant rate (held from each sample).

    ``t_grid_src`` (M,) sample times of ``rate`` (M,); ``stamps`` (N,) odometry times. Returns three (N−1,) arrays.
    """
    grid = np.union1d(t_grid_src, stamps)
    grid = grid[(grid >= stamps[0]) & (grid <= stamps[-1])]
    idx = np.searchsorted(t_grid_src, grid[:-1], side="right") - 1
    w = np.where(idx >= 0, rate[np.clip(idx, 0, None)], rate[0])  # before the first sample: hold the first
    dt = np.diff(grid)
    psi = np.concatenate([[0.0], np.cumsum(w * dt)])  # ψ at grid points (relative to stamps[0])
    seg = np.searchsorted(stamps, grid[:-1], side="right") - 1  # interval of each grid segment
    psi_start = np.interp(stamps, grid, psi)
    rel_mid = 0.5 * (psi[:-1] + psi[1:]) - psi_start[seg]
    n = stamps.size - 1
    a = np.bincount(seg, weights=np.cos(rel_mid) * dt, minlength=n)[:n]
    b = np.bincount(seg, weights=np.sin(rel_mid) * dt, minlength=n)[:n]
    return np.diff(psi_start), a, b


def run_odometry_ekf(odom: np.ndarray, imu: np.ndarray | None = None, R_base_imu: np.ndarray | None = None,
                     config: OdometryEkfConfig | None = None) -> OdometryEkfResult:
    """Filter wheel odometry (+ gyro) into a planar base_link trajectory.

    Args:
        odom: (N, 6) ``[t_s, x, y, yaw, v, yaw_rate]`` (s, m, m, rad, m/s, rad/s) in time order, as
            ``RosarioSequence.odom_array()``. The first pose initialises the state.
        imu: (M, 7) ``[t_s, gx, gy, gz, ax, ay, az]`` or None (then the odometry yaw rate drives the yaw).
        R_base_imu: (3, 3) IMU → base_link rotation; None = vertical axis from gravity at the static start.
    """
    cfg = config or OdometryEkfConfig()
    odom = np.asarray(odom, dtype=np.float64)
    if odom.ndim != 2 or odom.shape[1] != 6:
        raise AgrivioError(f"odometry EKF: odometry must be (N, 6) [t, x, y, yaw, v, yaw_rate], got {odom.shape}")
    if odom.shape[0] < 2:
        raise AgrivioError(f"odometry EKF: need at least 2 odometry messages, got {odom.shape[0]}")
    if np.any(np.diff(odom[:, 0]) <= 0):
        raise AgrivioError("odometry EKF: odometry stamps must increase strictly")
    t = odom[:, 0]
    static_until = _static_end(t, odom[:, 4], cfg.static_speed_mps)
    up = None
    bias = 0.0
    used_imu = imu is not None and len(imu) >= 2
    if used_imu:
        imu = np.asarray(imu, dtype=np.float64)
        if imu.ndim != 2 or imu.shape[1] != 7:
            raise AgrivioError(f"odometry EKF: IMU must be (M, 7) [t, gyro xyz, accel xyz], got {imu.shape}")
        rate, up = gyro_vertical(imu, R_base_imu, static_until, cfg.min_static_s)
        static = imu[:, 0] <= static_until
        if cfg.estimate_bias and static.any() and imu[static, 0][-1] - imu[0, 0] >= cfg.min_static_s:
            bias = float(rate[static].mean())
        dpsi, a, b = _yaw_increments(imu[:, 0], rate - bias, t)
    else:
        dpsi, a, b = _yaw_increments(t, odom[:, 5], t)

    ekf = _PlanarEkf()
    ekf.x = np.array([[odom[0, 1]], [odom[0, 2]], [odom[0, 3]], [odom[0, 4]]])
    ekf.P = np.diag([cfg.init_pos_std ** 2, cfg.init_pos_std ** 2, cfg.init_yaw_std ** 2, cfg.init_speed_std ** 2])
    r_speed = np.array([[cfg.speed_noise ** 2]])
    n = t.size
    states = np.empty((n, 4))
    covs = np.empty((n, 4, 4))
    ekf.update(np.array([odom[0, 4]]), _hjac, _hx, R=r_speed)
    states[0], covs[0] = ekf.x[:, 0], ekf.P
    for k in range(n - 1):
        dt = t[k + 1] - t[k]
        yaw, v = ekf.x[2, 0], ekf.x[3, 0]
        c, s = np.cos(yaw), np.sin(yaw)
        ca, cb = c * a[k] - s * b[k], s * a[k] + c * b[k]
        ekf.F = np.array([[1.0, 0.0, -v * cb, ca], [0.0, 1.0, v * ca, cb], [0.0, 0.0, 1.0, 0.0],
                          [0.0, 0.0, 0.0, 1.0]])
        q_yaw = cfg.gyro_noise ** 2 * dt + (cfg.gyro_bias_rw * dt) ** 2 * dt
        q_pos = cfg.position_noise ** 2 * dt
        ekf.Q = np.diag([q_pos, q_pos, q_yaw, cfg.accel_noise ** 2 * dt])
        ekf.step = (dpsi[k], a[k], b[k])
        ekf.predict()
        ekf.update(np.array([odom[k + 1, 4]]), _hjac, _hx, R=r_speed)
        states[k + 1], covs[k + 1] = ekf.x[:, 0], ekf.P
    quats = Rotation.from_euler("z", states[:, 2:3]).as_quat().reshape(n, 4)
    positions = np.column_stack([states[:, 0], states[:, 1], np.zeros(n)])
    traj = Trajectory(t, positions, quats, has_orientation=True)
    return OdometryEkfResult(traj, covs, bias, up, bool(used_imu))


def integrate_odometry(odom: np.ndarray) -> Trajectory:
    """Plain Euler dead reckoning of the wheel speed and yaw rate (the unfiltered reference for tests/plots)."""
    odom = np.asarray(odom, dtype=np.float64)
    t = odom[:, 0]
    dt = np.diff(t)
    yaw = odom[0, 3] + np.concatenate([[0.0], np.cumsum(odom[:-1, 5] * dt)])
    step = odom[:-1, 4] * dt
    x = odom[0, 1] + np.concatenate([[0.0], np.cumsum(step * np.cos(yaw[:-1]))])
    y = odom[0, 2] + np.concatenate([[0.0], np.cumsum(step * np.sin(yaw[:-1]))])
    quats = Rotation.from_euler("z", yaw[:, None]).as_quat().reshape(-1, 4)
    return Trajectory(t, np.column_stack([x, y, np.zeros(t.size)]), quats, has_orientation=True)
