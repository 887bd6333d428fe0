"""The depth oracle ladder: the same feature tracks, depths of known quality, the VIO's accuracy on each rung.

Why: a depth-aided VIO can only judge inpainting if it becomes *more* accurate when its depth becomes more
accurate. This module measures that on a simulated sequence, where the truth is known:

1. **Record the tracks once per seed.** The depth front end's tracking never looks at the depth map, so every
   depth variant with the same seed sees the same tracks. One pass of :class:`msckf.frontend.DepthFrontend`
   (driven with the raw SGBM map, i.e. exactly the ``depth-raw`` run) records, per frame, each feature's id,
   cam0 coordinate, track length and rectified pixel, and what every depth map of interest gives at that
   pixel (``sample_depth`` with the front end's own rejection rules: raw SGBM, each inpainted map).
2. **The truth of a tracked point.** The exact depth *map* is not the truth at a tracked corner (corners sit on
   depth edges: the map's value there is a foreground/background blend, measured +4.8–5.7 % too far). The
   truth is the depth of the tracked 3-D point: each track is triangulated from its cam0 observations with the
   simulator's *true* camera poses (``truth.npz: T_E_rectleft``), and its Z in each frame is that point's
   depth. Tracks whose true-pose triangulation is inconsistent (RMS reprojection > ``max_rms_px``: phantom
   corners at occlusion T-junctions have no 3-D point) or ill-conditioned (σ_Z/Z > ``max_rel_sigma``) fall back
   to the exact map's value at the nearest pixel; the fraction is reported.
3. **Rungs.** Each rung replaces only the depth values (and which features have one) and re-runs the back end
   (:class:`msckf.filter.MsckfFilter`) on identical tracks and IMU; ATE as the pipeline computes it.

Depths are handled as rectified-frame Z (what a depth map holds) and converted to cam0 Z and the cam1
coordinate with :func:`msckf.frontend_depth.depth_to_stereo`, as the front end does.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from eval.evaluate import EvalOptions, evaluate
from eval.gate_calibration import gate_statistics
from eval.trajectory import Trajectory, read_tum
from msckf.config import MsckfConfig
from msckf.errors import FilterDivergedError
from msckf.filter import MsckfFilter
from msckf.frontend import DepthFrontend
from msckf.frontend_depth import depth_to_stereo, nearest_pixel_values, sample_depth
from msckf.init import NonStaticStartError
from msckf.types import DepthSource, FeatureObservations
from msckf.update import inverse_depth_sigma
from pipeline.gate_power import GatePower
from pipeline.oracle_truth import AnchoredTruth, TrueImuPoses, tilt_yaw_nees

__all__ = ["TrackedFrame", "TrackLog", "record_tracks", "true_track_depths", "snap_to_true_points", "Rung",
           "EXACT_SIGMA_REL", "PAIR_CHECKS", "standard_rungs", "structure_rungs", "non_point_rungs", "run_backend",
           "NeesAccumulator", "evaluate_rung", "ate_against_truth"]


@dataclass
class TrackedFrame:
    """One frame of recorded tracks.

    Attributes:
        stamp_s: image time, s. index: stereo frame index.
        ids: (N,) int64 track ids. xy0: (N, 2) cam0 normalised coordinates. track_length: (N,) int32.
        rect_px: (N, 2) rectified left pixels of the features.
        z_rect: map name → (N,) rectified-frame Z in metres that the front end reads from that map (NaN where
            the read is rejected: hole, depth edge, out of range).
        sigma_rect: map name → (N,) σ of that Z in metres, where the map provides one (else absent).
    """

    stamp_s: float
    index: int
    ids: np.ndarray
    xy0: np.ndarray
    track_length: np.ndarray
    rect_px: np.ndarray
    z_rect: dict[str, np.ndarray] = field(default_factory=dict)
    sigma_rect: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class TrackLog:
    """The recorded tracks of one seed plus the IMU they were recorded with.

    Attributes:
        frames: the :class:`TrackedFrame` of every frame, in time order.
        imu: (M, 7) ``[t_s, gyro (rad/s), accel (m/s²)]`` IMU samples, IMU frame.
        seed: the front end's seed the tracks were recorded with.
        truth: filled by :func:`true_track_depths`: per frame (N,) true rectified Z, m (NaN outside range).
        truth_source: per frame (N,) uint8: 1 = true-pose triangulation, 2 = exact-map fallback, 0 = none.
        truth_sigma: per frame (N,) σ of ``truth`` in metres where it is a true-pose triangulation (the point's
            least-squares covariance at the tracking noise ``pixel_sigma`` of :func:`true_track_depths`, projected
            on that frame's optical axis; one error shared by every frame of the track), NaN elsewhere.
        truth_points: track id → (3,) world point of the accepted true-pose triangulations (m).
    """

    frames: list[TrackedFrame]
    imu: np.ndarray
    seed: int = 0
    truth: list[np.ndarray] = field(default_factory=list)
    truth_source: list[np.ndarray] = field(default_factory=list)
    truth_sigma: list[np.ndarray] = field(default_factory=list)
    truth_points: dict[int, np.ndarray] = field(default_factory=dict)


DepthProvider = Callable[[int], "tuple[np.ndarray, np.ndarray, np.ndarray | None]"]

#: σ_Z/Z the exact rungs state for the tracked point's true depth (a small floor: the depth is the truth).
EXACT_SIGMA_REL = 0.002

#: Checks between two rungs outside the ``chain``/``order`` chains (a rung belongs to one chain only): name →
#: (more accurate rung, less accurate rung); the first must not have the larger ATE (``ladder_verdict``).
PAIR_CHECKS: dict[str, tuple[str, str]] = {
    "coverage": ("exact-everywhere", "exact@raw-valid"),
    "perfect-fill": ("inpainted[exact]", "depth-raw"),
}


def record_tracks(rig: Any, config: MsckfConfig, seed: int, imu: np.ndarray,
                  frames: Iterable[tuple[int, float, np.ndarray]], raw_depth: DepthProvider,
                  other_maps: Mapping[str, DepthProvider] | None = None) -> TrackLog:
    """Run the depth front end over a sequence and record its tracks and the depth every map gives them.

    Args:
        rig: the :class:`msckf.camera.StereoRig`.
        config: the VIO configuration (its front-end part drives tracking and depth reading).
        seed: the front end's seed (RANSAC), as the run's seed.
        imu: (M, 7) IMU samples (fed to the front end for its rotation prediction, as in a run).
        frames: ``(index, stamp_s, left_grey)`` per stereo frame, in time order.
        raw_depth: index → ``(depth_m, valid, sigma_m or None)`` of the raw SGBM map (drives the front end).
        other_maps: name → provider of further maps read at the same pixels (e.g. inpainted, exact).
    Returns:
        The :class:`TrackLog`; ``z_rect["raw"]`` is what the ``depth-raw`` run attaches.
    """
    fe = DepthFrontend(config.frontend, rig, rig.T_left_imu, seed)
    c = config.frontend
    other_maps = dict(other_maps or {})
    out: list[TrackedFrame] = []
    k = 0
    for index, t_img, left in frames:
        while k < len(imu) and imu[k, 0] <= t_img:
            fe.add_imu(float(imu[k, 0]), imu[k, 1:4])
            k += 1
        d, v, s = raw_depth(index)
        obs = fe.process(float(t_img), left, d, v)
        rect = rig.rectify_left_normalised(obs.cam0_xy)
        tf = TrackedFrame(float(t_img), int(index), obs.ids.copy(), obs.cam0_xy.copy(),
                          obs.track_length.copy(), rect)
        for name, (dm, vm, sm) in [("raw", (d, v, s))] + [(n, p(index)) for n, p in other_maps.items()]:
            z, _ = sample_depth(dm, vm, rect, c.depth_sampling, c.depth_edge_window, c.depth_edge_threshold,
                                c.min_depth_m, c.max_depth_m, c.patch_size)
            tf.z_rect[name] = z
            if sm is not None:
                tf.sigma_rect[name] = nearest_pixel_values(sm, rect)
        out.append(tf)
    return TrackLog(out, imu, int(seed))


def true_track_depths(log: TrackLog, K_rect: np.ndarray, T_world_rect: Mapping[int, np.ndarray],
                      exact_map: DepthProvider | None = None, min_depth_m: float = 0.3, max_depth_m: float = 20.0,
                      max_rms_px: float = 1.0, max_rel_sigma: float = 0.02, pixel_sigma: float = 0.5
                      ) -> dict[str, float]:
    """Fill ``log.truth``: the true rectified Z of every tracked point in every frame (see the module doc).

    Args:
        K_rect: (3, 3) rectified left intrinsics.
        T_world_rect: frame index → (4, 4) true pose mapping rectified-left points into the world.
        exact_map: index → exact depth map (fallback for tracks that cannot be triangulated consistently).
        max_rms_px: largest RMS reprojection error (px) of a true-pose triangulation to accept it.
        max_rel_sigma: largest σ_Z/Z (at ``pixel_sigma`` px of tracking noise) to accept it.
    Returns:
        Statistics: fraction of observations with a triangulated truth, with a fallback, with none; median RMS;
        median σ_Z/Z of the triangulated truths (``median_sigma_rel``, at ``pixel_sigma``).
    """
    obs_of: dict[int, list[tuple[int, int]]] = {}
    for fi, fr in enumerate(log.frames):
        for j, tid in enumerate(fr.ids):
            obs_of.setdefault(int(tid), []).append((fi, j))
    Kinv = np.linalg.inv(K_rect)
    truth = [np.full(len(fr.ids), np.nan) for fr in log.frames]
    sigma = [np.full(len(fr.ids), np.nan) for fr in log.frames]
    source = [np.zeros(len(fr.ids), np.uint8) for fr in log.frames]
    rms_all: list[float] = []
    points: dict[int, np.ndarray] = {}
    for tid, lst in obs_of.items():
        if len(lst) < 2:
            continue
        fis = np.array([a for a, _ in lst])
        js = np.array([b for _, b in lst])
        px = np.stack([log.frames[a].rect_px[b] for a, b in lst])
        Ts = np.stack([T_world_rect[log.frames[a].index] for a in fis])
        p, rms, cov = _triangulate_true(px, Ts, Kinv, K_rect, pixel_sigma)
        if p is None:
            continue
        rms_all.append(rms)
        R = Ts[:, :3, :3]
        c = Ts[:, :3, 3]
        z = np.einsum("kij,ki->kj", R, p[None] - c)[:, 2]
        axis = R[:, :, 2]                                  # each view's optical axis in the world: Z = axis·(p - c)
        sz = np.sqrt(np.maximum(np.einsum("ki,ij,kj->k", axis, cov, axis), 0.0))
        if rms > max_rms_px or sz[-1] / z[-1] > max_rel_sigma:
            continue
        points[tid] = p
        for a, b, zz, ss in zip(fis, js, z, sz):
            truth[a][b] = zz
            sigma[a][b] = ss
            source[a][b] = 1
    if exact_map is not None:
        for fi, fr in enumerate(log.frames):
            miss = source[fi] == 0
            if np.any(miss):
                dm, vm, _ = exact_map(fr.index)
                val = nearest_pixel_values(np.where(vm, dm, np.nan), fr.rect_px[miss])
                truth[fi][miss] = val
                source[fi][miss] = np.where(np.isfinite(val), 2, 0)
    for fi in range(len(truth)):
        out = ~((truth[fi] >= min_depth_m) & (truth[fi] <= max_depth_m))
        truth[fi][out] = np.nan
        sigma[fi][out] = np.nan
        source[fi][out] = 0
    log.truth, log.truth_source, log.truth_sigma = truth, source, sigma
    log.truth_points = points
    src = np.concatenate(source) if source else np.zeros(0, np.uint8)
    rel = np.concatenate([s / t for s, t in zip(sigma, truth)]) if sigma else np.zeros(0)
    rel = rel[np.isfinite(rel)]
    n = max(len(src), 1)
    return {"triangulated": float(np.mean(src == 1)) if len(src) else 0.0,
            "exact_map_fallback": float(np.count_nonzero(src == 2) / n),
            "none": float(np.count_nonzero(src == 0) / n),
            "median_rms_px": float(np.median(rms_all)) if rms_all else float("nan"),
            "median_sigma_rel": float(np.median(rel)) if len(rel) else float("nan")}


def snap_to_true_points(log: TrackLog, K_rect: np.ndarray, R_left: np.ndarray,
                        T_world_rect: Mapping[int, np.ndarray]) -> int:
    """Replace the tracked pixels of every truth-triangulated track by the exact projection of its 3-D point.

    A diagnostic (``bench_depth_oracle.py --exact-pixels``): the tracks stay the same features over the same frames,
    but without KLT's pixel error, so the ladder separates what the *pixels* of the features a depth adds cost
    from what their *depths* cost. Tracks without an accepted true-pose point (not in ``truth_points``) keep their
    pixels; an accepted track is snapped in every frame, also where its depth is outside the truth's range. The
    depth reads recorded at the tracked pixels (``z_rect``) are left as they were. Call after
    :func:`true_track_depths`.

    Args:
        K_rect: (3, 3) rectified left intrinsics.
        R_left: (3, 3) rectification rotation ``p_rect = R_left p_cam0``.
        T_world_rect: frame index → (4, 4) true pose mapping rectified-left points into the world.
    Returns:
        The number of observations replaced.
    """
    n = 0
    point_ids = np.fromiter(log.truth_points, dtype=np.int64, count=len(log.truth_points))
    for fr in log.frames:
        sel = np.flatnonzero(np.isin(fr.ids, point_ids))
        if len(sel) == 0:
            continue
        T = T_world_rect[fr.index]
        pw = np.stack([log.truth_points[int(fr.ids[j])] for j in sel])
        p_rect = (pw - T[:3, 3]) @ T[:3, :3]                 # Rᵀ (p − c), row-wise
        uv = p_rect @ K_rect.T
        fr.rect_px = fr.rect_px.copy()
        fr.rect_px[sel] = uv[:, :2] / uv[:, 2:3]
        p0 = p_rect @ R_left                                 # R_leftᵀ p_rect, row-wise: the raw cam0 frame
        fr.xy0 = fr.xy0.copy()
        fr.xy0[sel] = p0[:, :2] / p0[:, 2:3]
        n += len(sel)
    return n


def _triangulate_true(px: np.ndarray, Ts: np.ndarray, Kinv: np.ndarray, K: np.ndarray, pixel_sigma: float
                      ) -> tuple[np.ndarray | None, float, np.ndarray]:
    """Least-squares point of rays from known poses, refined by Gauss–Newton on the pixel error.

    Returns (point (3,) world or None, RMS reprojection px, (3, 3) world covariance of the point in m² at
    ``pixel_sigma`` px of tracking noise per coordinate).
    """
    fail = (None, np.inf, np.full((3, 3), np.inf))
    rays = np.concatenate([px, np.ones((len(px), 1))], axis=1) @ Kinv.T
    R = Ts[:, :3, :3]
    c = Ts[:, :3, 3]
    d = np.einsum("kij,kj->ki", R, rays)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for di, ci in zip(d, c):
        M = np.eye(3) - np.outer(di, di)
        A += M
        b += M @ ci
    if np.linalg.cond(A) > 1e10:
        return fail
    p = np.linalg.solve(A, b)
    H = np.eye(3)
    for _ in range(5):
        pc = np.einsum("kji,kj->ki", R, p[None] - c)             # R^T (p - c)
        if np.any(pc[:, 2] <= 0.05):
            return fail
        proj = (pc @ K.T)
        uv = proj[:, :2] / proj[:, 2:3]
        r = (uv - px).reshape(-1)
        fx, fy = K[0, 0], K[1, 1]
        z = pc[:, 2]
        J_pc = np.zeros((len(px), 2, 3))
        J_pc[:, 0, 0] = fx / z
        J_pc[:, 0, 2] = -fx * pc[:, 0] / z ** 2
        J_pc[:, 1, 1] = fy / z
        J_pc[:, 1, 2] = -fy * pc[:, 1] / z ** 2
        J = (J_pc @ np.swapaxes(R, 1, 2)).reshape(-1, 3)
        H = J.T @ J
        try:
            step = np.linalg.solve(H, J.T @ r)
        except np.linalg.LinAlgError:
            return fail
        p = p - step
        if np.linalg.norm(step) < 1e-7:
            break
    pc = np.einsum("kji,kj->ki", R, p[None] - c)
    if np.any(pc[:, 2] <= 0.05):
        return fail
    proj = pc @ K.T
    uv = proj[:, :2] / proj[:, 2:3]
    rms = float(np.sqrt(np.mean(np.sum((uv - px) ** 2, axis=1))))
    try:
        cov = pixel_sigma ** 2 * np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return fail
    return p, rms, cov


@dataclass(frozen=True)
class Rung:
    """One rung of the ladder: how each frame's rectified Z (and σ) is chosen.

    ``depth(log, frame_index) -> (z_rect (N,), sigma_rect (N,) or None)``; NaN z = the feature has no depth.
    ``order``: the rung's depth-error rank within its chain (lower = more accurate), for the monotonicity check.
    ``measured``: ``(log, frame_index) -> (N,) bool`` True where the rung's depth is a direct (raw SGBM)
    measurement, as the pipeline tells the filter (``FeatureObservations.depth_measured``); None: unknown.
    ``keep_mono``: the features without depth enter the filter as monocular observations (``depth_keep_mono``)
    whatever the configuration says (the ``mono`` rung: a monocular VIO on the same tracks); False: as configured.
    """

    name: str
    depth: Callable[[TrackLog, int], tuple[np.ndarray, np.ndarray | None]]
    chain: str = ""
    order: int = 0
    measured: Callable[[TrackLog, int], np.ndarray] | None = None
    keep_mono: bool = False


def _raw_measured(log: TrackLog, i: int) -> np.ndarray:
    """(N,) True where frame ``i``'s raw SGBM map measured a depth (what the pipeline flags as measured)."""
    return np.isfinite(log.frames[i].z_rect["raw"])


def standard_rungs(inpaint_methods: Iterable[str] = (), noise_levels: Iterable[float] = (0.01, 0.03, 0.10),
                   noise_seed: int = 0, exact_sigma_rel: float = EXACT_SIGMA_REL,
                   track_noise_levels: Iterable[float] = ()) -> list[Rung]:
    """The ladder of issue 17: raw; exact at raw-valid pixels; exact everywhere; exact + noise; inpainted.

    Exact rungs carry σ_Z = ``exact_sigma_rel``·Z (a small floor, the depth is the truth); noisy rungs carry
    their stated σ; raw and inpainted rungs carry the σ their map provides (if any).

    "Exact" is the tracked point's true depth (:func:`true_track_depths`); features whose track is not a
    consistent 3-D point have no exact depth and stay monocular in the exact rungs. ``depth-raw`` is what the
    pipeline's run gets (SGBM depth at every raw-valid feature); ``depth-raw@tracked-point`` restricts it to the
    features of ``exact@raw-valid``, so that those two differ in depth values only.

    Chains checked for monotonicity (ATE must not grow as the depth error falls):
    ``noise``: exact-everywhere ≤ +1 % ≤ +3 % ≤ +10 % ≤ ``mono`` (no depth at any feature: a depth stated to the
    filter with its true σ may help little, but must not make the VIO worse than having none);
    ``value``: exact@raw-valid ≤ depth-raw@tracked-point;
    ``coverage`` (exact depth on more features): exact-everywhere ≤ exact@raw-valid (the exact rungs do not tell the
    filter which depths are fills: every depth counts as measured); ``perfect-fill``: ``inpainted[exact]`` (SGBM
    where it measured, the truth in its holes, flagged as fills as the pipeline flags every inpainted depth, so
    the filter's fill policy applies) ≤ depth-raw — a perfect inpainting must not make the VIO worse; with
    ``track_noise_levels``,
    ``track-noise``: exact + 1 %/track ≤ + 3 %/track ≤ … (one relative error per track, the same in every frame:
    the error structure of a map read at a tracked point, which the per-frame rungs do not have).
    """
    def raw(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        fr = log.frames[i]
        return fr.z_rect["raw"], fr.sigma_rect.get("raw")

    def raw_tracked(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        fr = log.frames[i]
        keep = log.truth_source[i] == 1
        s = fr.sigma_rect.get("raw")
        return np.where(keep, fr.z_rect["raw"], np.nan), None if s is None else np.where(keep, s, np.nan)

    def exact_raw(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray]:
        fr = log.frames[i]
        z = np.where(np.isfinite(fr.z_rect["raw"]) & (log.truth_source[i] == 1), log.truth[i], np.nan)
        return z, exact_sigma_rel * z

    def exact_all(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray]:
        z = np.where(log.truth_source[i] == 1, log.truth[i], np.nan)
        return z, exact_sigma_rel * z

    def perturbed(z: np.ndarray, level: float, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``z × (1 + level·e)`` (NaN where not positive) and its stated σ."""
        zn = z * (1.0 + level * e)
        return np.where(zn > 0, zn, np.nan), np.sqrt(exact_sigma_rel ** 2 + level ** 2) * z

    def noisy(level: float) -> Callable[[TrackLog, int], tuple[np.ndarray, np.ndarray | None]]:
        def f(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
            z, _ = exact_all(log, i)
            fr = log.frames[i]
            # one draw per (noise seed, level, track seed, frame): reproducible, independent across seeds
            rng = np.random.default_rng([noise_seed, int(round(level * 1e4)), log.seed, fr.index])
            return perturbed(z, level, rng.standard_normal(len(z)))
        return f

    def per_track(level: float) -> Callable[[TrackLog, int], tuple[np.ndarray, np.ndarray | None]]:
        # one relative error per track id, the same in every frame (as a stereo match's disparity bias or a
        # wrong fill is), stated to the filter with the same σ as the per-frame rungs
        tables: dict[int, np.ndarray] = {}

        def f(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
            z, _ = exact_all(log, i)
            if log.seed not in tables:
                top = max((int(fr.ids.max()) for fr in log.frames if len(fr.ids)), default=0)
                rng = np.random.default_rng([noise_seed, int(round(level * 1e4)), log.seed, 7])
                tables[log.seed] = rng.standard_normal(top + 1)
            return perturbed(z, level, tables[log.seed][log.frames[i].ids])
        return f

    def perfect_fill(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        # a perfect inpainting: SGBM where it measured, the tracked point's truth in its holes (fills, flagged so)
        fr = log.frames[i]
        zr, sr = fr.z_rect["raw"], fr.sigma_rect.get("raw")
        hole = ~np.isfinite(zr)
        zt, st = exact_all(log, i)
        return np.where(hole, zt, zr), None if sr is None else np.where(hole, st, sr)

    def no_depth(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        return np.full(len(log.frames[i].ids), np.nan), None

    def inpainted(name: str) -> Callable[[TrackLog, int], tuple[np.ndarray, np.ndarray | None]]:
        def f(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
            fr = log.frames[i]
            return fr.z_rect[name], fr.sigma_rect.get(name)
        return f

    noise_levels = tuple(noise_levels)
    rungs = [Rung("depth-raw", raw, measured=_raw_measured), Rung("depth-raw@tracked-point", raw_tracked, "value", 1),
             Rung("exact@raw-valid", exact_raw, "value", 0), Rung("exact-everywhere", exact_all, "noise", 0)]
    for k, lv in enumerate(noise_levels):
        rungs.append(Rung(f"exact+{lv * 100:g}%", noisy(lv), "noise", k + 1))
    # no depth at all: the σ → ∞ end of the noise chain (a depth stated with its true σ must not hurt)
    rungs.append(Rung("mono", no_depth, "noise", len(noise_levels) + 1, keep_mono=True))
    rungs.append(Rung("inpainted[exact]", perfect_fill, measured=_raw_measured))
    for k, lv in enumerate(track_noise_levels):
        rungs.append(Rung(f"exact+{lv * 100:g}%/track", per_track(lv), "track-noise", k + 1))
    for m in inpaint_methods:
        rungs.append(Rung(f"inpainted[{m}]", inpainted(m), measured=_raw_measured))
    return rungs


def structure_rungs(noise_seed: int = 0) -> list[Rung]:
    """Diagnostic rungs that keep SGBM's errors at tracked points but break their structure (issue 17).

    All act on the features of ``depth-raw@tracked-point`` (raw-valid, with a tracked-point truth t) and state the
    raw σ to the filter. With e = (z_raw − t) / σ_raw the σ-normalised error of each reading:

    ``raw-shuffled-in-frame``: each frame's e permuted among its features (keeps each frame's error distribution,
    breaks what ties an error to its track and its place in the image); ``raw-shuffled-in-run``: e drawn from the
    whole run's pool (also breaks what ties errors to a frame: turns, stops); ``raw-sign-flipped``: z_raw − t
    with a random sign per reading (keeps each error's size where it is, removes every shared sign);
    ``gauss@raw-sigma``: t + N(0, σ_raw) (SGBM's stated error model, exactly: no tails, no structure).
    They use the truth, so they diagnose; none is a method. Not part of any monotonicity chain. Like
    ``depth-raw@tracked-point`` (their reference), they do not say which readings are measured, so the filter's
    ``depth_fallback`` may re-gate a rejected feature without them (``depth-raw`` itself marks its readings
    measured: never re-gated).
    """
    def parts(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        fr = log.frames[i]
        z, s, t = fr.z_rect["raw"], fr.sigma_rect.get("raw"), log.truth[i]
        if s is None:
            raise ValueError("structure rungs need the raw map's σ (sigma_rect['raw'])")
        ok = np.isfinite(z) & np.isfinite(t) & (log.truth_source[i] == 1) & np.isfinite(s) & (s > 0)
        return ok, t, z, s

    def out(ok: np.ndarray, zz: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        zz = np.where(ok, zz, np.nan)
        return np.where(zz > 0, zz, np.nan), np.where(ok, s, np.nan)

    def rng(log: TrackLog, i: int, k: int) -> np.random.Generator:
        return np.random.default_rng([noise_seed, log.seed, log.frames[i].index, k])

    def shuffled_in_frame(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        ok, t, z, s = parts(log, i)
        e = (z - t) / s
        idx = np.flatnonzero(ok)
        e[idx] = e[rng(log, i, 1).permutation(idx)]
        return out(ok, t + e * s, s)

    pools: dict[int, np.ndarray] = {}

    def shuffled_in_run(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        if log.seed not in pools:
            es = []
            for j in range(len(log.frames)):
                okj, tj, zj, sj = parts(log, j)
                es.append(((zj - tj) / sj)[okj])
            pools[log.seed] = np.concatenate(es) if es else np.zeros(1)
        ok, t, z, s = parts(log, i)
        pool = pools[log.seed]
        return out(ok, t + pool[rng(log, i, 2).integers(0, len(pool), len(z))] * s, s)

    def sign_flipped(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        ok, t, z, s = parts(log, i)
        sign = np.where(rng(log, i, 3).random(len(z)) < 0.5, -1.0, 1.0)
        return out(ok, t + (z - t) * sign, s)

    def gauss(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        ok, t, z, s = parts(log, i)
        return out(ok, t + rng(log, i, 4).standard_normal(len(z)) * s, s)

    return [Rung("raw-shuffled-in-frame", shuffled_in_frame), Rung("raw-shuffled-in-run", shuffled_in_run),
            Rung("raw-sign-flipped", sign_flipped), Rung("gauss@raw-sigma", gauss)]


def non_point_rungs() -> list[Rung]:
    """Diagnostic rungs that split ``depth-raw`` by track class (issue 17): the tracks that are consistent 3-D
    points against the true poses (``truth_source`` 1) and the others (the exact map's value at the pixel is their
    only truth, ``truth_source`` 2: tracks that slide along an occlusion edge or a texture, RMS 1.4–3.9 px over
    their life, measured stop 46).

    ``raw+map@non-point``: as ``depth-raw`` (every raw-valid feature, the raw σ), but a non-point track's reading
    is replaced by the exact map's value at its pixel (keeping the raw σ): what the *SGBM values* on the non-point
    tracks cost, apart from the tracks themselves (a reading without any truth, ``truth_source`` 0, keeps SGBM's).
    ``raw@non-point``: the raw reading (and σ) on every track that is not a point track: ``depth-raw`` without
    ``depth-raw@tracked-point``'s features. Both say that their depths are
    measured where SGBM measured (as ``depth-raw``). Not part of any monotonicity chain.
    """
    def parts(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        fr = log.frames[i]
        return fr.z_rect["raw"], fr.sigma_rect.get("raw"), log.truth[i], log.truth_source[i]

    def map_at_non_point(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        z, s, t, src = parts(log, i)
        return np.where(np.isfinite(z) & (src == 2), t, z), s

    def non_point_only(log: TrackLog, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        z, s, _, src = parts(log, i)
        keep = src != 1
        return np.where(keep, z, np.nan), None if s is None else np.where(keep, s, np.nan)

    return [Rung("raw+map@non-point", map_at_non_point, measured=_raw_measured),
            Rung("raw@non-point", non_point_only, measured=_raw_measured)]


def run_backend(log: TrackLog, rung: Rung, config: MsckfConfig, rig: Any, use_sigma: bool = True,
                truth: TrueImuPoses | None = None) -> tuple[Trajectory, str | None, dict[str, Any]]:
    """Feed the recorded tracks with the rung's depths and the IMU to a fresh back end.

    Returns (IMU trajectory, divergence reason or None, per-run statistics: depth coverage, gate counts and, with
    ``truth``, the time-averaged NEES of the IMU position and orientation (χ²(3) each: 3 when the filter's
    covariance matches its error; ``pipeline.oracle_truth``)).
    """
    if rung.keep_mono and not config.depth.depth_keep_mono:
        config = replace(config, depth=replace(config.depth, depth_keep_mono=True))
    filt = MsckfFilter(config, rig.T_left_imu, rig.T_right_left)
    stamps: list[float] = []
    ps: list[np.ndarray] = []
    qs: list[np.ndarray] = []
    imu = log.imu
    k = 0
    n_depth = n_feat = n_gated = n_fallback = 0
    g_pairs: list[tuple[np.ndarray, np.ndarray]] = []
    nees = NeesAccumulator(truth)
    power = GatePower(fills_only_unmeasured=config.depth.depth_fills_only_unmeasured,
                      fallback_measured=config.update.depth_fallback_measured)
    fB = float(rig.fx * rig.baseline)
    failure = None
    try:
        for i, fr in enumerate(log.frames):
            while k < len(imu) and imu[k, 0] <= fr.stamp_s:
                try:
                    filt.feed_imu(imu[k, 0], imu[k, 1:4], imu[k, 4:7])
                except NonStaticStartError:
                    pass
                k += 1
            z_rect, sig_rect = rung.depth(log, i)
            z_rect = np.asarray(z_rect, dtype=np.float64)
            z0, xy1 = depth_to_stereo(fr.xy0, z_rect, rig.R_left, rig.T_right_left)
            has = np.isfinite(z0)
            src = np.where(has, DepthSource.DEPTH_MAP, DepthSource.MONO).astype(np.uint8)
            sig0 = None
            if use_sigma and sig_rect is not None:
                with np.errstate(divide="ignore", invalid="ignore"):
                    sig0 = np.where(has, np.asarray(sig_rect, dtype=np.float64) * z0 / z_rect, np.nan)
            measured = None if rung.measured is None else has & np.asarray(rung.measured(log, i), dtype=bool)
            obs = _observations(fr, xy1, z0, src, sig0, measured)
            if log.truth:
                with np.errstate(divide="ignore", invalid="ignore"):
                    dd = fB * np.abs(1.0 / z_rect - 1.0 / np.asarray(log.truth[i], dtype=np.float64))
                # the σ the gate tests the reading's inverse-depth row with, in disparity px
                sd = fB * inverse_depth_sigma(z0, sig0, config.depth.depth_inv_sigma, config.depth.depth_rel_sigma)
                power.add_readings(fr.stamp_s, fr.ids[has], dd[has], sd[has],
                                   np.zeros(int(has.sum()), bool) if measured is None else ~measured[has])
            window_start = _oldest_clone_time(filt, fr.stamp_s)
            pose = filt.feed_features(obs)
            for ids, verdict in zip(filt.last_stats.gate_ids, filt.last_stats.gate_verdict):
                power.add_verdicts(window_start, fr.stamp_s, ids, verdict)
            if i % 200 == 199:
                power.forget_before(window_start)
            n_depth += int(has.sum())
            n_feat += len(has)
            n_gated += filt.last_stats.n_gated_out
            n_fallback += filt.last_stats.n_depth_fallback
            g_pairs.append(filt.last_stats.gate_pairs())
            if pose is not None:
                stamps.append(pose.stamp_s)
                ps.append(pose.p_world)
                qs.append(pose.q_world_imu_xyzw)
                nees.add(filt, pose.stamp_s)
    except FilterDivergedError as exc:
        failure = exc.reason
    traj = Trajectory(np.asarray(stamps, dtype=np.float64), np.asarray(ps, dtype=np.float64).reshape(-1, 3),
                      np.asarray(qs, dtype=np.float64).reshape(-1, 4), has_orientation=True)
    return traj, failure, {"depth_fraction": n_depth / max(n_feat, 1), "gated_out": n_gated,
                           "depth_fallback": n_fallback, **frames_gate_statistics(g_pairs), **nees.stats(),
                           **power.stats()}


def _oldest_clone_time(filt: MsckfFilter, now_s: float) -> float:
    """Stamp (s) of the oldest clone in the filter's window before it takes the image at ``now_s`` (``now_s``
    when it has none yet): the first time an observation used by this image's updates can have."""
    order = filt.clones.order
    return float(np.min(filt.clones.times[np.asarray(order)])) if order else now_s


def frames_gate_statistics(pairs: Iterable[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """:func:`eval.gate_calibration.gate_statistics` of one run's gated features, from its frames'
    ``FrameStats.gate_pairs()`` (median and mean γ/dof, χ² noise scale, share above the 95 % quantile)."""
    pairs = list(pairs)
    g = np.concatenate([p[0] for p in pairs]) if pairs else np.zeros(0)
    d = np.concatenate([p[1] for p in pairs]) if pairs else np.zeros(0)
    return gate_statistics(g, d)


class NeesAccumulator:
    """Per-frame NEES of one run's IMU pose against the truth (``pipeline.oracle_truth``); a no-op without truth.

    ``add(filter, stamp_s)`` after each pose the filter returns; ``stats()`` gives ``nees_position_mean`` and
    ``nees_orientation_mean`` (time averages over the frames within the truth's span where the NEES is defined;
    NaN when there were none; 3 for a consistent filter), the orientation's split ``nees_tilt_mean`` (roll / pitch,
    2 for a consistent filter) and ``nees_yaw_mean`` (1; :func:`pipeline.oracle_truth.tilt_yaw_nees`), and
    ``nees_undefined_frames`` (frames whose covariance block was singular, e.g. the zero position covariance right
    after an online reset: left out of the means, counted here).
    """

    def __init__(self, truth: TrueImuPoses | None) -> None:
        self._anchored = AnchoredTruth(truth) if truth is not None else None
        self.position: list[float] = []
        self.orientation: list[float] = []
        self.tilt: list[float] = []
        self.yaw: list[float] = []
        self.undefined = 0

    def add(self, filt: MsckfFilter, stamp_s: float) -> None:
        if self._anchored is None or filt.state is None or not self._anchored.poses.covers(stamp_s):
            return
        R_true, p_true = self._anchored(stamp_s, filt.state.R_w_i, filt.state.p)
        e_p, e_t = filt.pose_nees(R_true, p_true)
        if not (np.isfinite(e_p) and np.isfinite(e_t)):
            self.undefined += 1
            return
        self.position.append(e_p)
        self.orientation.append(e_t)
        tilt, yaw = tilt_yaw_nees(filt.state.R_w_i, filt.P[0:3, 0:3], R_true)
        self.tilt.append(tilt)
        self.yaw.append(yaw)

    def stats(self) -> dict[str, float]:
        def mean(v: list[float]) -> float:
            return float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
        return {"nees_position_mean": mean(self.position), "nees_orientation_mean": mean(self.orientation),
                "nees_tilt_mean": mean(self.tilt), "nees_yaw_mean": mean(self.yaw),
                "nees_undefined_frames": float(self.undefined)}


def _observations(fr: TrackedFrame, xy1: np.ndarray, z0: np.ndarray, src: np.ndarray,
                  sigma0: np.ndarray | None, measured: np.ndarray | None = None) -> FeatureObservations:
    return FeatureObservations(fr.stamp_s, fr.ids, fr.xy0, xy1, z0, src, fr.track_length, sigma0, measured)


def ate_against_truth(traj: Trajectory, truth: TrueImuPoses) -> float:
    """ATE RMSE (m) of the estimate's IMU positions against the simulator's true IMU positions *at the estimate's
    own stamps* (the truth is sampled at the IMU rate and interpolated), after an SE(3) alignment.

    The GT file a run is evaluated against is the antenna path at 5 Hz, associated with the 15 Hz estimate by nearest
    stamp within 20 ms (as evo does): every pair then carries a time offset of up to 20 ms, the same in every pair
    when the two clocks' phases are fixed, so even the true trajectory scores an ATE (measured, stop 46:
    rosario-like-03 10 s, 0.0075 m, Sim(3) scale 1.0039 — the true trajectory looks 0.4 % short). At the mm level of
    the 10 s ladder that artifact can decide a comparison; this evaluation has none (the truth scores 0).

    Raises:
        EvalInputError: fewer than 3 estimate stamps within the truth's span, or a degenerate alignment.
    """
    est = traj.subset((traj.stamps_s >= truth.t_s[0]) & (traj.stamps_s <= truth.t_s[-1]))
    ref = Trajectory.from_positions(est.stamps_s, truth.positions(est.stamps_s))
    return float(evaluate(ref, est, EvalOptions(align="se3", max_diff_s=1e-6)).metrics()["ate_rmse_m"])


def evaluate_rung(traj: Trajectory, gt_path: str, lever_arm_imu: Any) -> float:
    """ATE RMSE (m) as a run computes it: SE(3) alignment, 20 ms association, estimate at the antenna."""
    opts = EvalOptions(align="se3", max_diff_s=0.02,
                       lever_arm_m=tuple(lever_arm_imu) if lever_arm_imu is not None else None)
    return float(evaluate(read_tum(gt_path), traj, opts).metrics()["ate_rmse_m"])
