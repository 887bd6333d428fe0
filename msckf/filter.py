"""The MSCKF back end (S-MSCKF ``MsckfVio`` without ROS): IMU in, feature observations in, poses out.

Per image (msckf_vio ``featureCallback``): propagate with the buffered IMU samples up to the image time →
clone the cam0 pose → add the observations → update with the features whose track ended (lost) → prune two
clones when the window is full (updating with the features they saw) → output the pose → online reset if the
position σ exploded. Health is checked after every image; divergence raises
:class:`~msckf.errors.FilterDivergedError`.

Deterministic: no randomness in the back end; same inputs give bit-identical outputs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from msckf.augmentation import augment, augmentation_jacobian
from msckf.camera import check_transform
from msckf.config import MsckfConfig
from msckf.errors import FilterDivergedError, MsckfInputError
from msckf.init import StaticInit, static_initialize
from msckf.propagation import propagate_samples
from msckf.rotation import matrix_to_quat_xyzw, orthonormalize, skew, so3_log
from msckf.state import BA, BG, EXT_P, EXT_R, IMU_DIM, TH, VEL, CloneStore, FeatureStore, ImuState, initial_covariance
from msckf.triangulation import initial_guess, triangulate_batch, views_from_clones
from msckf.types import DepthSource, FeatureObservations, PoseEstimate
from msckf.update import (
    FeatureBatch,
    MeasurementSpec,
    bucket_by_length,
    chi2_threshold,
    downweight_features,
    ekf_update_information,
    find_redundant_clones,
    gating_chi2,
    inject_correction,
    inverse_depth_sigma,
    measurement_blocks,
    qr_update,
    scale_depth_rows,
    schur_information,
    whiten_depth_shared,
    whiten_track_drift,
)

__all__ = ["MsckfFilter", "FrameStats"]


#: fewest features seen in both of the last two images for the zero-velocity test to decide anything
ZUPT_MIN_FEATURES = 10
#: quantile of the zero-velocity pseudo-measurement's χ² gate (3 dof)
ZUPT_GATE_QUANTILE = 0.99


@dataclass
class FrameStats:
    """What the filter did with one image (for logs, replay and benchmarks). Times in seconds.

    ``over_budget``: the back end took longer than one image period (1 / ``config.health.frame_rate``), as
    msckf_vio warns. ``gate_gamma`` / ``gate_dof``: the χ² statistic γ and its degrees of freedom of every feature
    that was gated in this frame (one array per gated batch), for checking the noise calibration (γ/dof ≈ 1).
    ``gate_ids`` / ``gate_verdict``: aligned with ``gate_gamma``, the feature (track) ids and what the gate did with
    each: 0 rejected, 1 accepted with all of its observations, 2 accepted without its filled depths
    (``depth_fallback``).
    ``n_depth_fallback``: features rejected with their depth-map observations and accepted without them
    (``update.depth_fallback``); they are not counted in ``n_gated_out``. ``zupt``: a zero-velocity update was made
    (``update.zupt_max_flow``).
    """

    stamp_s: float = 0.0
    n_observations: int = 0
    n_new: int = 0
    tracking_rate: float = 0.0
    n_lost: int = 0
    n_lost_used: int = 0
    n_pruned_used: int = 0
    n_gated_out: int = 0
    n_depth_fallback: int = 0
    n_triangulation_failed: int = 0
    n_clones: int = 0
    n_map: int = 0
    online_reset: bool = False
    over_budget: bool = False
    zupt: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    gate_gamma: list[np.ndarray] = field(default_factory=list)
    gate_dof: list[np.ndarray] = field(default_factory=list)
    gate_ids: list[np.ndarray] = field(default_factory=list)
    gate_verdict: list[np.ndarray] = field(default_factory=list)

    @property
    def n_gated(self) -> int:
        """Features that went through the χ² gate in this frame."""
        return int(sum(np.size(g) for g in self.gate_gamma))

    def gate_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(γ, dof)``: (M,) χ² statistics and degrees of freedom of this frame's gated features with a finite γ
        and dof > 0 (γ ~ χ²(dof) when the stated residual covariance is right)."""
        gs, ds = [], []
        for g, dof in zip(self.gate_gamma, self.gate_dof):
            g = np.asarray(g, dtype=np.float64).reshape(-1)
            dof = np.broadcast_to(np.asarray(dof, dtype=np.float64), g.shape)
            ok = (dof > 0) & np.isfinite(g)
            gs.append(g[ok])
            ds.append(dof[ok])
        return (np.concatenate(gs), np.concatenate(ds)) if gs else (np.zeros(0), np.zeros(0))


