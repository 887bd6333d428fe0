"""A small simulated feature world for the MSCKF back end (no images).

A ground robot drives a smooth weaving path through a field of 3-D landmarks (a crop-row-like volume near
the ground). The IMU/camera head uses Rosario's extrinsics (IMU x up, y right, z forward; cam0 pitched
down ~6°; 0.119 m stereo baseline). From the known trajectory we synthesise:

* IMU samples (gyro, specific force) with white noise and bias random walks of given densities; each sample
  is the true signal at the middle of the interval that ends at its stamp (the filter holds a sample over
  that interval), plus noise;
* per image, :class:`~msckf.types.FeatureObservations` of the tracked landmarks: normalised cam0 / cam1
  coordinates with Gaussian noise, track ids, optional monocular or depth-map observations and outliers.

Everything is seeded; the same arguments give bit-identical worlds. The module also holds what the tests and the
benchmark do with a world: a filter configured with the simulator's noise (:func:`matched_config`), a filter
started from a perturbed truth (:func:`perturbed_filter`), the feed loop (:func:`iterate`) and the per-frame NEES
of one run (:func:`nees_run`, with :func:`anees_bounds`). Used by tests/test_msckf_*.py and
benchmarks/bench_msckf.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from msckf.config import MsckfConfig, load_config
from msckf.filter import MsckfFilter
from msckf.rotation import orthonormalize, so3_exp
from msckf.types import DepthSource, FeatureObservations

# Rosario v1 extrinsics (data/rosario_camchain.yaml): cam0/T_cam_imu and cam1/T_cn_cnm1.
_T_CAM0_IMU = np.array([
    [0.009471441780975032, 0.9984567420628084, 0.05472134884952806, 0.07585973485189132],
    [-0.9939081748565041, 0.0033909183804303744, 0.11015916496574298, -0.03342054396674176],
    [0.10980360533243941, -0.055431362078334365, 0.9924064350628417, -0.027188513339280743],
    [0.0, 0.0, 0.0, 1.0]])
_T_CAM1_CAM0 = np.array([
    [0.9999064, 0.00116937, 0.01362243, -0.118718331],
    [-0.00112614, 0.99999456, -0.00314845, 0.0000521848390],
    [-0.01362563, 0.00313285, 0.99990197, -0.000269290935],
    [0.0, 0.0, 0.0, 1.0]])
FX = 351.06           # rectified focal length of the Rosario rig, px (used to express pixel noise)
WIDTH, HEIGHT = 672, 376
#: IMU noise densities the worlds are simulated with (and :func:`matched_config` gives the filter).
SIM_NOISE = dict(gyro_noise=0.002, acc_noise=0.02, gyro_bias_noise=1e-4, acc_bias_noise=1e-3)


def rosario_extrinsics() -> tuple[np.ndarray, np.ndarray]:
    """(T_cam0_imu, T_cam1_cam0) with exactly orthonormal rotations."""
    a, b = _T_CAM0_IMU.copy(), _T_CAM1_CAM0.copy()
    a[:3, :3] = orthonormalize(a[:3, :3])
    b[:3, :3] = orthonormalize(b[:3, :3])
    return a, b


@dataclass
class Trajectory:
    """Smooth ground-robot motion of the IMU frame in a z-up world; evaluate at arrays of times (s)."""

    speed: float = 1.0          # m/s forward
    weave_amp: float = 1.5      # m lateral
    weave_period: float = 12.0  # s
    bob_amp: float = 0.05       # m vertical
    roll_amp: float = 0.04      # rad
    pitch_amp: float = 0.03     # rad
    height: float = 1.0         # m
    start_still: float = 0.0    # s standing still before moving (smooth start)
    R_body_imu: np.ndarray = field(default=None)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        if self.R_body_imu is None:
            T_ci, _ = rosario_extrinsics()
            # body: x forward, y left, z up; cam0 looks forward, pitched down by 6 degrees
            R_b_c = Rotation.from_euler("y", np.deg2rad(6.0)).as_matrix() @ np.array(
                [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
            self.R_body_imu = R_b_c @ T_ci[:3, :3]

    def _s(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Smooth time warp: 0 before start_still, ramps up, then t − start_still − const (C² continuous)."""
        t = np.asarray(t, dtype=np.float64)
        if self.start_still <= 0:
            return t, np.ones_like(t), np.zeros_like(t)
        T = 2.0  # ramp duration, s
        u = np.clip((t - self.start_still) / T, 0.0, 1.0)
        # s'(t) = smoothstep(u) (C²: 6u^5 - 15u^4 + 10u^3), s(t) = ∫ s'
        sp = 6 * u**5 - 15 * u**4 + 10 * u**3
        s_ramp = T * (u**6 - 3 * u**5 + 2.5 * u**4)
        s = np.where(t <= self.start_still, 0.0,
                     np.where(u < 1.0, s_ramp, T * 0.5 + (t - self.start_still - T)))
        spp = np.where((u > 0) & (u < 1), (30 * u**4 - 60 * u**3 + 30 * u**2) / T, 0.0)
        return s, np.where(t <= self.start_still, 0.0, sp), spp

    def position(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p, v, a) of the IMU in world, each (N, 3) in m, m/s, m/s²."""
        s, sd, sdd = self._s(t)
        w, wz = 2 * np.pi / self.weave_period, 2 * np.pi / 3.1
        f = np.stack([self.speed * s, self.weave_amp * np.sin(w * s), self.height + self.bob_amp * np.sin(wz * s)],
                     axis=1)
        fd = np.stack([np.full_like(s, self.speed), self.weave_amp * w * np.cos(w * s),
                       self.bob_amp * wz * np.cos(wz * s)], axis=1)
        fdd = np.stack([np.zeros_like(s), -self.weave_amp * w * w * np.sin(w * s),
                        -self.bob_amp * wz * wz * np.sin(wz * s)], axis=1)
        v = fd * sd[:, None]
        a = fdd * (sd * sd)[:, None] + fd * sdd[:, None]
        return f, v, a

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """(N, 3, 3) IMU → world rotations."""
        s, _, _ = self._s(t)
        w = 2 * np.pi / self.weave_period
        yaw = np.arctan2(self.weave_amp * w * np.cos(w * s), self.speed)
        roll = self.roll_amp * np.sin(2 * np.pi * s / 2.3)
        pitch = self.pitch_amp * np.sin(2 * np.pi * s / 1.7 + 0.5)
        R_w_b = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1)).as_matrix()
        return R_w_b @ self.R_body_imu

    def angular_rate(self, t: np.ndarray, h: float = 1e-4) -> np.ndarray:
        """(N, 3) IMU-frame angular rate, rad/s (central difference on SO(3))."""
        t = np.asarray(t, dtype=np.float64)
        Ra, Rb = self.rotation(t - h), self.rotation(t + h)
        return Rotation.from_matrix(np.swapaxes(Ra, 1, 2) @ Rb).as_rotvec() / (2 * h)


@dataclass
class SimWorld:
    """A simulated run. Times in s; IMU in the IMU frame; truth of the IMU frame in the world frame."""

    imu_t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    frames: list[FeatureObservations]
    frame_t: np.ndarray
    R_w_i: np.ndarray        # (M, 3, 3) truth at frame times
    p_w: np.ndarray          # (M, 3)
    v_w: np.ndarray          # (M, 3)
    b_g: np.ndarray          # (M, 3) true gyro bias at frame times
    b_a: np.ndarray          # (M, 3)
    t0: float                # start time (state at t0 given below)
    R0: np.ndarray
    p0: np.ndarray
    v0: np.ndarray
    b_g0: np.ndarray
    b_a0: np.ndarray
    T_cam0_imu: np.ndarray
    T_cam1_cam0: np.ndarray
    landmarks: np.ndarray
    gravity: float = 9.81


def make_world(seed: int = 0, duration: float = 10.0, imu_rate: float = 150.0, cam_rate: float = 15.0,
               n_landmarks: int = 4000, max_features: int = 300, track_end_prob: float = 0.08,
               pixel_sigma: float = 1.0, gyro_noise: float = 0.002, acc_noise: float = 0.02,
               gyro_bias_noise: float = 1e-4, acc_bias_noise: float = 1e-3, gyro_bias0: np.ndarray | None = None,
               acc_bias0: np.ndarray | None = None, mono_fraction: float = 0.0, depth_mode: bool = False,
               depth_rel_sigma: float = 0.0, depth_disp_sigma_px: float = 0.0, outlier_fraction: float = 0.0,
               outlier_px: float = 30.0,
               trajectory: Trajectory | None = None, world_seed: int | None = None,
               imu_noise_free: bool = False) -> SimWorld:
    """Generate a world. ``world_seed`` (default ``seed``) fixes the landmarks and track policy; ``seed`` the
    sensor noise. Noise densities are continuous-time σ's (same units as MsckfConfig). With ``depth_mode`` every
    observation carries a depth (relative noise ``depth_rel_sigma`` and/or disparity noise ``depth_disp_sigma_px``
    at the rig's f·b) and its cam1 coordinate is the one implied by that depth (``DEPTH_MAP``)."""
    traj = trajectory or Trajectory()
    wrng = np.random.default_rng(seed if world_seed is None else world_seed)
    rng = np.random.default_rng(10_000 + seed)
    T_ci, T_10 = rosario_extrinsics()
    R_c_i, t_c_i = T_ci[:3, :3], T_ci[:3, 3]
    R_10, t_10 = T_10[:3, :3], T_10[:3, 3]
    g_w = np.array([0.0, 0.0, -9.81])

    # ---- IMU
    dt = 1.0 / imu_rate
    n_imu = int(round(duration * imu_rate))
    imu_t = np.arange(1, n_imu + 1) * dt
    mid = imu_t - 0.5 * dt
    R_mid = traj.rotation(mid)
    _, _, a_mid = traj.position(mid)
    w_true = traj.angular_rate(mid)
    f_true = np.einsum("nji,nj->ni", R_mid, a_mid - g_w)
    bg0 = np.zeros(3) if gyro_bias0 is None else np.asarray(gyro_bias0, float)
    ba0 = np.zeros(3) if acc_bias0 is None else np.asarray(acc_bias0, float)
    bg = bg0 + np.cumsum(rng.normal(0, gyro_bias_noise * np.sqrt(dt), (n_imu, 3)), axis=0)
    ba = ba0 + np.cumsum(rng.normal(0, acc_bias_noise * np.sqrt(dt), (n_imu, 3)), axis=0)
    ng = rng.normal(0, gyro_noise / np.sqrt(dt), (n_imu, 3))
    na = rng.normal(0, acc_noise / np.sqrt(dt), (n_imu, 3))
    if imu_noise_free:
        ng[:], na[:], bg[:], ba[:] = 0.0, 0.0, bg0, ba0
    gyro = w_true + bg + ng
    acc = f_true + ba + na

    # ---- landmarks: a field volume around the path
    x_max = traj.speed * duration + 30.0
    L = np.stack([wrng.uniform(-5.0, x_max, n_landmarks), wrng.uniform(-9.0, 9.0, n_landmarks),
                  np.abs(wrng.normal(0.0, 0.5, n_landmarks))], axis=1)

    # ---- frames (every imu_rate/cam_rate-th IMU stamp)
    step = int(round(imu_rate / cam_rate))
    fidx = np.arange(step - 1, n_imu, step)
    frame_t = imu_t[fidx]
    R_f = traj.rotation(frame_t)
    p_f, v_f, _ = traj.position(frame_t)
    sig = pixel_sigma / FX
    next_id = 0
    active: dict[int, int] = {}       # landmark -> track id
    length: dict[int, int] = {}
    frames = []
    for m, t in enumerate(frame_t):
        R_w_c = R_f[m] @ R_c_i.T
        p_c = p_f[m] + R_f[m] @ (-R_c_i.T @ t_c_i)
        P0 = (L - p_c) @ R_w_c                       # landmarks in cam0
        P1 = P0 @ R_10.T + t_10
        with np.errstate(divide="ignore", invalid="ignore"):
            x0 = P0[:, :2] / P0[:, 2:3]
            x1 = P1[:, :2] / P1[:, 2:3]
        u0 = x0 * FX + np.array([WIDTH / 2, HEIGHT / 2])
        u1 = x1 * FX + np.array([WIDTH / 2, HEIGHT / 2])
        vis = (P0[:, 2] > 0.5) & (P0[:, 2] < 25.0) & (P1[:, 2] > 0.5)
        vis &= np.all((u0 > 5) & (u0 < np.array([WIDTH - 5, HEIGHT - 5])), axis=1)
        vis &= np.all((u1 > 5) & (u1 < np.array([WIDTH - 5, HEIGHT - 5])), axis=1)
        # continue tracks (random ends emulate KLT losses)
        for lm in list(active):
            if not vis[lm] or wrng.random() < track_end_prob:
                del active[lm]
                del length[lm]
        free = max_features - len(active)
        cand = np.flatnonzero(vis)
        cand = cand[~np.isin(cand, np.fromiter(active.keys(), dtype=np.int64, count=len(active)))]
        if free > 0 and len(cand):
            pick = wrng.choice(cand, size=min(free, len(cand)), replace=False)
            for lm in np.sort(pick):
                active[int(lm)] = next_id
                length[int(lm)] = 0
                next_id += 1
        lms = np.array(sorted(active, key=lambda k: active[k]), dtype=np.int64)
        for lm in lms:
            length[int(lm)] += 1
        n = len(lms)
        c0 = x0[lms] + rng.normal(0, sig, (n, 2))
        c1 = x1[lms] + rng.normal(0, sig, (n, 2))
        src = np.full(n, DepthSource.STEREO_MATCH, dtype=np.uint8)
        depth = np.full(n, np.nan)
        if depth_mode:
            z = P0[lms, 2] * (1.0 + rng.normal(0, depth_rel_sigma, n)) if depth_rel_sigma > 0 else P0[lms, 2].copy()
            if depth_disp_sigma_px > 0:                  # stereo-like: Gaussian disparity noise, σ_z ∝ z²
                fb = FX * np.linalg.norm(t_10)
                z = fb / np.maximum(fb / z + rng.normal(0, depth_disp_sigma_px, n), 1e-3)
            pts = np.concatenate([c0, np.ones((n, 1))], axis=1) * z[:, None]
            q1 = pts @ R_10.T + t_10
            c1 = q1[:, :2] / q1[:, 2:3]
            src[:] = DepthSource.DEPTH_MAP
            depth = z
        if mono_fraction > 0:
            mono = wrng.random(n) < mono_fraction
            src[mono] = DepthSource.MONO
            c1[mono] = np.nan
            depth[mono] = np.nan
        if outlier_fraction > 0:
            bad = rng.random(n) < outlier_fraction
            c0[bad] += rng.normal(0, outlier_px / FX, (int(bad.sum()), 2))
        frames.append(FeatureObservations(
            stamp_s=float(t), ids=np.array([active[int(lm)] for lm in lms], dtype=np.int64),
            cam0_xy=c0, cam1_xy=c1, depth_m=depth, source=src,
            track_length=np.array([length[int(lm)] for lm in lms], dtype=np.int32)))

    R0 = traj.rotation(np.array([0.0]))[0]
    p0, v0, _ = traj.position(np.array([0.0]))
    return SimWorld(imu_t=imu_t, gyro=gyro, acc=acc, frames=frames, frame_t=frame_t, R_w_i=R_f, p_w=p_f, v_w=v_f,
                    b_g=bg[fidx], b_a=ba[fidx], t0=0.0, R0=R0, p0=p0[0], v0=v0[0], b_g0=bg0, b_a0=ba0,
                    T_cam0_imu=T_ci, T_cam1_cam0=T_10, landmarks=L)


def iterate(world: SimWorld, flt, stop_after: int | None = None):
    """Feed a world into an ``MsckfFilter`` (or anything with ``feed_imu`` / ``feed_features``) in time order:
    the IMU samples up to each image, then its features. Yields ``(frame_index, pose)``."""
    i = 0
    n_imu = len(world.imu_t)
    for m, obs in enumerate(world.frames):
        if stop_after is not None and m >= stop_after:
            return
        while i < n_imu and world.imu_t[i] <= obs.stamp_s:
            flt.feed_imu(world.imu_t[i], world.gyro[i], world.acc[i])
            i += 1
        yield m, flt.feed_features(obs)


def matched_config(**overrides) -> MsckfConfig:
    """Filter config whose noise equals the simulator's (:data:`SIM_NOISE`, 1 px white feature noise: the update's
    and the gate's pixel σ, not the 0.18 px gate calibrated on rendered KLT tracks), plus overrides."""
    args = dict(SIM_NOISE, feature_noise=1.0 / FX, gate_noise=1.0 / FX, gyro_bias_cov=1e-6, acc_bias_cov=1e-4,
                velocity_cov=1e-3)
    args.update(overrides)
    return load_config(args)


def perturbed_filter(world: SimWorld, cfg: MsckfConfig, P0_diag: np.ndarray, rng: np.random.Generator) -> MsckfFilter:
    """Filter whose initial state (IMU and extrinsics) is the truth minus an error drawn from ``P0_diag`` (21,)."""
    d = rng.normal(size=21) * np.sqrt(P0_diag)
    T = world.T_cam0_imu.copy()
    R_ci = so3_exp(d[15:18]) @ T[:3, :3]                       # R_c_i = Exp(−δθ_e) R̂_c_i
    p_ic = -T[:3, :3].T @ T[:3, 3] - d[18:21]
    T[:3, :3], T[:3, 3] = R_ci, -R_ci @ p_ic
    flt = MsckfFilter(cfg, T, world.T_cam1_cam0)
    flt.initialize(world.t0, world.R0 @ so3_exp(-d[0:3]), world.p0 - d[12:15], world.v0 - d[6:9],
                   world.b_g0 - d[3:6], world.b_a0 - d[9:12], 9.81, covariance=np.diag(P0_diag))
    return flt


def nees_run(world: SimWorld, flt: MsckfFilter) -> tuple[list[float], list[float]]:
    """Feed a world into a filter; per frame, the NEES of the 3-d position and of the 3-d orientation error.

    Position error ``p_true − p̂`` against the covariance block of p; orientation error
    ``Log(R̂ᵀ R_true)`` (the filter's local perturbation) against the block of θ.
    """
    nees_p: list[float] = []
    nees_t: list[float] = []
    for m, _ in iterate(world, flt):
        assert flt.state is not None, "nees_run: the filter must be initialised"
        e_p, e_t = flt.pose_nees(world.R_w_i[m], world.p_w[m])
        nees_p.append(e_p)
        nees_t.append(e_t)
    return nees_p, nees_t


def anees_bounds(n_runs: int) -> tuple[float, float]:
    """Two-sided 95 % bounds of the run-averaged NEES of a 3-d error over ``n_runs`` runs: χ²(3N)/N quantiles."""
    return chi2.ppf(0.025, 3 * n_runs) / n_runs, chi2.ppf(0.975, 3 * n_runs) / n_runs
