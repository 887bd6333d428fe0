"""GPS and odometry of the simulator: the antenna is the body trajectory composed with the lever arm, the
geodesy round-trips, RTK noise has the configured size, and wheel odometry dead-reckons the true path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.calibration import rig_from_camchain
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.sim.mount import mount_transform
from pipeline.sim.presets import get_preset
from pipeline.sim.sensors import enu_to_geodetic, geodetic_to_enu, rotation_enu_field, simulate_gps, simulate_odometry
from pipeline.sim.terrain import Terrain
from pipeline.sim.trajectory import RobotTrajectory


@pytest.fixture(scope="module")
def traj() -> RobotTrajectory:
    cfg = dataclasses.replace(get_preset("rosario-like-02"), duration_s=40.0)
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    return RobotTrajectory(cfg, Terrain(cfg.field, 1, (40.0, 45.0)),
                           mount_transform(rig, cfg.camera.tilt_deg, cfg.camera.imu_position_m), 1)


def test_antenna_is_body_pose_composed_with_lever_arm(traj: RobotTrajectory) -> None:
    cfg = traj.cfg
    t = 0.113 + np.arange(190) / 5.0
    R_EF = rotation_enu_field(cfg.field.azimuth_deg)
    lever_B = np.asarray(cfg.camera.gps_antenna_m)
    gps, p0 = simulate_gps(cfg.gps.ideal(), traj, lever_B, R_EF, t, seed=3)
    np.testing.assert_array_equal(gps.meas_enu, gps.true_enu)
    k = traj.kinematics(t)
    T_BI = traj.T_BI
    lever_I = T_BI[:3, :3].T @ (lever_B - T_BI[:3, 3])  # antenna in the IMU (body GT) frame
    ant_F = k.p_I + np.einsum("nij,j->ni", k.R_FI, lever_I)
    np.testing.assert_allclose(gps.true_enu, (ant_F - p0) @ R_EF.T, atol=1e-9)
    np.testing.assert_allclose(gps.true_enu[0], 0.0, atol=1e-12)
    # the fix decodes back to the same ENU point
    g = cfg.gps
    h0 = g.origin_alt_msl_m + g.geoid_separation_m
    back = geodetic_to_enu(gps.lat, gps.lon, gps.alt, g.origin_lat_deg, g.origin_lon_deg, h0)
    np.testing.assert_allclose(back, gps.true_enu, atol=1e-6)
    # velocity is the antenna's: compare with finite differences of its position
    v_fd = np.gradient(gps.true_enu[:, :2], t, axis=0)
    assert np.median(np.abs(v_fd - gps.vel_en)) < 0.03
    assert np.abs(gps.vel_en).max() > 0.3


def test_rtk_noise_has_centimetre_size(traj: RobotTrajectory) -> None:
    cfg = traj.cfg
    t = 0.113 + np.arange(190) / 5.0
    gps, _ = simulate_gps(cfg.gps, traj, np.asarray(cfg.camera.gps_antenna_m),
                          rotation_enu_field(cfg.field.azimuth_deg), t, seed=3)
    err = gps.meas_enu - gps.true_enu
    horiz = np.linalg.norm(err[:, :2], axis=1)
    assert 0.005 < np.sqrt(np.mean(horiz ** 2)) < 0.05
    other, _ = simulate_gps(cfg.gps, traj, np.asarray(cfg.camera.gps_antenna_m),
                            rotation_enu_field(cfg.field.azimuth_deg), t, seed=4)
    assert not np.allclose(other.meas_enu, gps.meas_enu)


def test_geodesy_round_trip_near_zavalla() -> None:
    enu = np.array([[0.0, 0.0, 0.0], [120.5, -73.25, 1.5], [-900.0, 400.0, -3.0]])
    lat, lon, h = enu_to_geodetic(enu, -33.0337693, -60.8846327, 74.5)
    assert lat[0] == pytest.approx(-33.0337693, abs=1e-12) and lon[0] == pytest.approx(-60.8846327, abs=1e-12)
    assert lat[1] < lat[0] and lon[1] > lon[0]  # south-east of the origin
    np.testing.assert_allclose(geodetic_to_enu(lat, lon, h, -33.0337693, -60.8846327, 74.5), enu, atol=1e-6)


def test_odometry_dead_reckons_the_true_path(traj: RobotTrajectory) -> None:
    cfg = traj.cfg
    t = 0.057 + np.arange(395) / 10.0
    ideal = simulate_odometry(cfg.odom.ideal(), traj, t, seed=1)
    real = simulate_odometry(cfg.odom, traj, t, seed=1)
    k = traj.kinematics(t)
    yaw0 = k.euler[0, 0]
    c, s = np.cos(-yaw0), np.sin(-yaw0)
    d = k.p_B[:, :2] - k.p_B[0, :2]
    true_xy = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], 1)  # in the odom frame
    err_ideal = np.linalg.norm(np.stack([ideal.x, ideal.y], 1) - true_xy, axis=1)
    err_real = np.linalg.norm(np.stack([real.x, real.y], 1) - true_xy, axis=1)
    travelled = np.linalg.norm(np.diff(true_xy, axis=0), axis=1).sum()
    assert travelled > 15.0
    assert err_ideal.max() < 0.02 * travelled  # Euler integration at 10 Hz of exact wheel data
    assert err_real[-1] > err_ideal[-1]  # slip and steering bias make it drift
    assert np.all(real.v[t < cfg.route.still_s - 0.1] == 0.0)  # standing still reads zero
