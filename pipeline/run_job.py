"""One run of one variant on one sequence with one seed: VIO (or odometry EKF) → TUM estimate → evaluation → record.

A run folder holds:

* ``record.json`` — the :class:`eval.records.RunRecord` (written last, atomically, by :mod:`pipeline.batch`);
* ``estimate.tum`` — the estimated IMU/body trajectory (base_link for ``odometry``), TUM, for evo and the report;
* ``frames.npz`` — the per-frame log for the replay: stamps, feature counts, time per frame and the features
  themselves (raw left pixels, track length, depth source), ragged arrays flattened with an index; streamed to
  disk while the run goes (:mod:`pipeline.frame_log`), so the features are not held in memory.

The function :func:`run_job` is what the batch runner calls in a worker process; it runs from the job's
:class:`pipeline.run_plan.RunPlan` (resolved settings, the MSCKF config object included: no settings file is read
here) and raises on failure (the batch runner turns the exception into a failed record) except for filter
divergence, which it records itself with the reason and the partial estimate.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from eval.evaluate import evaluate
from eval.records import RunRecord, config_hash
from eval.trajectory import Trajectory, format_tum, read_tum
from eval.variants import DEPTH_INPAINTED, ODOMETRY, STEREO, VARIANTS
from msckf.errors import FilterDivergedError
from msckf.frontend_replay import RecordedDepthFrontend
from msckf.init import NonStaticStartError
from msckf.vio import Msckf
from pipeline.atomic import write_text_atomic
from pipeline.bag_reader import RosarioSequence
from pipeline.batch import RECORD_FIELDS, Job, job_description
from pipeline.depth import to_grey
from pipeline.depth_cache import DepthCache
from pipeline.depth_sigma import DepthSigmaModel
from pipeline.errors import AgrivioError
from pipeline.frame_log import FrameLog, GrowingArray
from pipeline.imu_cache import cached_imu_samples
from pipeline.odometry_ekf import run_odometry_ekf
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.run_plan import RunPlan
from pipeline.track_cache import TrackCache, TrackRecorder, track_key_parts
from pipeline.version import code_version

ESTIMATE_NAME = "estimate.tum"
FRAMES_NAME = "frames.npz"


def _poses_to_trajectory(poses: GrowingArray) -> Trajectory:
    """``poses``: (n, 8) rows of stamp (s), position (3), xyzw quaternion (4)."""
    rows = poses.view()
    return Trajectory(rows[:, 0].copy(), rows[:, 1:4].copy(), rows[:, 4:8].copy(), has_orientation=True)


#: Environment variable: ``off`` makes every ``depth-*`` run track live and record nothing (benchmarks, checks).
TRACK_CACHE_ENV = "AGRIVIO_TRACK_CACHE"


def _track_cache(job: Job, plan: RunPlan) -> TrackCache | None:
    """The shared track recording of a ``depth-*`` run's seed (None: no key to file it under, or switched off
    with ``AGRIVIO_TRACK_CACHE=off``)."""
    if not job.variant.startswith("depth") or not plan.key_parts:
        return None
    if os.environ.get(TRACK_CACHE_ENV, "").strip().lower() in ("off", "0", "false", "no"):
        return None
    return TrackCache(plan.cache_root, plan.bag_identity,
                      track_key_parts(plan.key_parts, plan.msckf.frontend, job.seed))


def _depth_vio(job: Job, plan: RunPlan, rig: Any, tracks: TrackCache | None) -> tuple[Msckf, str]:
    """The VIO of a ``depth-*`` run: replaying its seed's recorded tracks when there are (``"replayed"``), else
    tracking live (``"live"``)."""
    n_recorded = tracks.n_frames() if tracks is not None else None
    if tracks is not None and n_recorded is not None:
        fe = RecordedDepthFrontend(plan.msckf.frontend, rig, rig.T_left_imu, job.seed, tracks.frames(n_recorded))
        return Msckf(plan.msckf, rig, variant="depth", seed=job.seed, frontend=fe), "replayed"
    return Msckf(plan.msckf, rig, variant="depth", seed=job.seed), "live"


def _run_vio(job: Job, plan: RunPlan, seq: RosarioSequence, log: FrameLog) -> tuple[Trajectory, str | None, str]:
    """Feed IMU and frames to the MSCKF in time order; return the trajectory, a divergence reason (or None) and
    how the front end's tracks were obtained (``stereo``, ``live``, ``recorded`` or ``replayed``; a ``depth-*``
    run that tracks live records its tracks for the other depth variants of its seed, :mod:`pipeline.track_cache`).
    """
    rig = seq.calibration
    variant = "stereo" if job.variant == STEREO else "depth"
    if variant == "stereo":
        vio, tracking = Msckf(plan.msckf, rig, variant=variant, seed=job.seed), "stereo"
    else:
        tracks = _track_cache(job, plan)
        vio, tracking = _depth_vio(job, plan, rig, tracks)
        if tracking == "live" and tracks is not None:
            with tracks.recorder() as recorder:
                traj, reason = _feed(job, plan, seq, log, vio, recorder)
                if reason is None and recorder.commit():
                    tracking = "recorded"
            return traj, reason, tracking
    return (*_feed(job, plan, seq, log, vio, None), tracking)


def _feed(job: Job, plan: RunPlan, seq: RosarioSequence, log: FrameLog, vio: Msckf,
          recorder: TrackRecorder | None) -> tuple[Trajectory, str | None]:
    """The frame loop of :func:`_run_vio`: IMU, images and depth in time order into ``vio``; each frame's tracks
    into ``recorder`` when given."""
    rig = seq.calibration
    variant = vio.variant
    replayed = isinstance(vio.frontend, RecordedDepthFrontend)
    imu_ns, imu = cached_imu_samples(seq, plan.cache_root)
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
    poses = GrowingArray(np.float64, width=8)  # stamp, p, q per pose: 64 B, not three Python objects
    k_imu = 0
    try:
        for frame in seq.stereo_frames(stop_index=plan.max_frames, right=variant == "stereo", left=not replayed):
            t_img = frame.stamp_ns / 1e9  # the same ns → s conversion as the IMU's
            k_end = imu_samples_through(imu_ns, frame.stamp_ns, k_imu)  # ordered in integer ns, not in seconds
            for k in range(k_imu, k_end):
                try:
                    vio.add_imu(imu_ns[k] / 1e9, imu[k, 0:3], imu[k, 3:6])
                except NonStaticStartError as exc:  # S-MSCKF needs a still start: wait for one, say so if none
                    non_static = str(exc)
            k_imu = k_end
            left = None if frame.left_bgr is None else to_grey(frame.left_bgr)
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
                    valid, sigma, far, edge = sigma_model.filled_detail(d.depth_m, d.valid, r.depth_m, r.valid,
                                                                        plan.inpaint_method)
                    measured = r.valid
                    fills = d.valid & ~r.valid
                    log.add_fills(np.count_nonzero(fills), np.count_nonzero(fills & far),
                                  np.count_nonzero(fills & edge & ~far))
                pose = vio.add_frame(t_img, left, depth=d.depth_m, depth_valid=valid, depth_sigma=sigma,
                                     depth_measured=measured)
                if recorder is not None:
                    recorder.add(vio.frontend.last_tracks)
            log.add(t_img, vio.last_debug, time.perf_counter() - t0)
            log.add_gate(vio.last_stats)
            if pose is not None:
                poses.append(np.concatenate([[pose.stamp_s], np.asarray(pose.p_world, np.float64).reshape(3),
                                             np.asarray(pose.q_world_imu_xyzw, np.float64).reshape(4)]))
    except FilterDivergedError as exc:
        return _poses_to_trajectory(poses), exc.reason + (f" at t={exc.stamp_s:.2f} s"
                                                                   if exc.stamp_s is not None else "")
    if not vio.initialized:
        return _poses_to_trajectory(poses), ("the filter never initialised" +
                                                      (f": {non_static}" if non_static else ""))
    return _poses_to_trajectory(poses), None


M_MMAP_THRESHOLD = -3  # glibc <malloc.h>
MMAP_THRESHOLD_BYTES = 128 * 1024  # glibc's initial value


def fixed_mmap_threshold() -> bool:
    """Keep glibc's mmap threshold at its initial 128 KiB for this process; True if set (glibc), else False.

    glibc raises the threshold to the size of each mmapped block that is freed (up to 32 MiB), after which the
    per-frame images, depth maps and filter matrices (0.1–2 MB, allocated and freed every frame) come from the
    heap instead, whose free space fragments and is not returned: a whole run's RSS then creeps up with the number
    of frames although no data are kept (measured on 120 s rosario-like-02 stereo: +7–12 MB per 1,000 frames
    inside the frame loop with the threshold free to move, flat with it fixed). A fixed threshold also stops the
    trim threshold from moving. Nothing else changes: the same arrays, the same values.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (macOS, Windows): nothing to do
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


