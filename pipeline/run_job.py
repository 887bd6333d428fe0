"""One run of one variant on one sequence with one seed: VIO (or odometry EKF) → TUM estimate → evaluation → record.

A run folder holds:

* ``record.json`` — the :class:`eval.records.RunRecord` (written last, atomically, by :mod:`pipeline.batch`);
* ``estimate.tum`` — the estimated IMU/body trajectory (base_link for ``odometry``), TUM, for evo and the report;
* ``frames.npz`` — the per-frame log for the replay: stamps, feature counts, time per frame and the features
  themselves (raw left pixels, track length, depth source), ragged arrays flattened with an index.

The function :func:`run_job` is what the batch runner calls in a worker process; it runs from the job's
:class:`pipeline.run_plan.RunPlan` (resolved settings, the MSCKF config object included: no settings file is read
here) and raises on failure (the batch runner turns the exception into a failed record) except for filter
divergence, which it records itself with the reason and the partial estimate.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from eval.evaluate import evaluate
from eval.records import RunRecord, config_hash
from eval.trajectory import Trajectory, format_tum, read_tum
from eval.variants import DEPTH_INPAINTED, ODOMETRY, STEREO, VARIANTS
from msckf.errors import FilterDivergedError
from msckf.init import NonStaticStartError
from msckf.vio import Msckf
from pipeline.atomic import atomic_path, write_text_atomic
from pipeline.bag_reader import RosarioSequence
from pipeline.batch import RECORD_FIELDS, Job, job_description
from pipeline.depth import to_grey
from pipeline.depth_cache import DepthCache
from pipeline.depth_sigma import DepthSigmaModel
from pipeline.errors import AgrivioError
from pipeline.odometry_ekf import run_odometry_ekf
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.run_plan import RunPlan
from pipeline.version import code_version

ESTIMATE_NAME = "estimate.tum"
FRAMES_NAME = "frames.npz"


class _FrameLog:
    """Per-frame log of a VIO run (for the replay and timing figures)."""

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.n_features: list[int] = []
        self.n_depth: list[int] = []
        self.frame_ms: list[float] = []
        self.uv: list[np.ndarray] = []
        self.track_len: list[np.ndarray] = []
        self.source: list[np.ndarray] = []
        self.depth: list[np.ndarray] = []
        self.depth_sigma: list[np.ndarray] = []
        self.measured: list[np.ndarray] = []
        self.gate_ratio: list[np.ndarray] = []
        self.gated = 0
        self.gated_out = 0
        self.fill_px = 0
        self.far_open_px = 0

    def add_fills(self, n_filled_px: int, n_far_open_px: int) -> None:
        """Count one frame's inpainted pixels (raw SGBM holes the method filled) and how many of them were
        dropped as open to the far field (:meth:`pipeline.depth_sigma.DepthSigmaModel.far_open`)."""
        self.fill_px += int(n_filled_px)
        self.far_open_px += int(n_far_open_px)

    def add_gate(self, stats: Any) -> None:
        """Collect the χ² gate of one frame (``msckf.filter.FrameStats``): γ/dof of every gated feature."""
        self.gate_ratio.append(stats.gamma_per_dof())
        self.gated += stats.n_gated
        self.gated_out += int(stats.n_gated_out)

    def gate_summary(self) -> dict[str, float]:
        """The χ² gate over the run: median and mean γ/dof (≈ 1 when the measurement noise is calibrated) and the
        fraction of gated features that were rejected."""
        r = _cat(self.gate_ratio, np.float64)
        if r.size == 0:
            return {}
        return {"gamma_per_dof_median": float(np.median(r)), "gamma_per_dof_mean": float(np.mean(r)),
                "features_gated": self.gated, "rejected_fraction": float(self.gated_out / max(self.gated, 1))}

    def add(self, stamp_s: float, debug: Any, elapsed_s: float) -> None:
        self.stamps.append(stamp_s)
        self.frame_ms.append(1e3 * elapsed_s)
        if debug is None:
            uv, tl, src = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        else:
            uv, tl, src = debug.cam0_px, debug.track_length, debug.source
        n = len(src)
        depth = getattr(debug, "depth_m", None)
        sigma = getattr(debug, "depth_sigma_m", None)
        measured = getattr(debug, "depth_measured", None)
        self.uv.append(np.asarray(uv, dtype=np.float32).reshape(-1, 2))
        self.track_len.append(np.asarray(tl, dtype=np.int32))
        self.source.append(np.asarray(src, dtype=np.uint8))
        self.depth.append(np.full(n, np.nan, np.float32) if depth is None else np.asarray(depth, np.float32))
        self.depth_sigma.append(np.full(n, np.nan, np.float32) if sigma is None else np.asarray(sigma, np.float32))
        self.measured.append(np.zeros(n, bool) if measured is None else np.asarray(measured, bool))
        self.n_features.append(len(self.uv[-1]))
        self.n_depth.append(int(np.count_nonzero(self.source[-1] > 0)))

    def save(self, path: Path) -> None:
        counts = np.array([len(u) for u in self.uv], dtype=np.int64)
        with atomic_path(path, suffix=".npz") as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh, stamps_s=np.array(self.stamps), n_features=np.array(self.n_features),
                    n_depth=np.array(self.n_depth), frame_ms=np.array(self.frame_ms),
                    feature_offsets=np.concatenate([[0], np.cumsum(counts)]),
                    feature_uv=_cat(self.uv, np.float32).reshape(-1, 2),
                    feature_track_length=_cat(self.track_len, np.int32),
                    feature_source=_cat(self.source, np.uint8),
                    feature_depth_m=_cat(self.depth, np.float32),
                    feature_depth_sigma_m=_cat(self.depth_sigma, np.float32),
                    feature_depth_measured=_cat(self.measured, bool))

    def depth_summary(self) -> dict[str, float]:
        """How much of the run's feature depth was measured vs filled, and its stated σ_Z/Z (medians)."""
        z, sig, meas = _cat(self.depth, np.float64), _cat(self.depth_sigma, np.float64), _cat(self.measured, bool)
        has = np.isfinite(z)
        if not has.any():
            return {}
        out: dict[str, float] = {"features_with_depth": int(has.sum()),
                                 "filled_fraction": float(np.mean(~meas[has]))}
        rel = sig / z
        for name, sel in (("measured", has & meas), ("filled", has & ~meas)):
            r = rel[sel & np.isfinite(rel)]
            if r.size:
                out[f"sigma_rel_median_{name}"] = float(np.median(r))
        if self.fill_px:
            out["far_open_fill_fraction"] = float(self.far_open_px / self.fill_px)
        return out

    def timing_summary(self) -> dict[str, float]:
        ms = np.asarray(self.frame_ms)
        if ms.size == 0:
            return {}
        return {"frame_ms_median": float(np.median(ms)), "frame_ms_p95": float(np.percentile(ms, 95)),
                "fps": float(1e3 / np.mean(ms))}


