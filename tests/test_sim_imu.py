"""Simulator IMU: the readings are exact derivatives of the trajectory, stillness is true stillness, noise has the
configured statistics, and the output does not depend on how the stream is chunked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msckf.rotation import skew
from pipeline.calibration import rig_from_camchain
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.sim.imu import ImuSimulator
from pipeline.sim.mount import mount_transform
from pipeline.sim.presets import get_preset
from pipeline.sim.terrain import Terrain
from pipeline.sim.trajectory import RobotTrajectory


def _trajectory(preset: str, duration: float, seed: int = 3, **route) -> RobotTrajectory:
    cfg = get_preset(preset)
    cfg = dataclasses.replace(cfg, duration_s=duration, route=dataclasses.replace(cfg.route, **route))
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    terrain = Terrain(cfg.field, seed, (40.0, 45.0))
    return RobotTrajectory(cfg, terrain, mount_transform(rig, cfg.camera.tilt_deg, cfg.camera.imu_position_m), seed)


@pytest.fixture(scope="module")
def loop_traj() -> RobotTrajectory:
    # the loop route: across and along the rows, 90° corners, a stop, vibration on rough ground
    return _trajectory("rosario-like-02", 15.0, stop_every_s=6.0, stop_s=1.0)


def test_integrating_the_true_imu_reproduces_the_trajectory(loop_traj: RobotTrajectory) -> None:
    t0, t1, dt = 3.5, 13.5, 0.002
    n = int(round((t1 - t0) / dt))
    grid = t0 + np.arange(2 * n + 1) * (dt / 2)  # RK4 needs the half steps
    k = loop_traj.kinematics(grid)
    g = loop_traj.gravity
    R = k.R_FI[0].copy()
    v = k.v_I[0].copy()
    p = k.p_I[0].copy()

    def deriv(R_: np.ndarray, v_: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return R_ @ skew(k.gyro[j]), R_ @ k.specific_force[j] + g, v_

    for i in range(n):
        j = 2 * i
        k1 = deriv(R, v, j)
        k2 = deriv(R + 0.5 * dt * k1[0], v + 0.5 * dt * k1[1], j + 1)
        k3 = deriv(R + 0.5 * dt * k2[0], v + 0.5 * dt * k2[1], j + 1)
        k4 = deriv(R + dt * k3[0], v + dt * k3[1], j + 2)
        R = R + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v_new = v + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        p = p + dt / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        v = v_new
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
    travelled = np.linalg.norm(np.diff(k.p_I, axis=0), axis=1).sum()
    assert travelled > 3.0  # the robot really moved (and stopped) in this window
    assert np.linalg.norm(p - k.p_I[-1]) < 1e-3  # millimetres after 10 s
    assert np.linalg.norm(v - k.v_I[-1]) < 1e-4
    ang = Rotation.from_matrix(R.T @ k.R_FI[-1]).magnitude()
    assert ang < 1e-5


def test_kinematics_are_consistent_derivatives(loop_traj: RobotTrajectory) -> None:
    """Finite differences of positions and orientations match the analytic velocity and body rate."""
    t = np.linspace(4.0, 12.0, 400)
    h = 1e-5
    a, b = loop_traj.kinematics(t - h), loop_traj.kinematics(t + h)
    k = loop_traj.kinematics(t)
    np.testing.assert_allclose((b.p_I - a.p_I) / (2 * h), k.v_I, atol=1e-5)
    np.testing.assert_allclose((b.v_I - a.v_I) / (2 * h), k.a_I, atol=1e-4)
    dR = np.einsum("nji,njk->nik", a.R_FI, b.R_FI)  # R(t-h)^T R(t+h) = exp(2h [w]x)
    w_fd = Rotation.from_matrix(dR).as_rotvec() / (2 * h)
    np.testing.assert_allclose(w_fd, k.gyro, atol=1e-5)


def test_standing_still_is_exact_and_reads_gravity(loop_traj: RobotTrajectory) -> None:
    t = np.arange(0.0, loop_traj.still_until_s, 1 / 142)
    k = loop_traj.kinematics(t)
    assert np.all(k.gyro == 0.0)
    assert np.all(k.v_I == 0.0)
    np.testing.assert_allclose(k.specific_force, np.broadcast_to(k.specific_force[0], k.specific_force.shape),
                               rtol=0, atol=1e-12)
    assert np.linalg.norm(k.specific_force[0]) == pytest.approx(loop_traj.cfg.imu.gravity_mps2, abs=1e-9)
    # Rosario IMU axes: x ≈ up, z ≈ forward (pitched down 12°: negative forward component)
    f = k.specific_force[0]
    assert f[0] > 9.0 and f[2] < -1.0 and abs(f[1]) < 0.6


def test_ideal_imu_equals_the_true_kinematics_and_noise_has_the_configured_statistics() -> None:
    traj = _trajectory("tiny", 60.0, still_s=70.0)  # stands still for the whole minute
    cfg = traj.cfg.imu
    ideal = ImuSimulator(cfg.ideal(), traj, seed=5).next(500)
    k = traj.kinematics(ideal.t)
    np.testing.assert_array_equal(ideal.gyro, k.gyro)
    np.testing.assert_array_equal(ideal.accel, k.specific_force)
    sim = ImuSimulator(cfg, traj, seed=5)
    out = sim.next(8000)
    k = traj.kinematics(out.t)
    white_g = out.gyro - k.gyro - out.bias_gyro
    white_a = out.accel - k.specific_force - out.bias_accel
    rate = cfg.rate_hz
    assert white_g.std(axis=0) == pytest.approx(np.full(3, cfg.gyro_noise_density * np.sqrt(rate)), rel=0.05)
    assert white_a.std(axis=0) == pytest.approx(np.full(3, cfg.acc_noise_density * np.sqrt(rate)), rel=0.05)
    steps = np.diff(out.bias_gyro, axis=0)
    assert steps.std() == pytest.approx(cfg.gyro_random_walk / np.sqrt(rate), rel=0.05)


def test_imu_stream_does_not_depend_on_chunking() -> None:
    traj = _trajectory("tiny", 5.0)
    a = ImuSimulator(traj.cfg.imu, traj, seed=9)
    whole = a.next(700)
    b = ImuSimulator(traj.cfg.imu, traj, seed=9)
    parts = [b.next(n) for n in (1, 99, 300, 300)]
    # equal up to the last bit of vectorised matrix products (noise and biases are chunk-independent)
    np.testing.assert_allclose(np.concatenate([p.gyro for p in parts]), whole.gyro, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.concatenate([p.accel for p in parts]), whole.accel, rtol=0, atol=1e-13)
    other = ImuSimulator(traj.cfg.imu, traj, seed=10).next(700)
    assert not np.array_equal(other.gyro, whole.gyro)