class MsckfFilter:
    """S-MSCKF back end.

    Args:
        config: :class:`MsckfConfig`.
        T_cam0_imu: (4, 4) maps IMU-frame points into cam0 (Kalibr ``cam0/T_cam_imu``); its rotation and
            translation are the initial extrinsic estimate (the filter refines them).
        T_cam1_cam0: (4, 4) maps cam0 points into cam1 (Kalibr ``cam1/T_cn_cnm1``); fixed.

    Use :meth:`feed_imu` for every IMU sample and :meth:`feed_features` for every image, in time order.
    The filter initialises itself from the first ``config.init.init_imu_samples`` IMU samples (static start),
    or explicitly with :meth:`initialize`.
    """

    def __init__(self, config: MsckfConfig, T_cam0_imu: np.ndarray, T_cam1_cam0: np.ndarray) -> None:
        self.config = config
        T_ci = check_transform(T_cam0_imu, "T_cam0_imu")
        T_10 = check_transform(T_cam1_cam0, "T_cam1_cam0")
        self._R_c_i0 = orthonormalize(T_ci[:3, :3])
        self._p_i_c0 = -self._R_c_i0.T @ T_ci[:3, 3]
        self.R_c1_c0 = orthonormalize(T_10[:3, :3])
        self.t_c1_c0 = T_10[:3, 3].copy()
        self.noise = config.imu_noise
        self.tri_params = config.triangulation
        self.clones = CloneStore(config.window.max_cam_state_size + 2)
        self.features = FeatureStore(self.clones.capacity)
        self.state: ImuState | None = None
        self.P = np.zeros((0, 0))
        self.g_w = np.array([0.0, 0.0, -9.81])
        self.init_result: StaticInit | None = None
        self._imu_t: list[float] = []
        self._imu_w: list[np.ndarray] = []
        self._imu_a: list[np.ndarray] = []
        self._last_imu: tuple[float, np.ndarray, np.ndarray] | None = None
        self._last_imu_t = -np.inf
        self._last_frame_t = -np.inf
        self.n_online_resets = 0
        self.last_stats = FrameStats()
        #: the robot was seen moving (``update.zupt_only_at_start``: no zero-velocity update from then on)
        self.has_moved = False
        #: the extrinsics' prior covariance blocks while they are held (``update.extrinsics_after_motion``), else None
        self._extrinsic_prior: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------------------------------ input
    @property
    def initialized(self) -> bool:
        return self.state is not None

    def initialize(self, t_s: float, R_world_imu: np.ndarray, p_world: np.ndarray | None = None,
                   v_world: np.ndarray | None = None, gyro_bias: np.ndarray | None = None,
                   acc_bias: np.ndarray | None = None, gravity_norm: float = 9.81,
                   covariance: np.ndarray | None = None) -> None:
        """Set the initial state explicitly (instead of the static initialisation).

        Args:
            t_s: state time, s; IMU samples after it propagate the state, images before it are ignored.
            R_world_imu: (3, 3) IMU → world rotation (world z up). p_world, v_world: m, m/s (default 0).
            gyro_bias (rad/s), acc_bias (m/s²): default 0. gravity_norm: |g|, m/s².
            covariance: (21, 21) initial IMU error covariance; default: the configured S-MSCKF one (zero for
                θ and p).
        """
        z3 = np.zeros(3)
        R = np.asarray(R_world_imu, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise MsckfInputError("initialize: R_world_imu must be a 3x3 rotation matrix")
        self.state = ImuState(time=float(t_s), R_w_i=orthonormalize(R),
                              p=np.array(p_world if p_world is not None else z3, dtype=np.float64),
                              v=np.array(v_world if v_world is not None else self.config.init.initial_velocity,
                                         dtype=np.float64),
                              b_g=np.array(gyro_bias if gyro_bias is not None else z3, dtype=np.float64),
                              b_a=np.array(acc_bias if acc_bias is not None else z3, dtype=np.float64),
                              R_c_i=self._R_c_i0.copy(), p_i_c=self._p_i_c0.copy())
        self.g_w = np.array([0.0, 0.0, -float(gravity_norm)])
        if covariance is None:
            self.P = self._initial_cov()
        else:
            P = np.asarray(covariance, dtype=np.float64)
            if P.shape != (IMU_DIM, IMU_DIM):
                raise MsckfInputError(f"initialize: covariance must be 21x21, got {P.shape}")
            self.P = 0.5 * (P + P.T)
        if self.config.update.extrinsics_after_motion and not self.has_moved and self.config.update.zupt_max_flow > 0:
            # hold the camera–IMU extrinsics while the robot stands (unobservable there); restored at first motion
            self._extrinsic_prior = (self.P[EXT_R, EXT_R].copy(), self.P[EXT_P, EXT_P].copy())
            self._clear_extrinsic_blocks()
            for blk in (EXT_R, EXT_P):
                self.P[blk, blk] = 1e-14 * np.eye(3)
        self.clones.clear()
        self.features.clear()
        self._drop_imu_before(float(t_s))

    def feed_imu(self, t_s: float, gyro: np.ndarray, accel: np.ndarray) -> None:
        """Buffer one IMU sample.

        Args:
            t_s: stamp, s (non-decreasing). gyro: (3,) angular rate, rad/s, IMU frame. accel: (3,) specific
                force, m/s², IMU frame (reads +|g| upwards at rest).
        Raises:
            MsckfInputError: wrong shape, non-finite values or a stamp earlier than the previous one.
            NonStaticStartError: the static-initialisation window shows motion (a subclass of MsckfInputError).
                The oldest half of the window is dropped first: a caller that wants to wait for a still period
                can catch it and keep feeding; initialisation is retried once the window is full again.
        """
        t = float(t_s)
        w = np.asarray(gyro, dtype=np.float64).reshape(-1)
        a = np.asarray(accel, dtype=np.float64).reshape(-1)
        if w.shape != (3,) or a.shape != (3,):
            raise MsckfInputError(f"IMU sample at t={t:.6f} s: gyro and accel must have 3 values")
        if not (np.isfinite(t) and np.all(np.isfinite(w)) and np.all(np.isfinite(a))):
            raise MsckfInputError(f"IMU sample at t={t:.6f} s holds non-finite values")
        if t < self._last_imu_t:
            raise MsckfInputError(f"IMU stamps go backwards: {t:.6f} s after {self._last_imu_t:.6f} s")
        self._last_imu_t = t
        self._imu_t.append(t)
        self._imu_w.append(w)
        self._imu_a.append(a)
        if self.state is None and len(self._imu_t) >= self.config.init.init_imu_samples:
            self._static_init()

    def _static_init(self) -> None:
        init = self.config.init
        n = init.init_imu_samples
        try:
            res = static_initialize(np.asarray(self._imu_t[:n]), np.asarray(self._imu_w[:n]),
                                    np.asarray(self._imu_a[:n]), init)
        except MsckfInputError:
            # Slide the window by half, so a caller that catches the error and keeps feeding gets a new try.
            del self._imu_t[:n // 2], self._imu_w[:n // 2], self._imu_a[:n // 2]
            raise
        self.init_result = res
        # [port] S-MSCKF jumps the state time to the first image (assuming the robot is still at rest);
        # here the state is propagated from the end of the init window through every later sample.
        self.initialize(res.t_end, res.R_w_i, gyro_bias=res.gyro_bias, gravity_norm=res.gravity_norm,
                        covariance=self._static_init_cov(res))

    def _initial_cov(self) -> np.ndarray:
        return initial_covariance(self.config.init)

    def _static_init_cov(self, res: StaticInit) -> np.ndarray:
        """The initial covariance after a static initialisation: the configured one, with the gyro-bias variance
        the window measured, the velocity variance of a verified standstill and the roll/pitch error the unknown
        accelerometer bias leaves in the gravity direction (each switchable; ``InitOptions`` says why)."""
        init = self.config.init
        P = self._initial_cov()
        if init.static_bias_from_window:
            # the bias at the window's end differs from its mean over the window by a random walk: variance σ²·T/3
            walk = self.config.imu_noise.gyro_bias_noise ** 2 * res.duration_s / 3.0
            P[BG, BG] = np.diag(np.asarray(res.gyro_bias_var, dtype=np.float64) + walk)
        if init.static_velocity_cov > 0:
            P[VEL, VEL] = init.static_velocity_cov * np.eye(3)
        if init.static_tilt_from_acc_bias:
            # The window's mean specific force a = Rᵀ·g·ẑ + b_a fixes the gravity direction with the accelerometer
            # bias in it: the roll/pitch error (IMU frame) is δθ = [u]× b_a / g, u = the body-frame up direction.
            u = res.R_w_i.T @ np.array([0.0, 0.0, 1.0])
            J = skew(u) / res.gravity_norm
            cross = J @ P[BA, BA]
            P[TH, TH] = cross @ J.T
            P[TH, BA] = cross
            P[BA, TH] = cross.T
        return P

    def _drop_imu_before(self, t: float) -> None:
        i = 0
        while i < len(self._imu_t) and self._imu_t[i] < t:
            i += 1
        if i:
            self._last_imu = (self._imu_t[i - 1], self._imu_w[i - 1], self._imu_a[i - 1])
            del self._imu_t[:i], self._imu_w[:i], self._imu_a[:i]

    # ------------------------------------------------------------------------------------------ images
    def feed_features(self, obs: FeatureObservations) -> PoseEstimate | None:
        """Process the features of one image; returns the IMU pose at the image time (None before init).

        Raises:
            MsckfInputError: malformed observations or a stamp not after the previous image.
            FilterDivergedError: the state became non-finite, the covariance lost positive definiteness or the
                speed exceeded ``config.health.max_speed``.
        """
        if not isinstance(obs, FeatureObservations):
            raise MsckfInputError(f"feed_features expects FeatureObservations, got {type(obs).__name__}")
        stamp = float(obs.stamp_s)
        if not np.isfinite(stamp) or stamp <= self._last_frame_t:
            raise MsckfInputError(f"image stamps must increase: {stamp:.6f} s after {self._last_frame_t:.6f} s")
        self._last_frame_t = stamp
        ids = np.asarray(obs.ids, dtype=np.int64)
        cam0 = np.asarray(obs.cam0_xy, dtype=np.float64)
        if len(ids) and (not np.all(np.isfinite(cam0))):
            raise MsckfInputError(f"image at t={stamp:.6f} s: non-finite cam0 coordinates")
        if len(np.unique(ids)) != len(ids):
            raise MsckfInputError(f"image at t={stamp:.6f} s: duplicate feature ids")
        if not self.config.depth.depth_keep_mono and len(ids):
            keep = np.asarray(obs.source) != DepthSource.MONO
            if not keep.all():
                obs = obs.subset(keep)
                ids = ids[keep]
        if self.state is None or stamp < self.state.time:
            return None
        st = FrameStats(stamp_s=stamp, n_observations=len(ids))
        tm = st.timings
        t0 = time.perf_counter()

        self._propagate_to(stamp)
        t1 = time.perf_counter()
        tm["propagate"] = t1 - t0

        self.state.id += 1
        self.P = augment(self.state, self.P, self.clones)
        cur_slot = self.clones.order[-1]
        tracking_rate = self._add_observations(obs, cur_slot, st)
        t2 = time.perf_counter()
        tm["augment"] = t2 - t1

        self._zero_velocity_update(cur_slot, st)
        self._remove_lost_features(cur_slot, st)
        t3 = time.perf_counter()
        tm["lost_update"] = t3 - t2

        self._prune(tracking_rate, st)
        t4 = time.perf_counter()
        tm["prune"] = t4 - t3

        self._check_health(stamp)
        pose = self._pose(stamp)
        st.online_reset = self._online_reset()
        st.n_clones = len(self.clones)
        st.n_map = self.features.n_alive
        tm["total"] = time.perf_counter() - t0
        st.over_budget = tm["total"] > 1.0 / self.config.health.frame_rate
        self.last_stats = st
        return pose

    def _initialised(self) -> ImuState:
        """The IMU state of an initialised filter (the steps that call this run only after initialisation)."""
        if self.state is None:
            raise RuntimeError("the MSCKF is not initialised yet")
        return self.state

    def _propagate_to(self, stamp: float) -> None:
        st = self._initialised()
        i = 0
        while i < len(self._imu_t) and self._imu_t[i] <= stamp:
            i += 1
        if i:
            times = np.asarray(self._imu_t[:i])
            gy = np.asarray(self._imu_w[:i])
            ac = np.asarray(self._imu_a[:i])
            keep = times > st.time
            self.P = propagate_samples(st, self.P, times[keep], gy[keep], ac[keep], self.noise, self.g_w,
                                       self.config.propagation.observability_constrained)
            self._last_imu = (self._imu_t[i - 1], self._imu_w[i - 1], self._imu_a[i - 1])
            del self._imu_t[:i], self._imu_w[:i], self._imu_a[:i]
        if self.config.propagation.propagate_to_image_time and self._last_imu is not None and st.time < stamp:
            # Hold the latest sample over the rest of the interval so the clone sits exactly at the image time.
            _, w, a = self._last_imu
            self.P = propagate_samples(st, self.P, np.array([stamp]), w[None], a[None], self.noise, self.g_w,
                                       self.config.propagation.observability_constrained)

    def _add_observations(self, obs: FeatureObservations, slot: int, st: FrameStats) -> float:
        fs = self.features
        ids = np.asarray(obs.ids, dtype=np.int64)
        rows = fs.lookup(ids)
        new = rows < 0
        curr = fs.n_alive
        tracked = int(np.count_nonzero(~new))
        tracking_rate = tracked / curr if curr > 0 else 0.0
        rows[new] = fs.add(ids[new])
        src = np.asarray(obs.source, dtype=np.uint8).reshape(-1)
        cam1 = np.asarray(obs.cam1_xy, dtype=np.float64).copy()
        cam1[src == DepthSource.MONO] = np.nan
        depth = np.asarray(obs.depth_m, dtype=np.float64).copy()
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
        fs.obs[rows, slot, 0:2] = obs.cam0_xy
        fs.obs[rows, slot, 2:4] = cam1
        fs.depth[rows, slot] = depth
        if obs.depth_sigma_m is not None:
            sig = np.asarray(obs.depth_sigma_m, dtype=np.float64)
            floor = self.config.depth.depth_min_rel_sigma
            if floor > 0.0:
                sig = np.maximum(sig, floor * depth)           # NaN where either is NaN: no stated σ
            fs.depth_sigma[rows, slot] = np.where(np.isfinite(depth) & np.isfinite(sig) & (sig > 0), sig, np.nan)
        else:
            fs.depth_sigma[rows, slot] = np.nan
        measured = np.zeros(len(depth), dtype=bool) if obs.depth_measured is None \
            else np.asarray(obs.depth_measured, dtype=bool).reshape(-1)
        fs.depth_filled[rows, slot] = np.isfinite(depth) & ~measured
        fs.src[rows, slot] = src
        fs.has[rows, slot] = True
        st.n_new = int(np.count_nonzero(new))
        st.tracking_rate = tracking_rate
        return tracking_rate

    # ------------------------------------------------------------------------------------------ features
    def _order(self) -> np.ndarray:
        return np.asarray(self.clones.order, dtype=np.int64)

    @staticmethod
    def _compact(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row, the positions of True entries first (time order kept), padded to the row maximum."""
        n = int(mask.sum(axis=1).max()) if len(mask) else 0
        cols = np.argsort(~mask, axis=1, kind="stable")[:, :max(n, 1)]
        valid = np.take_along_axis(mask, cols, axis=1)
        return cols, valid

    def _motion_ok(self, rows: np.ndarray, cols: np.ndarray, valid: np.ndarray,
                   without_depth: bool = False) -> np.ndarray:
        """S-MSCKF ``checkMotion`` (vectorised) with the mono threshold for tracks without any cam1."""
        order = self._order()
        fs, cl = self.features, self.clones
        ar = np.arange(len(rows))
        n_obs = valid.sum(axis=1)
        first = order[cols[:, 0]]
        last = order[cols[ar, n_obs - 1]]
        o = fs.obs[rows, first]
        d = np.concatenate([o[:, :2], np.ones((len(rows), 1))], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d = np.einsum("kij,kj->ki", cl.R_w_c[first], d)
        tr = cl.p[last] - cl.p[first]
        orth = tr - np.sum(tr * d, axis=1, keepdims=True) * d
        slots = order[cols]
        rr = rows[:, None]
        has_cam1 = np.isfinite(fs.obs[rr, slots, 2]) & valid
        dep = self.config.depth
        if dep.depth_row:
            # With inverse-depth rows, a depth-map observation gives the track a usable depth only if its σ is
            # small: a filled depth with a 15 % σ does not make a short, low-parallax track observable.
            dm = fs.src[rr, slots] == DepthSource.DEPTH_MAP
            depth = fs.depth[rr, slots]
            rel = inverse_depth_sigma(depth, fs.depth_sigma[rr, slots], dep.depth_inv_sigma,
                                      dep.depth_rel_sigma) * depth
            has_cam1 = np.where(dm, valid & (rel <= dep.depth_motion_rel_sigma), has_cam1)
        if without_depth:
            has_cam1 &= ~self._fallback_drop(rr, slots)
        any_cam1 = np.any(has_cam1, axis=1)
        tri = self.tri_params
        thr = np.where(any_cam1, tri.feature_translation_threshold, tri.mono_translation_threshold)
        return np.linalg.norm(orth, axis=1) > thr

    def _triangulate(self, rows: np.ndarray, st: FrameStats, without_depth: bool = False) -> np.ndarray:
        """Initialise the positions of features (rows) from all their observations; returns ok (bool).

        ``without_depth``: depth-map observations with a filled depth count with their cam0 pixel only
        (``depth_fallback``).
        """
        if len(rows) == 0:
            return np.zeros(0, dtype=bool)
        fs, cl = self.features, self.clones
        order = self._order()
        mask = self._usable_observations(rows)
        seen = mask.any(axis=1)
        if not seen.all():  # nothing left to triangulate from (every observation dropped): not triangulated
            ok = np.zeros(len(rows), dtype=bool)
            if seen.any():
                ok[seen] = self._triangulate(rows[seen], st, without_depth)
            st.n_triangulation_failed += int(np.count_nonzero(~seen))
            return ok
        cols, valid = self._compact(mask)
        ok = self._motion_ok(rows, cols, valid, without_depth)
        idx = np.flatnonzero(ok)
        if len(idx):
            r_i = rows[idx]
            slots = order[cols[idx]]
            v_i = valid[idx]
            obs = fs.obs[r_i[:, None], slots]
            depth_inv = depth_w = None
            dep = self.config.depth
            if without_depth:
                dm = self._fallback_drop(r_i[:, None], slots)
                obs = obs.copy()
                obs[..., 2:4] = np.where(dm[..., None], np.nan, obs[..., 2:4])
            elif dep.depth_row:
                # Depth enters as a σ-weighted inverse-depth residual, not as a virtual right-camera pixel.
                dm = (fs.src[r_i[:, None], slots] == DepthSource.DEPTH_MAP) & v_i
                obs = obs.copy()
                obs[..., 2:4] = np.where(dm[..., None], np.nan, obs[..., 2:4])
                depth = np.where(dm, fs.depth[r_i[:, None], slots], np.nan)
                sig = inverse_depth_sigma(depth, fs.depth_sigma[r_i[:, None], slots], dep.depth_inv_sigma,
                                          dep.depth_rel_sigma)
                k_, n_ = depth.shape
                depth_inv = np.full((k_, 2 * n_), np.nan)
                depth_w = np.full((k_, 2 * n_), np.nan)
                with np.errstate(divide="ignore", invalid="ignore"):
                    depth_inv[:, 0::2] = 1.0 / depth
                    depth_w[:, 0::2] = self.config.update.feature_noise / (dep.depth_sigma_scale * sig)
            R, t, z, vv, anchor = views_from_clones(cl.R_w_c[slots], cl.p[slots], obs, v_i, self.R_c1_c0,
                                                    self.t_c1_c0)
            a_slot = slots[np.arange(len(idx)), anchor]
            a_depth = fs.depth[r_i, a_slot] if dep.depth_seed and not without_depth else None
            x0 = initial_guess(R, t, z, vv, 2 * anchor, a_depth)
            p_a, good, _ = triangulate_batch(R, t, z, vv, x0, self.tri_params, depth_inv, depth_w)
            p_w = np.einsum("kij,kj->ki", cl.R_w_c[a_slot], p_a) + cl.p[a_slot]
            gr = r_i[good]
            fs.pos[gr] = p_w[good]
            fs.initialized[gr] = True
            ok[idx[~good]] = False
        st.n_triangulation_failed += int(np.count_nonzero(~ok))
        return ok

    def _measurement_spec(self) -> MeasurementSpec:
        c = self.config
        return MeasurementSpec.from_options(self.R_c1_c0, self.t_c1_c0, self.g_w, c.update, c.depth, c.propagation)

    def _batch(self, rows: np.ndarray, clone_mask: np.ndarray, spec: MeasurementSpec,
               without_depth: bool = False) -> FeatureBatch:
        """Measurement blocks for features ``rows`` over the clones of ``clone_mask`` ((k, C), time order).

        ``without_depth``: the depth-map observations whose depth is filled (or not known to be measured:
        ``FeatureStore.depth_filled``) enter with their cam0 pixel only (no virtual cam1, no inverse-depth row),
        as if they were monocular.
        """
        return self._batches(rows, clone_mask, spec, without_depth)[0]

    def _batches(self, rows: np.ndarray, clone_mask: np.ndarray, spec: MeasurementSpec,
                 without_depth: bool = False) -> tuple[FeatureBatch, FeatureBatch]:
        """The blocks of :meth:`_batch` for the update and the same blocks as the χ² gate sees them: with
        ``update.gate_depth_scale`` s > 0 the gate's depth rows also carry one error shared by all readings of a
        feature, σ = s·Z (``whiten_depth_shared``); the update's depth rows carry ``depth.depth_shared_rel_sigma``'s
        shared relative error the same way; otherwise both are the same object."""
        fs, cl = self.features, self.clones
        order = self._order()
        cols, valid = self._compact(clone_mask)
        slots = order[cols]
        rr = rows[:, None]
        from_map = fs.src[rr, slots] == DepthSource.DEPTH_MAP
        use_depth_row = from_map if spec.depth_row else np.zeros(slots.shape, dtype=bool)
        obs, depth = fs.obs[rr, slots], fs.depth[rr, slots]
        if without_depth:
            drop = self._fallback_drop(rr, slots)
            obs = obs.copy()
            obs[..., 2:4] = np.where(drop[..., None], np.nan, obs[..., 2:4])
            depth = np.where(drop, np.nan, depth)
        depth_sigma = fs.depth_sigma[rr, slots]
        raw = measurement_blocks(spec, fs.pos[rows], cl.R_w_c[slots], cl.p[slots], cl.R_c_w_null[slots],
                                 cl.p_null[slots], obs, depth, use_depth_row, valid,
                                 cols, len(order), depth_sigma=depth_sigma)
        # the drift model whitens the pixel rows, the shared-error terms the depth rows: independent of each other;
        # ``own``: every depth row at its reading's own σ, as the χ² gate tests it
        own = whiten_track_drift(raw, cl.times[slots], valid, spec.feature_noise, self.config.update.track_drift_psd)
        # the update weighs a depth reading at depth_sigma_scale × its σ (as it weighs the pixels at the inflated
        # feature_noise); with 1 (default) it is the same batch
        k_sig = self.config.depth.depth_sigma_scale
        upd = scale_depth_rows(own, 1.0 / k_sig)
        track = np.full(slots.shape, np.sqrt(self.config.depth.depth_track_bias))   # 0 (default): no shared term
        s_upd = self.config.depth.depth_shared_rel_sigma
        s_gate = self.config.update.gate_depth_scale or s_upd      # the gate's shared term, else the update's
        if s_gate <= 0.0 or own.r.shape[2] < 5 or not own.rows[:, :, 4].any():
            b = whiten_depth_shared(upd, track)
            return b, (b if upd is own else whiten_depth_shared(own, track))
        with np.errstate(divide="ignore", invalid="ignore"):
            # σ of a shared relative error s in units of a reading's inverse-depth σ: (s / Z) / (k · σ_ρ)
            sig_rho = inverse_depth_sigma(depth, depth_sigma, spec.depth_inv_sigma, spec.depth_rel_sigma)
            ok = np.isfinite(sig_rho) & (sig_rho > 0) & (depth > 0)

            def with_shared(base: FeatureBatch, s: float, k: float) -> FeatureBatch:
                # a zero term adds nothing (whiten_depth_shared returns the batch when every loading is 0)
                return whiten_depth_shared(base, np.stack([track, np.where(ok, s / (depth * k * sig_rho), 0.0)],
                                                          axis=-1))

            b = with_shared(upd, s_upd, k_sig)
            return b, (b if upd is own and s_gate == s_upd else with_shared(own, s_gate, 1.0))

    def _update(self, rows: np.ndarray, clone_mask: np.ndarray, obs_dof: np.ndarray, st: FrameStats) -> int:
        """Gate and apply one EKF update with the given features; returns how many were used."""
        if len(rows) == 0:
            return 0
        c = self.config.update
        spec = self._measurement_spec()
        sigma = c.feature_noise
        n_cl = len(self.clones)
        if self.config.depth.depth_fills_only_unmeasured:
            usable = self._usable_observations(rows, clone_mask)
            dropped = clone_mask.sum(axis=1) - usable.sum(axis=1)
            # a feature left with fewer than two observations has nothing to constrain: not an update, not a rejection
            keep = usable.sum(axis=1) >= 2
            rows, obs_dof, clone_mask = rows[keep], (obs_dof - dropped)[keep], usable[keep]
            if len(rows) == 0:
                return 0
        n_obs = clone_mask.sum(axis=1)
        accepted: list[FeatureBatch] = []
        acc_rows_count: list[np.ndarray] = []
        for grp in bucket_by_length(n_obs):
            b, b_gate = self._batches(rows[grp], clone_mask[grp], spec)
            gamma = gating_chi2(self.P, b_gate, sigma, c.gate_noise or None)
            dof = b.n_rows - 3 if c.chi2_dof == "residual" else obs_dof[grp]
            ok = (gamma < chi2_threshold(c.chi2_quantile, dof)) & (b.n_rows > 3)
            st.gate_gamma.append(gamma)
            st.gate_dof.append(np.asarray(b.n_rows - 3))
            back = self._regate_without_depth(rows[grp], clone_mask[grp], obs_dof[grp], ok, spec, accepted,
                                              acc_rows_count, st) if c.depth_fallback else np.zeros(0, np.int64)
            verdict = ok.astype(np.int8)
            verdict[back] = 2
            st.gate_ids.append(self.features.ids[rows[grp]])   # fancy indexing: a copy
            st.gate_verdict.append(verdict)
            st.n_gated_out += int(np.count_nonzero(~ok)) - len(back)
            if np.any(ok):
                kept = b.subset(ok)
                if c.robust_k > 0:
                    kept = downweight_features(kept, gamma[ok] / np.maximum(kept.n_rows - 3, 1), c.robust_k)
                accepted.append(kept)
                acc_rows_count.append(b.n_rows[ok] - 3)
        if not accepted:
            return 0
        if c.max_update_rows > 0:
            counts = np.concatenate(acc_rows_count)
            before = np.cumsum(counts) - counts
            keep_all = before <= c.max_update_rows
            out, start = [], 0
            for b in accepted:
                k = len(b.pos)
                keep = keep_all[start:start + k]
                start += k
                if np.any(keep):
                    out.append(b.subset(keep))
            accepted = out
        used = sum(len(b.pos) for b in accepted)
        if c.update_method == "schur":
            Lam = np.zeros((6 * n_cl, 6 * n_cl))
            eta = np.zeros(6 * n_cl)
            for b in accepted:
                L_b, e_b, _ = schur_information(b, n_cl)
                Lam += L_b
                eta += e_b
            dx, P_new = ekf_update_information(self.P, Lam, eta, sigma)
        else:
            nmax = max(b.Hx.shape[1] for b in accepted)
            padded = [self._pad_batch(b, nmax, n_cl) for b in accepted]
            mixed = any(b.mix is not None for b in padded)
            pos, Hx, Hf, r, rows = (np.concatenate([getattr(b, f) for b in padded])
                                    for f in ("pos", "Hx", "Hf", "r", "rows"))
            merged = FeatureBatch(pos, Hx, Hf, r, rows,
                                  np.concatenate([b.mix_or_identity() for b in padded]) if mixed else None)
            dx, P_new = qr_update(self.P, merged, sigma, n_cl)
        self.P = P_new
        inject_correction(self._initialised(), self.clones, dx)
        return used

    def _usable_observations(self, rows: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """``mask`` ((k, C) bool, clone order; default: every observation of the features ``rows``) less, with
        ``depth.depth_fills_only_unmeasured``, the observations with a filled depth of the features that have a
        measured depth in the window."""
        fs = self.features
        order = self._order()
        has = fs.has[rows][:, order]
        if mask is None:
            mask = has
        if not self.config.depth.depth_fills_only_unmeasured:
            return mask
        from_map = fs.src[rows][:, order] == DepthSource.DEPTH_MAP
        filled = fs.depth_filled[rows][:, order]
        measured = has & from_map & ~filled & np.isfinite(fs.depth[rows][:, order])
        return mask & ~(has & from_map & filled & measured.any(axis=1, keepdims=True))

    def _fallback_drop(self, rr: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """The depth-map observations (features ``rr`` × clone ``slots``, broadcast) that ``depth_fallback`` drops:
        the filled ones (``FeatureStore.depth_filled``), or all of them with ``update.depth_fallback_measured``."""
        fs = self.features
        from_map = fs.src[rr, slots] == DepthSource.DEPTH_MAP
        if self.config.update.depth_fallback_measured:
            return from_map
        return from_map & fs.depth_filled[rr, slots]

    def _regate_without_depth(self, rows: np.ndarray, clone_mask: np.ndarray, obs_dof: np.ndarray, ok: np.ndarray,
                              spec: MeasurementSpec, accepted: list[FeatureBatch], acc_rows_count: list[np.ndarray],
                              st: FrameStats) -> np.ndarray:
        """Gate the rejected features that have filled depths again without them (``depth_fallback``).

        ``ok``: (k,) the first gate's verdict. Those that pass now are appended to ``accepted`` /
        ``acc_rows_count`` (depth-free blocks) and counted in ``st.n_depth_fallback``; returns their indices into
        ``rows`` (int64).
        """
        c = self.config.update
        order = self._order()
        cols, valid = self._compact(clone_mask)
        sl = order[cols]
        has_fill = np.any(self._fallback_drop(rows[:, None], sl) & valid, axis=1)
        retry = np.flatnonzero(~ok & has_fill)
        if len(retry) == 0:
            return retry
        # the position was triangulated with the rejected depth: triangulate it again from the pixels alone
        retry = retry[self._triangulate(rows[retry], FrameStats(), without_depth=True)]
        if len(retry) == 0:
            return retry
        b, b_gate = self._batches(rows[retry], clone_mask[retry], spec, without_depth=True)
        gamma = gating_chi2(self.P, b_gate, c.feature_noise, c.gate_noise or None)
        dof = b.n_rows - 3 if c.chi2_dof == "residual" else obs_dof[retry]
        ok2 = (gamma < chi2_threshold(c.chi2_quantile, dof)) & (b.n_rows > 3)
        if np.any(ok2):
            kept = b.subset(ok2)
            if c.robust_k > 0:
                kept = downweight_features(kept, gamma[ok2] / np.maximum(kept.n_rows - 3, 1), c.robust_k)
            accepted.append(kept)
            acc_rows_count.append(b.n_rows[ok2] - 3)
        st.n_depth_fallback += int(np.count_nonzero(ok2))
        return retry[ok2]

    @staticmethod
    def _pad_batch(b: FeatureBatch, n: int, dummy: int) -> FeatureBatch:
        k, m = b.pos.shape
        if m == n:
            return b
        pad = n - m
        mix = None
        if b.mix is not None:
            R = b.r.shape[2]
            mix = np.pad(b.mix, ((0, 0), (0, pad * R), (0, pad * R)))   # the padding rows come last
            tail = np.arange(m * R, n * R)
            mix[:, tail, tail] = 1.0
        return FeatureBatch(np.pad(b.pos, ((0, 0), (0, pad)), constant_values=dummy),
                            np.pad(b.Hx, ((0, 0), (0, pad), (0, 0), (0, 0))),
                            np.pad(b.Hf, ((0, 0), (0, pad), (0, 0), (0, 0))),
                            np.pad(b.r, ((0, 0), (0, pad), (0, 0))),
                            np.pad(b.rows, ((0, 0), (0, pad), (0, 0))), mix)

    def _remove_lost_features(self, cur_slot: int, st: FrameStats) -> None:
        fs = self.features
        alive = fs.alive_rows()
        lost = alive[~fs.has[alive, cur_slot]]
        st.n_lost = len(lost)
        if len(lost) == 0:
            return
        order = self._order()
        mask = fs.has[lost][:, order]
        n_obs = mask.sum(axis=1)
        use = self._positions_for_update(lost[n_obs >= 3], st)
        if len(use):
            m = fs.has[use][:, order]
            st.n_lost_used = self._update(use, m, m.sum(axis=1) - 1, st)
        fs.remove(lost)

    def _zero_velocity_update(self, cur_slot: int, st: FrameStats) -> None:
        """Zero-velocity update while the robot stands still (``update.zupt_max_flow``).

        Standing still: the median image motion of the features seen in this image and the one before is at most
        ``zupt_max_flow`` (normalised image coordinates; rotation moves the image, so a turn on the spot is never
        taken for a stop) over at least ``ZUPT_MIN_FEATURES`` features. The pseudo-measurement v_world = 0 with σ
        ``zupt_velocity_sigma`` (m/s) is χ²-gated (99 %, 3 dof) against the state, so a filter confident that it
        moves is not stopped by a still image of a far scene. Without it nothing constrains the state while a robot
        stands: no track is lost and the window does not prune until it is full. With ``update.zupt_only_at_start``
        the first image whose features moved (``has_moved``) ends the zero-velocity updates for the run: only the
        stand the static initialisation verified is taken for one (a per-image flow test cannot tell a robot creeping
        at a few cm/s from a standing one).
        """
        c = self.config.update
        if c.zupt_max_flow <= 0 or len(self.clones.order) < 2 or (c.zupt_only_at_start and self.has_moved):
            return
        prev = self.clones.order[-2]
        fs = self.features
        alive = fs.alive_rows()
        both = alive[fs.has[alive, cur_slot] & fs.has[alive, prev]]
        if len(both) < ZUPT_MIN_FEATURES:
            return
        flow = np.linalg.norm(fs.obs[both, cur_slot, :2] - fs.obs[both, prev, :2], axis=1)
        if np.median(flow) > c.zupt_max_flow:
            self.has_moved = True
            self._release_extrinsics()
            return
        state = self._initialised()
        v = state.v
        PHt = self.P[:, VEL]
        S = self.P[VEL, VEL] + c.zupt_velocity_sigma ** 2 * np.eye(3)
        if float(v @ np.linalg.solve(S, v)) > float(chi2_threshold(ZUPT_GATE_QUANTILE, np.array(3))):
            return
        K = np.linalg.solve(S, PHt.T).T
        P = self.P - K @ PHt.T - PHt @ K.T + K @ S @ K.T           # Joseph form for H = [0 … I_v … 0]
        self.P = 0.5 * (P + P.T)
        inject_correction(state, self.clones, K @ (-v))
        st.zupt = True

    def _release_extrinsics(self) -> None:
        """The extrinsics become observable (``update.extrinsics_after_motion``; a no-op when none are held): their
        error e, still unknown with its prior covariance Σ (nothing was learnt while they were held), enters the
        extrinsic block and every clone in the window through the clone's augmentation Jacobian
        (:func:`msckf.augmentation.augmentation_jacobian`, its extrinsic columns), i.e. P ← P + A Σ Aᵀ with the held
        blocks cleared first."""
        if self._extrinsic_prior is None:
            return
        state = self._initialised()
        sig_r, sig_p = self._extrinsic_prior
        self._clear_extrinsic_blocks()
        ext = slice(EXT_R.start, EXT_P.stop)
        A = np.zeros((self.P.shape[0], 6))
        A[ext] = np.eye(6)
        for k, slot in enumerate(self.clones.order):
            R_w_i = self.clones.R_w_c[slot] @ state.R_c_i                      # the IMU orientation of that clone
            A[IMU_DIM + 6 * k:IMU_DIM + 6 * k + 6] = augmentation_jacobian(replace(state, R_w_i=R_w_i))[:, ext]
        Sigma = np.zeros((6, 6))
        Sigma[0:3, 0:3], Sigma[3:6, 3:6] = sig_r, sig_p
        P = self.P + A @ Sigma @ A.T
        self.P = 0.5 * (P + P.T)
        self._extrinsic_prior = None

    def _clear_extrinsic_blocks(self) -> None:
        """Zero the covariance rows and columns of the camera–IMU extrinsics (``EXT_R``, ``EXT_P``)."""
        for blk in (EXT_R, EXT_P):
            self.P[blk, :] = 0.0
            self.P[:, blk] = 0.0

    def _positions_for_update(self, rows: np.ndarray, st: FrameStats) -> np.ndarray:
        """The features (rows) that enter an update, each with a position triangulated from its current
        observations: with ``update.retriangulate`` every one is triangulated again (a feature that fails is left
        out), otherwise (S-MSCKF) only those never triangulated."""
        fs = self.features
        need = rows if self.config.update.retriangulate else rows[~fs.initialized[rows]]
        if len(need):
            fs.initialized[need] = False
            self._triangulate(need, st)
        return rows[fs.initialized[rows]]

    def _prune(self, tracking_rate: float, st: FrameStats) -> None:
        window = self.config.window
        cl, fs = self.clones, self.features
        if len(cl) < window.max_cam_state_size:
            return
        rm = find_redundant_clones(cl, window, tracking_rate)
        order = self._order()
        rm_pos = cl.position_in_order(np.asarray(rm))
        alive = fs.alive_rows()
        inv = fs.has[alive][:, rm]
        cnt = inv.sum(axis=1)
        multi = alive[cnt >= 2]
        if len(multi):
            use = self._positions_for_update(multi, st)
            if len(use):
                m = np.zeros((len(use), len(order)), dtype=bool)
                m[:, rm_pos] = fs.has[use][:, rm]
                st.n_pruned_used = self._update(use, m, m.sum(axis=1), st)
        fs.has[:, rm] = False
        fs.obs[:, rm] = np.nan
        fs.depth[:, rm] = np.nan
        fs.depth_sigma[:, rm] = np.nan
        fs.depth_filled[:, rm] = False
        keep = np.ones(self.P.shape[0], dtype=bool)
        for p in rm_pos:
            keep[IMU_DIM + 6 * p: IMU_DIM + 6 * p + 6] = False
        self.P = self.P[np.ix_(keep, keep)]
        cl.remove(list(rm))

    # ------------------------------------------------------------------------------------------ output
    def _check_health(self, stamp: float) -> None:
        s = self._initialised()
        vals = (s.R_w_i, s.p, s.v, s.b_g, s.b_a, s.R_c_i, s.p_i_c)
        if not all(np.all(np.isfinite(x)) for x in vals):
            raise FilterDivergedError("non-finite IMU state", stamp)
        if not np.all(np.isfinite(self.P)):
            raise FilterDivergedError("non-finite covariance", stamp)
        speed = float(np.linalg.norm(s.v))
        max_speed = self.config.health.max_speed
        if speed > max_speed:
            raise FilterDivergedError(f"speed {speed:.1f} m/s exceeds max_speed {max_speed:g} m/s",
                                      stamp)
        d = np.diag(self.P)
        scale = max(1.0, float(d.max()))
        if d.min() < -1e-9 * scale:
            raise FilterDivergedError(f"negative variance {d.min():.3g} in the covariance", stamp)
        try:
            np.linalg.cholesky(self.P + np.eye(len(d)) * (1e-9 * scale))
        except np.linalg.LinAlgError:
            raise FilterDivergedError("covariance is not positive semi-definite", stamp) from None

    def _pose(self, stamp: float) -> PoseEstimate:
        s = self._initialised()
        return PoseEstimate(stamp_s=stamp, p_world=s.p.copy(), q_world_imu_xyzw=matrix_to_quat_xyzw(s.R_w_i),
                            v_world=s.v.copy(), gyro_bias=s.b_g.copy(), acc_bias=s.b_a.copy(),
                            cov_diag=np.diag(self.P)[:IMU_DIM].copy())

    def pose_nees(self, R_w_i_true: np.ndarray, p_w_true: np.ndarray) -> tuple[float, float]:
        """NEES of a true IMU pose against the current estimate and covariance: (position, orientation).

        ``R_w_i_true`` (3, 3) maps IMU-frame vectors into this filter's world frame, ``p_w_true`` (3,) is the IMU
        position in it (m). Position error ``p_true − p̂`` against the covariance block of p (m²); orientation error
        ``Log(R̂ᵀ R_true)`` (rad, the filter's local perturbation) against the block of θ. Each is χ²(3) for a
        consistent filter (mean 3). NaN for a block that is singular (the filter claims no uncertainty there, e.g.
        the zero position covariance right after an online reset): no NEES is defined then."""
        s = self._initialised()
        ep = np.asarray(p_w_true, dtype=np.float64) - s.p
        et = so3_log(s.R_w_i.T @ np.asarray(R_w_i_true, dtype=np.float64))
        return _nees(ep, self.P[12:15, 12:15]), _nees(et, self.P[0:3, 0:3])

    def _online_reset(self) -> bool:
        thr = self.config.health.position_std_threshold
        if thr <= 0:
            return False
        std = np.sqrt(np.maximum(np.diag(self.P)[12:15], 0.0))
        if np.all(std < thr):
            return False
        self.clones.clear()
        self.features.clear()
        self.P = self._initial_cov()
        self.n_online_resets += 1
        return True


def _nees(err: np.ndarray, cov: np.ndarray) -> float:
    """``errᵀ cov⁻¹ err``; NaN where ``cov`` is singular."""
    try:
        return float(err @ np.linalg.solve(cov, err))
    except np.linalg.LinAlgError:
        return float("nan")