def _cat(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)


def _poses_to_trajectory(stamps: list[float], p: list[np.ndarray], q: list[np.ndarray]) -> Trajectory:
    return Trajectory(np.asarray(stamps, dtype=np.float64), np.asarray(p, dtype=np.float64).reshape(-1, 3),
                      np.asarray(q, dtype=np.float64).reshape(-1, 4), has_orientation=True)


def _run_vio(job: Job, plan: RunPlan, seq: RosarioSequence, log: _FrameLog) -> tuple[Trajectory, str | None]:
    """Feed IMU and frames to the MSCKF in time order; return the trajectory and a divergence reason (or None)."""
    rig = seq.calibration
    variant = "stereo" if job.variant == STEREO else "depth"
    vio = Msckf(plan.msckf, rig, variant=variant, seed=job.seed)
    imu_ns, imu = seq.imu_samples()
    depth_params = plan.depth_params(job.variant)
    depth_store = DepthCache(plan.cache_root, plan.bag_identity, depth_params) if depth_params is not None else None
    if depth_store is not None and not depth_store.has_frames(plan.max_frames):
        raise AgrivioError(f"{seq.path}: the {job.variant} depth cache is missing or incomplete "
                           f"({depth_store.directory}); run the depth/inpainting stage first")
    # Per-pixel depth σ (pipeline/depth_sigma.py): the raw validity mask travels with the inpainted map, so the
    # filter can tell a filled depth from a measured one.
    sigma_model = DepthSigmaModel.for_rig(rig)
    raw_store = DepthCache(plan.cache_root, plan.bag_identity, plan.depth) if job.variant == DEPTH_INPAINTED else None
    non_static: str | None = None
    stamps: list[float] = []
    ps: list[np.ndarray] = []
    qs: list[np.ndarray] = []
    k_imu = 0
    try:
        for frame in seq.stereo_frames(stop_index=plan.max_frames, right=variant == "stereo"):
            t_img = frame.stamp_ns / 1e9  # the same ns → s conversion as the IMU's
            k_end = imu_samples_through(imu_ns, frame.stamp_ns, k_imu)  # ordered in integer ns, not in seconds
            for k in range(k_imu, k_end):
                try:
                    vio.add_imu(imu_ns[k] / 1e9, imu[k, 0:3], imu[k, 3:6])
                except NonStaticStartError as exc:  # S-MSCKF needs a still start: wait for one, say so if none
                    non_static = str(exc)
            k_imu = k_end
            left = to_grey(frame.left_bgr)
            t0 = time.perf_counter()
            if variant == "stereo":
                pose = vio.add_frame(t_img, left, right_grey=to_grey(frame.right_bgr))
            else:
                d = depth_store.get(frame.index, grey=False)
                if d is None or d.stamp_ns != frame.stamp_ns:  # joined by stamp (integer ns), never by index only
                    raise AgrivioError(f"{seq.path}: depth cache has no frame {frame.index} at stamp "
                                       f"{frame.stamp_ns} ns" + (f" (it holds {d.stamp_ns} ns)" if d else ""))
                if raw_store is None:
                    sigma = sigma_model.raw_sigma(d.depth_m, d.valid)
                    valid = measured = d.valid
                else:
                    r = raw_store.get(frame.index, grey=False)
                    if r is None or r.stamp_ns != frame.stamp_ns:
                        raise AgrivioError(f"{seq.path}: raw depth cache has no frame {frame.index} at stamp "
                                           f"{frame.stamp_ns} ns")
                    valid, sigma = sigma_model.filled(d.depth_m, d.valid, r.depth_m, r.valid, plan.inpaint_method)
                    measured = r.valid
                    fills = d.valid & ~r.valid
                    log.add_fills(np.count_nonzero(fills), np.count_nonzero(fills & ~valid))
                pose = vio.add_frame(t_img, left, depth=d.depth_m, depth_valid=valid, depth_sigma=sigma,
                                     depth_measured=measured)
            log.add(t_img, vio.last_debug, time.perf_counter() - t0)
            log.add_gate(vio.last_stats)
            if pose is not None:
                stamps.append(pose.stamp_s)
                ps.append(pose.p_world)
                qs.append(pose.q_world_imu_xyzw)
    except FilterDivergedError as exc:
        return _poses_to_trajectory(stamps, ps, qs), exc.reason + (f" at t={exc.stamp_s:.2f} s"
                                                                   if exc.stamp_s is not None else "")
    if not vio.initialized:
        return _poses_to_trajectory(stamps, ps, qs), ("the filter never initialised" +
                                                      (f": {non_static}" if non_static else ""))
    return _poses_to_trajectory(stamps, ps, qs), None


