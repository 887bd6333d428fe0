"""GPS-RTK and wheel odometry from the true trajectory, and the geodesy between ENU and WGS84.

* ENU ↔ field frame: ``p_E = R_EF (p_F − p_F0)``, with ``R_EF`` rotating the field's +y axis to azimuth
  ``field.azimuth_deg`` (from north towards east) and ``p_F0`` the true antenna position at the first GPS fix.
* ENU ↔ geodetic: exact WGS84 (ENU → ECEF → latitude/longitude/ellipsoidal height) around the Zavalla origin.
* GPS: antenna = base_link ∘ lever arm; error = white + first-order Gauss-Markov per axis (vertical larger);
  ``/gps/fix`` altitude is ellipsoidal (MSL + geoid separation), like the bags; velocity east/north with noise.
* Odometry: measured speed = true forward speed × (scale − turn slip · |yaw rate|) + slip noise; measured yaw
  rate = true + bias + noise; integrated with Euler steps at the odometry rate in an ``odom`` frame that starts at
  (0, 0, 0), like the authors' converter (rosario.md §3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.sim.config import GpsConfig, OdomConfig
from pipeline.sim.imu import block_normals
from pipeline.sim.trajectory import RobotTrajectory

_A = 6378137.0
_F = 1 / 298.257223563
_E2 = _F * (2 - _F)


def geodetic_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, h: np.ndarray) -> np.ndarray:
    """WGS84 geodetic (degrees, ellipsoidal metres) → ECEF (N, 3) metres."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = _A / np.sqrt(1 - _E2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1 - _E2) + h) * np.sin(lat)], -1)


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (N, 3) → (lat_deg, lon_deg, ellipsoidal height m), iterative (converges to < 1e-9 m here)."""
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - _E2))
    h = np.zeros_like(p)
    for _ in range(8):
        n = _A / np.sqrt(1 - _E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - _E2 * n / (n + h)))
    return np.degrees(lat), np.degrees(lon), h


def _enu_basis(lat_deg: float, lon_deg: float) -> np.ndarray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    e = np.array([-np.sin(lon), np.cos(lon), 0.0])
    n = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    u = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    return np.stack([e, n, u])  # rows: ECEF components of E, N, U


def enu_to_geodetic(enu: np.ndarray, lat0: float, lon0: float, h0: float) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray]:
    """Local ENU (N, 3) metres around (lat0, lon0, h0) → (lat_deg, lon_deg, ellipsoidal height m)."""
    ecef = geodetic_to_ecef(np.array(lat0), np.array(lon0), np.array(h0)) + np.asarray(enu) @ _enu_basis(lat0, lon0)
    return ecef_to_geodetic(ecef)


def geodetic_to_enu(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, lat0: float, lon0: float,
                    h0: float) -> np.ndarray:
    """Inverse of :func:`enu_to_geodetic`: (N, 3) ENU metres."""
    d = geodetic_to_ecef(lat, lon, h) - geodetic_to_ecef(np.array(lat0), np.array(lon0), np.array(h0))
    return d @ _enu_basis(lat0, lon0).T


def rotation_enu_field(azimuth_deg: float) -> np.ndarray:
    """R_EF (3, 3): field-frame vectors to ENU (the field's +y axis points to ``azimuth_deg`` east of north)."""
    a = np.radians(azimuth_deg)
    return np.array([[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


@dataclass
class GpsSamples:
    """GPS output at stamps ``t`` (s since start).

    Attributes:
        true_enu: (N, 3) true antenna position, ENU (origin at the true antenna position of the first fix).
        meas_enu: (N, 3) measured position (true + RTK error), ENU.
        lat, lon, alt: (N,) what ``/gps/fix`` holds (degrees, ellipsoidal metres).
        vel_en: (N, 2) ``/gps/vel`` east/north, m/s.
    """

    t: np.ndarray
    true_enu: np.ndarray
    meas_enu: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    vel_en: np.ndarray


def simulate_gps(cfg: GpsConfig, traj: RobotTrajectory, antenna_B: np.ndarray, R_EF: np.ndarray,
                 t: np.ndarray, seed: int) -> tuple[GpsSamples, np.ndarray]:
    """All GPS samples at stamps ``t`` (the whole sequence: a few thousand rows).

    Returns:
        ``(samples, p_F0)``: the samples and the field-frame origin of the ENU frame (true antenna at ``t[0]``).
    """
    kin = traj.kinematics(t)
    ant_F = kin.p_B + np.einsum("nij,j->ni", kin.R_FB, antenna_B)
    omega_F = np.einsum("nij,nj->ni", kin.R_FB, kin.omega_B)
    vel_F = kin.v_B + np.cross(omega_F, np.einsum("nij,j->ni", kin.R_FB, antenna_B))
    p0 = ant_F[0].copy()
    true_enu = (ant_F - p0) @ R_EF.T
    vel_enu = vel_F @ R_EF.T
    n = len(t)
    white = block_normals(seed, 701, 0, n, 3) * cfg.white_m
    dt = 1.0 / cfg.rate_hz
    phi = np.exp(-dt / cfg.tau_s)
    drive = block_normals(seed, 702, 0, n, 3) * cfg.correlated_m * np.sqrt(1 - phi ** 2)
    corr = np.empty((n, 3))
    corr[0] = block_normals(seed, 703, 0, 1, 3)[0] * cfg.correlated_m
    for i in range(1, n):
        corr[i] = phi * corr[i - 1] + drive[i]
    err = white + corr
    err[:, 2] *= cfg.vertical_factor
    meas = true_enu + err
    lat, lon, h = enu_to_geodetic(meas, cfg.origin_lat_deg, cfg.origin_lon_deg,
                                  cfg.origin_alt_msl_m + cfg.geoid_separation_m)
    vel = vel_enu[:, :2] + block_normals(seed, 704, 0, n, 2) * cfg.vel_noise_mps
    return GpsSamples(t, true_enu, meas, lat, lon, h, vel), p0


@dataclass
class OdomSamples:
    """``/odom`` at stamps ``t``: x, y, yaw (odom frame), measured signed speed v and yaw rate (N,) each."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    yaw_rate: np.ndarray


def simulate_odometry(cfg: OdomConfig, traj: RobotTrajectory, t: np.ndarray, seed: int) -> OdomSamples:
    """Wheel odometry at stamps ``t`` (Euler integration with the actual stamp spacing)."""
    kin = traj.kinematics(t)
    fwd = kin.R_FB[:, :, 0]
    v_true = np.einsum("ni,ni->n", kin.v_B, fwd)
    w_true = np.einsum("nij,nj->ni", kin.R_FB, kin.omega_B)[:, 2]
    n = len(t)
    nz = block_normals(seed, 801, 0, n, 2)
    v = v_true * (cfg.speed_scale - cfg.turn_slip * np.abs(w_true)) + np.abs(v_true) * cfg.slip_std * nz[:, 0]
    w = w_true + (cfg.yaw_rate_bias + cfg.yaw_rate_noise * nz[:, 1]) * (np.abs(v_true) > 1e-3)
    x = np.zeros(n)
    y = np.zeros(n)
    yaw = np.zeros(n)
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        x[i] = x[i - 1] + v[i - 1] * np.cos(yaw[i - 1]) * dt
        y[i] = y[i - 1] + v[i - 1] * np.sin(yaw[i - 1]) * dt
        yaw[i] = yaw[i - 1] + w[i - 1] * dt
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    return OdomSamples(t, x, y, yaw, v, w)
