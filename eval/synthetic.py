"""Synthetic trajectories and run sets for tests, benchmarks and report previews (seeded, deterministic).

Not a simulator of the robot: a smooth planar path with small height changes, and estimates made from it by
a rigid world change, a slow random-walk drift and white noise.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from eval.trajectory import Trajectory
from eval.variants import DEPTH_INPAINTED, DEPTH_RAW, ODOMETRY, STEREO, VARIANTS

__all__ = ["field_path", "perturbed_estimate", "random_transform", "synthetic_runset"]


def field_path(duration_s: float = 120.0, rate_hz: float = 10.0, speed_mps: float = 1.0, row_length_m: float = 40.0,
               row_spacing_m: float = 3.0, t0_s: float = 1_600_000_000.0) -> Trajectory:
    """A crop-row path: straight rows joined by half-circle turns, z with a gentle slope, heading along travel.

    Args:
        duration_s, rate_hz: sampling (seconds, Hz). speed_mps: constant ground speed (m/s).
        row_length_m, row_spacing_m: field layout (metres). t0_s: first stamp (s, epoch-like).
    Returns:
        ``T_world_body`` poses (x east, y north, z up; body x forward), with orientation.
    """
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    s = speed_mps * t
    turn = np.pi * row_spacing_m / 2.0
    period = 2.0 * (row_length_m + turn)
    k, u = np.divmod(s, period)
    x = np.empty(n)
    y = np.empty(n)
    yaw = np.empty(n)
    r = row_spacing_m / 2.0
    base_y = k * 2.0 * row_spacing_m
    # four pieces: row east, turn left (north), row west, turn right (north)
    a = u < row_length_m
    x[a], y[a], yaw[a] = u[a], base_y[a], 0.0
    b = (u >= row_length_m) & (u < row_length_m + turn)
    th = (u[b] - row_length_m) / r
    x[b], y[b], yaw[b] = row_length_m + r * np.sin(th), base_y[b] + r - r * np.cos(th), th
    c = (u >= row_length_m + turn) & (u < 2 * row_length_m + turn)
    x[c], y[c], yaw[c] = row_length_m - (u[c] - row_length_m - turn), base_y[c] + row_spacing_m, np.pi
    d = u >= 2 * row_length_m + turn
    th = (u[d] - 2 * row_length_m - turn) / r
    x[d] = -r * np.sin(th)
    y[d] = base_y[d] + row_spacing_m + r - r * np.cos(th)
    yaw[d] = np.pi - th
    z = 0.02 * x + 0.1 * np.sin(0.05 * s)
    pos = np.column_stack([x, y, z])
    quats = Rotation.from_euler("z", yaw[:, None]).as_quat().reshape(n, 4)
    return Trajectory(t0_s + t, pos, quats)


def random_transform(rng: np.random.Generator, max_angle_rad: float = np.pi,
                     max_translation_m: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A random rotation (3, 3) (angle ≤ ``max_angle_rad``) and translation (3,) (each |t_i| ≤ max)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rot = Rotation.from_rotvec(axis * rng.uniform(0.0, max_angle_rad)).as_matrix()
    return rot, rng.uniform(-max_translation_m, max_translation_m, size=3)


def perturbed_estimate(gt: Trajectory, seed: int, noise_m: float = 0.02, drift_m_per_sqrt_s: float = 0.02,
                       yaw_drift_deg: float = 0.0, world_yaw_deg: float = 25.0,
                       world_t_m: tuple[float, float, float] = (3.0, -2.0, 0.5), scale: float = 1.0,
                       time_offset_s: float = 0.0, keep_every: int = 1) -> Trajectory:
    """An estimate of ``gt`` as a VIO might give it, in its own world frame.

    positions: ``scale·R_w·(p_gt + random-walk drift + white noise) + t_w``; orientations: ``R_w·R_gt`` (plus a
    linear yaw drift reaching ``yaw_drift_deg`` at the end, applied to positions about the start too);
    stamps shifted by ``time_offset_s``; every ``keep_every``-th pose kept. Seeded by ``seed``.
    """
    rng = np.random.default_rng(seed)
    n = len(gt)
    dt = np.diff(gt.stamps_s, prepend=gt.stamps_s[0])
    walk = np.cumsum(rng.normal(size=(n, 3)) * np.sqrt(dt)[:, None] * drift_m_per_sqrt_s, axis=0)
    walk[:, 2] *= 0.3
    frac = (gt.stamps_s - gt.stamps_s[0]) / max(gt.duration_s, 1e-9)
    yaw_err = Rotation.from_euler("z", np.radians(yaw_drift_deg * frac)[:, None])
    p = gt.positions - gt.positions[0]
    p = yaw_err.apply(p) + gt.positions[0] + walk + rng.normal(size=(n, 3)) * noise_m
    r_w = Rotation.from_euler("z", np.radians(world_yaw_deg))
    pos = scale * r_w.apply(p) + np.asarray(world_t_m)
    quats = (r_w * yaw_err * gt.rotations).as_quat()
    est = Trajectory(gt.stamps_s + time_offset_s, pos, quats, has_orientation=True)
    return est.subset(np.arange(0, n, keep_every)) if keep_every > 1 else est


#: Per-variant error scale of :func:`synthetic_runset` (drift m/√s, yaw drift deg) — made up, for previews only.
_VARIANT_ERRORS = {STEREO: (0.05, 2.0), DEPTH_RAW: (0.06, 3.0), DEPTH_INPAINTED: (0.035, 1.5), ODOMETRY: (0.15, 8.0)}


def synthetic_runset(sequences: tuple[str, ...] = ("sim-01", "sim-02"),
                     variants: tuple[str, ...] = VARIANTS,
                     n_seeds: int = 5, failed: tuple[tuple[str, str, int], ...] = (("sim-01", DEPTH_RAW, 3),),
                     duration_s: float = 120.0, code_version: str = "synthetic") -> dict[str, str]:
    """Files of a fake runs folder: ``relative path → text`` (run-record JSON and TUM trajectories).

    Layout: ``<seq>/gt.tum`` and ``<seq>/<variant>/seed<k>/{record.json, estimate.tum}``; the runs listed in
    ``failed`` (sequence, variant, seed) get a failed record and no estimate. Metrics are computed with
    :func:`eval.evaluate.evaluate` (SE(3), position-only GT). The numbers are synthetic, not results.
    """
    import json

    from eval.evaluate import EvalOptions, evaluate
    from eval.records import RunRecord, config_hash
    from eval.trajectory import format_tum

    files: dict[str, str] = {}
    for si, seq in enumerate(sequences):
        gt_full = field_path(duration_s=duration_s + 10 * si, rate_hz=5.0, row_length_m=30.0 + 5 * si)
        gt = Trajectory.from_positions(gt_full.stamps_s, gt_full.positions)
        files[f"{seq}/gt.tum"] = format_tum(gt, header=f"synthetic ground truth of {seq} (position only)")
        for vi, variant in enumerate(variants):
            drift, yaw = _VARIANT_ERRORS.get(variant, (0.05, 2.0))
            for seed in range(n_seeds):
                folder = f"{seq}/{variant}/seed{seed}"
                method = "paper" if variant == DEPTH_INPAINTED else None
                cfg = {"sequence": seq, "variant": variant, "inpaint_method": method}
                if (seq, variant, seed) in failed:
                    rec = RunRecord(seq, variant, seed, status="failed",
                                    failure_reason="FilterDivergedError: filter diverged at t=42.000 s: velocity "
                                                   "above 50 m/s", inpaint_method=method,
                                    config_hash=config_hash(cfg), code_version=code_version,
                                    timings={"total_s": 12.5})
                    files[f"{folder}/record.json"] = json.dumps(rec.to_dict(), indent=2, sort_keys=True) + "\n"
                    continue
                est = perturbed_estimate(gt_full, seed=1000 * si + 100 * vi + seed, drift_m_per_sqrt_s=drift,
                                         yaw_drift_deg=yaw * (1 + 0.2 * seed), time_offset_s=0.002,
                                         keep_every=1)
                ev = evaluate(gt, est, EvalOptions(align="se3"))
                rec = RunRecord(seq, variant, seed, inpaint_method=method, config_hash=config_hash(cfg),
                                code_version=code_version, metrics=ev.metrics(),
                                timings={"total_s": 60.0 + seed, "vio_s": 40.0 + seed},
                                estimate_path="estimate.tum", gt_path="../../gt.tum")
                files[f"{folder}/estimate.tum"] = format_tum(est)
                files[f"{folder}/record.json"] = json.dumps(rec.to_dict(), indent=2, sort_keys=True) + "\n"
    return files