def imu_samples_through(imu_stamps_ns: np.ndarray, frame_stamp_ns: int, start: int = 0) -> int:
    """The end index of the IMU samples a frame at ``frame_stamp_ns`` must see: every sample from ``start`` with a
    stamp ≤ the frame's, compared in integer ns (imu_stamps_ns: (N,) int64, sorted). In float seconds a sample up
    to ≈ 238 ns after a 2017-epoch frame compares equal to it and would be fed before the frame."""
    return max(int(np.searchsorted(imu_stamps_ns, np.int64(frame_stamp_ns), side="right")), start)


def _run_odometry(plan: RunPlan, seq: RosarioSequence) -> Trajectory:
    R = np.asarray(plan.R_base_imu) if plan.R_base_imu is not None else None
    odom = seq.odom_array()
    if plan.max_frames is not None:  # the odometry of the first max_frames camera frames' time span
        t_end = (seq.start_ns + round(plan.max_frames * 1e9 / RATE_CAMERA_HZ)) / 1e9
        odom = odom[odom[:, 0] <= t_end]
    return run_odometry_ekf(odom, seq.imu_array(), R_base_imu=R).trajectory


def run_job(job: Job) -> dict[str, Any]:
    """Run one job (see the module docstring) from its plan and return its record as a dict."""
    if job.variant not in VARIANTS:
        raise AgrivioError(f"unknown variant {job.variant!r}; choose from {', '.join(VARIANTS)}")
    plan = job.plan
    if not isinstance(plan, RunPlan):
        raise AgrivioError(f"{job.label}: the job carries no run plan (jobs come from pipeline.run_sequence.plan_jobs)")
    import cv2

    cv2.setNumThreads(1)  # one run = one core: runs are parallelised across processes, not inside OpenCV
    out = Path(job.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    seq = RosarioSequence(plan.bag, camchain=plan.camchain)
    log = _FrameLog()
    failure = None
    if job.variant == ODOMETRY:
        est = _run_odometry(plan, seq)
    else:
        est, failure = _run_vio(job, plan, seq, log)
        log.save(out / FRAMES_NAME)
    t_run = time.perf_counter() - t_start
    if len(est.stamps_s):
        frame_name = "base_link" if job.variant == ODOMETRY else "IMU"
        write_text_atomic(out / ESTIMATE_NAME, format_tum(est, header=f"agrivio {job.label} ({frame_name} frame)"))
    metrics: dict[str, Any] = {}
    eval_options = plan.eval_options(job.variant)
    if failure is None and plan.gt is not None:
        if len(est.stamps_s) < 3:
            failure = f"the filter produced {len(est.stamps_s)} poses (never initialised?)"
        else:
            metrics = evaluate(read_tum(plan.gt), est, eval_options).metrics()
    settings = {"variant": job.variant, "inputs": plan.variant_inputs(job.variant), "eval": eval_options.to_dict()}
    if job.variant != ODOMETRY:
        settings["msckf"] = plan.msckf.to_flat_dict()
    record = RunRecord(
        sequence=job.sequence, variant=job.variant, seed=job.seed,
        status="failed" if failure else "ok", failure_reason=failure,
        inpaint_method=plan.inpaint_method if job.variant == DEPTH_INPAINTED else None,
        config_hash=config_hash(settings), code_version=code_version(), metrics=metrics,
        timings={"total_s": time.perf_counter() - t_start, "run_s": t_run, **log.timing_summary()},
        estimate_path=ESTIMATE_NAME if len(est.stamps_s) else None,
        gt_path=str(Path(plan.gt).resolve()) if plan.gt else None,
        extra={"eval_options": eval_options.to_dict(), "n_poses": int(len(est.stamps_s)),
               "frames": int(len(log.stamps)), "feature_depth": log.depth_summary(),
               "chi2_gate": log.gate_summary(), **{k: job.options.get(k) for k in RECORD_FIELDS},
               "job": job_description(job)},
    )
    return record.to_dict()


def lever_arms_from_tf(seq: RosarioSequence) -> dict[str, Any]:
    """Antenna lever arms from the bag's ``tf_static`` (base_link→imu, base_link→gps), or {} if absent.

    Returns keys ``lever_arm_imu`` (antenna in the IMU frame), ``lever_arm_base`` (antenna in base_link) and
    ``R_base_imu`` (IMU → base_link rotation), JSON-able.
    """
    tfs = {(p.lstrip("/"), c.lstrip("/")): T for (p, c), T in seq.static_transforms().items()}
    T_base_imu = tfs.get(("base_link", "imu"))
    T_base_gps = tfs.get(("base_link", "gps"))
    out: dict[str, Any] = {}
    if T_base_gps is not None:
        out["lever_arm_base"] = tuple(float(x) for x in T_base_gps[:3, 3])
    if T_base_imu is not None:
        out["R_base_imu"] = tuple(tuple(float(x) for x in row) for row in T_base_imu[:3, :3])
        if T_base_gps is not None:
            p_imu = np.linalg.inv(T_base_imu) @ np.append(T_base_gps[:3, 3], 1.0)
            out["lever_arm_imu"] = tuple(float(x) for x in p_imu[:3])
    return out


__all__ = ["lever_arms_from_tf", "run_job"]