def imu_samples_through(imu_stamps_ns: np.ndarray, frame_stamp_ns: int, start: int = 0) -> int:
    """The end index of the IMU samples a frame at ``frame_stamp_ns`` must see: every sample from ``start`` with a
    stamp ≤ the frame's, compared in integer ns (imu_stamps_ns: (N,) int64, sorted). In float seconds a sample up
    to ≈ 238 ns after a 2017-epoch frame compares equal to it and would be fed before the frame."""
    return max(int(np.searchsorted(imu_stamps_ns, np.int64(frame_stamp_ns), side="right")), start)


def feed_imu_until(vio: Msckf, imu: np.ndarray, start: int, t_s: float) -> int:
    """Feed ``vio`` the rows of ``imu`` ((M, 7) ``[t_s, gyro rad/s, accel m/s²]``, IMU frame) from ``start`` whose
    time is ≤ ``t_s`` (seconds); returns the index of the first row not fed. A :class:`NonStaticStartError` (the
    filter waits for a still start; the sample has reached the front end) is passed over — for the oracle and the
    benchmarks, which feed float-second arrays; a run uses :func:`imu_samples_through` and reports the error."""
    k = start
    while k < len(imu) and imu[k, 0] <= t_s:
        try:
            vio.add_imu(imu[k, 0], imu[k, 1:4], imu[k, 4:7])
        except NonStaticStartError:
            pass
        k += 1
    return k


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
    fixed_mmap_threshold()
    out = Path(job.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    seq = RosarioSequence(plan.bag, camchain=plan.camchain)
    failure = None
    tracking = None
    # the frame log streams to a spill folder next to frames.npz while the run goes; a diverged run saves it
    # like a finished one, a run that raises leaves neither the spill nor a partial frames.npz
    with FrameLog(out / FRAMES_NAME) as log:
        if job.variant == ODOMETRY:
            est = _run_odometry(plan, seq)
        else:
            est, failure, tracking = _run_vio(job, plan, seq, log)
            log.save()
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
               "frames": int(len(log)), "feature_depth": log.depth_summary(),
               "chi2_gate": log.gate_summary(), "zero_velocity": log.zupt_summary(), "tracks": tracking,
               **{k: job.options.get(k) for k in RECORD_FIELDS},
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
