"""The oracle ladder on a simulated sequence: inputs from the cache, every rung × seed, the monotonicity verdict.

Used by ``benchmarks/bench_depth_oracle.py`` and its test. The ATE is computed against the simulator's *true*
antenna positions (``gt_antenna_true.tum``: no RTK noise, so the rungs are compared without a shared noise
floor), with the pipeline's alignment (SE(3), 20 ms, estimate at the antenna).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from eval.errors import EvalInputError
from eval.trajectory import Trajectory
from msckf.config import MsckfConfig, load_config
from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthParams, to_grey
from pipeline.depth_cache import DepthCache, depth_stream
from pipeline.depth_oracle import (
    PAIR_CHECKS,
    NeesAccumulator,
    Rung,
    TrackLog,
    ate_against_truth,
    evaluate_rung,
    frames_gate_statistics,
    record_tracks,
    run_backend,
    snap_to_true_points,
    standard_rungs,
    true_track_depths,
)
from pipeline.depth_sigma import DepthSigmaModel
from pipeline.inpaint_stage import InpaintParams, inpainted_stream
from pipeline.oracle_truth import TrueImuPoses, imu_without_true_acc_bias
from pipeline.run_job import feed_imu_until, lever_arms_from_tf
from pipeline.sim.sequence import SimulatedSequence

__all__ = ["prepare_oracle", "run_ladder", "ladder_verdict", "stereo_reference", "default_config"]


def prepare_oracle(sim_dir: Path, cache_root: Path, methods: Sequence[str], config: MsckfConfig,
                   seeds: Iterable[int], max_frames: int | None = None,
                   sigma_overrides: Mapping[str, Any] | None = None, true_acc_bias: bool = False,
                   exact_pixels: bool = False) -> dict[str, Any]:
    """Record one :class:`TrackLog` per seed (with truth) for a simulated sequence folder.

    Depth and inpainted caches are computed when missing (the pipeline's own stages and caches). Inpainted maps
    reach the front end as a depth-inpainted run gets them (:meth:`DepthSigmaModel.filled`). ``sigma_overrides``:
    fields of the rig's :class:`DepthSigmaModel` replaced for the ablations, e.g. ``{"far_open_radius_px": 0}`` (the
    far-field rule off: every fill kept) or ``{"edge_disparity_sigmas": 0}`` (the occlusion-edge rule off).
    ``true_acc_bias``: the back ends get the IMU with the simulator's accelerometer bias removed
    (:func:`pipeline.oracle_truth.imu_without_true_acc_bias`; the tracks are recorded from the bag's IMU as before);
    run them with :data:`pipeline.oracle_truth.PINNED_ACC_BIAS`. ``exact_pixels``: every truth-triangulated track's
    pixels replaced by the exact projection of its point (:func:`pipeline.depth_oracle.snap_to_true_points`, a
    diagnostic: what the features' pixel errors cost, apart from their depths).
    """
    sim = SimulatedSequence(Path(sim_dir))
    seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
    rig = seq.calibration
    for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=cache_root,
                          stop_index=max_frames):
        pass
    for m in methods:
        for _ in inpainted_stream(seq, InpaintParams(method=m), cache_root, progress=False):
            pass
    raw = DepthCache(cache_root, seq.identity(), DepthParams())
    inp = {m: DepthCache(cache_root, seq.identity(), InpaintParams(method=m)) for m in methods}
    model = replace(DepthSigmaModel.for_rig(rig), **(sigma_overrides or {}))

    def raw_provider(i: int):
        f = raw.get(i)
        return f.depth_m, f.valid, model.raw_sigma(f.depth_m, f.valid)

    def inp_provider(m: str):
        def p(i: int):
            f = inp[m].get(i)
            r = raw.get(i)
            valid, sigma = model.filled(f.depth_m, f.valid, r.depth_m, r.valid, m)
            return f.depth_m, valid, sigma
        return p

    def exact_provider(i: int):
        d = sim.depth(i)
        return d, np.isfinite(d) & (d > 0), None

    truth = sim.truth
    stamp_to_k = {int(s): k for k, s in enumerate(truth["frame_stamp_ns"])}
    frames = []
    T_world_rect: dict[int, np.ndarray] = {}
    for fr in seq.stereo_frames(stop_index=max_frames):
        k = stamp_to_k.get(int(fr.stamp_ns))
        if k is None:
            raise ValueError(f"{sim_dir}: frame {fr.index} (stamp {fr.stamp_ns}) has no simulator truth")
        T_world_rect[fr.index] = truth["T_E_rectleft"][k]
        frames.append((fr.index, fr.stamp_ns / 1e9, to_grey(fr.left_bgr)))  # as a run converts image stamps
    imu = seq.imu_array()
    logs: dict[int, TrackLog] = {}
    truth_stats: dict[int, dict[str, float]] = {}
    for seed in seeds:
        log = record_tracks(rig, config, seed, imu, frames, raw_provider,
                            {m: inp_provider(m) for m in methods})
        truth_stats[seed] = true_track_depths(log, rig.K_rect, T_world_rect, exact_provider,
                                              config.frontend.min_depth_m, config.frontend.max_depth_m)
        if exact_pixels:
            snap_to_true_points(log, rig.K_rect, rig.R_left, T_world_rect)
        if true_acc_bias:
            log.imu = imu_without_true_acc_bias(log.imu, truth)
        logs[seed] = log
    lever = lever_arms_from_tf(seq).get("lever_arm_imu")
    return {"logs": logs, "rig": rig, "gt": str(sim.gt_antenna_true_path), "lever": lever,
            "imu_truth": TrueImuPoses.from_truth(truth),
            "truth_stats": truth_stats, "depth_errors": _depth_errors(logs, methods)}


def _depth_errors(logs: dict[int, TrackLog], methods: Sequence[str]) -> dict[str, dict[str, float]]:
    """Median |relative error| of each map's depth at tracked points against the tracked-point truth."""
    out: dict[str, dict[str, float]] = {}
    for name in ["raw", *methods]:
        rel: list[np.ndarray] = []
        for log in logs.values():
            for fr, t, s in zip(log.frames, log.truth, log.truth_source):
                z = fr.z_rect[name]
                ok = np.isfinite(z) & np.isfinite(t) & (s == 1)
                rel.append((z[ok] - t[ok]) / t[ok])
        r = np.concatenate(rel) if rel else np.zeros(0)
        out[name] = {"n": int(len(r)), "median_abs_rel": float(np.median(np.abs(r))) if len(r) else float("nan"),
                     "median_rel": float(np.median(r)) if len(r) else float("nan")}
    return out


def _scores(traj: Trajectory, prepared: dict[str, Any]) -> tuple[float, float | None]:
    """ATE RMSE (m) of one run against the GT file as a run computes it, and against the true IMU trajectory where
    ``prepared`` has it (else None). Raises ``EvalInputError`` when either cannot be computed."""
    truth = prepared.get("imu_truth")
    return (evaluate_rung(traj, prepared["gt"], prepared["lever"]),
            None if truth is None else ate_against_truth(traj, truth))


def run_ladder(prepared: dict[str, Any], config: MsckfConfig, rungs: list[Rung] | None = None,
               methods: Sequence[str] = (), use_sigma: bool = True) -> dict[str, dict[str, Any]]:
    """ATE RMSE of every rung for every seed: ``{rung: {"ate": {seed: m}, "failed": {seed: reason}, ...}}``, with the
    runs' time-averaged NEES of position and orientation averaged over seeds (``nees_position`` /
    ``nees_orientation``: 3 for a consistent filter) where ``prepared`` has the true IMU poses."""
    rungs = rungs or standard_rungs(methods)
    out: dict[str, dict[str, Any]] = {}
    for rung in rungs:
        ate: dict[int, float] = {}
        ate_truth: dict[int, float] = {}
        failed: dict[int, str] = {}
        stats: dict[int, dict[str, Any]] = {}
        for seed, log in prepared["logs"].items():
            traj, failure, st = run_backend(log, rung, config, prepared["rig"], use_sigma=use_sigma,
                                            truth=prepared.get("imu_truth"))
            stats[seed] = st
            if failure is not None or len(traj.stamps_s) < 3:
                failed[seed] = failure or "no poses"
                continue
            try:
                ate[seed], truth_ate = _scores(traj, prepared)
            except EvalInputError as exc:      # e.g. a clip too short to align: a failed run, not a lost ladder
                failed[seed] = f"evaluation: {exc}"
                continue
            if truth_ate is not None:
                ate_truth[seed] = truth_ate
        out[rung.name] = {"ate": ate, "ate_truth": ate_truth, "failed": failed, "chain": rung.chain,
                          "order": rung.order,
                          "depth_fraction": float(np.mean([s["depth_fraction"] for s in stats.values()])),
                          "gated_out": int(sum(s["gated_out"] for s in stats.values())),
                          "depth_fallback": int(sum(s["depth_fallback"] for s in stats.values())),
                          "gamma_per_dof_median": float(np.nanmedian([s["gamma_per_dof_median"]
                                                                      for s in stats.values()])),
                          "chi2_noise_scale": float(np.nanmedian([s["chi2_noise_scale"] for s in stats.values()])),
                          **_mean_nees([stats[s] for s in ate]), **_pooled_gate_power(stats.values())}
    return out


def _pooled_gate_power(stats: Iterable[dict[str, Any]]) -> dict[str, float]:
    """The gate's verdicts on known-bad and known-good depths (:mod:`pipeline.gate_power`) pooled over seeds: counts
    summed, fractions of the sums (NaN where there were none)."""
    out: dict[str, float] = {}
    stats = list(stats)
    for kind, frac in (("bad_depth", "passed"), ("flagged_depth", "passed"), ("good_depth", "rejected")):
        n = np.array([s.get(f"gate_{kind}_features", 0.0) for s in stats], dtype=np.float64)
        f = np.array([s.get(f"gate_{kind}_{frac}", np.nan) for s in stats], dtype=np.float64)
        hits = float(np.sum(np.where(n > 0, f * n, 0.0)))
        out[f"gate_{kind}_features"] = float(n.sum())
        out[f"gate_{kind}_{frac}"] = hits / n.sum() if n.sum() > 0 else float("nan")
    return out


def _mean_nees(stats: Sequence[dict[str, Any]]) -> dict[str, float]:
    """The seeds' mean of each run's time-averaged NEES (runs that did not diverge; NaN without truth)."""
    out: dict[str, float] = {}
    for key, name in (("nees_position_mean", "nees_position"), ("nees_orientation_mean", "nees_orientation"),
                      ("nees_tilt_mean", "nees_tilt"), ("nees_yaw_mean", "nees_yaw")):
        v = [s[key] for s in stats if np.isfinite(s.get(key, np.nan))]
        out[name] = float(np.mean(v)) if v else float("nan")
    return out


def ladder_verdict(results: dict[str, dict[str, dict[str, Any]]], rel_tol: float = 0.03
                   ) -> tuple[bool, list[str]]:
    """Is ATE non-increasing as depth error decreases, within the run-to-run spread? (per sequence and chain)

    For every pair of neighbouring rungs of a chain (more accurate ``a``, less accurate ``b``) on every sequence,
    the paired per-seed differences ``ATE_a − ATE_b`` must have a mean ≤ 2 standard errors of that mean plus
    ``rel_tol`` × mean ATE_b (the spread of repeated runs). A failed run on the more accurate rung is a violation.
    A ladder in which no pair could be compared (e.g. one rung, or every run failed) is not monotone: nothing was
    shown, and the violation says so.

    Returns (monotone, list of violations as text).
    """
    bad: list[str] = []
    compared = 0
    for seq_name, res in results.items():
        chains = {name: [(0, a), (1, b)] for name, (a, b) in PAIR_CHECKS.items() if a in res and b in res}
        for name, r in res.items():
            if r["chain"]:
                chains.setdefault(r["chain"], []).append((r["order"], name))
        for members in chains.values():
            members.sort()
            for (_, a), (_, b) in zip(members, members[1:]):
                ra, rb = res[a], res[b]
                if ra["failed"]:
                    bad.append(f"{seq_name}: {a} failed on seeds {sorted(ra['failed'])}")
                    compared += 1
                    continue
                seeds = sorted(set(ra["ate"]) & set(rb["ate"]))
                if not seeds:
                    continue
                compared += 1
                d = np.array([ra["ate"][s] - rb["ate"][s] for s in seeds])
                se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
                mb = float(np.mean([rb["ate"][s] for s in seeds]))
                if float(d.mean()) > 2 * se + rel_tol * mb:
                    bad.append(f"{seq_name}: {a} ({np.mean([ra['ate'][s] for s in seeds]):.4f} m) worse than "
                               f"{b} ({mb:.4f} m): paired Δ {d.mean():+.4f} m > 2·SE {2 * se:.4f} + "
                               f"{rel_tol:.0%} of {b}")
    if compared == 0:
        bad.append("nothing compared: no chain has two rungs with a common successful seed (run more rungs, "
                   "e.g. without --only-rungs)")
    return not bad, bad


def default_config(overrides: dict[str, Any] | None = None) -> MsckfConfig:
    """The pipeline's VIO configuration with optional overrides (a mapping, as a --config YAML holds)."""
    return load_config(overrides or None)


def stereo_reference(sim_dir: Path, config: MsckfConfig, seeds: Iterable[int], prepared: dict[str, Any],
                     max_frames: int | None = None, true_acc_bias: bool = False) -> dict[str, Any]:
    """The stereo front end's ATE on the same sequence and seeds (same evaluation as the rungs); with
    ``true_acc_bias`` fed the IMU without the simulator's accelerometer bias, as :func:`prepare_oracle`."""
    from msckf.errors import FilterDivergedError
    from msckf.vio import Msckf

    sim = SimulatedSequence(Path(sim_dir))
    seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
    imu = seq.imu_array()
    if true_acc_bias:
        imu = imu_without_true_acc_bias(imu, sim.truth)
    ate: dict[int, float] = {}
    ate_truth: dict[int, float] = {}
    failed: dict[int, str] = {}
    gate_stats: list[dict[str, float]] = []
    nees_stats: list[dict[str, float]] = []
    gated_out = 0
    for seed in seeds:
        vio = Msckf(config, seq.calibration, variant="stereo", seed=seed)
        nees = NeesAccumulator(prepared.get("imu_truth"))
        stamps, ps, qs = [], [], []
        pairs: list[tuple[np.ndarray, np.ndarray]] = []
        k = 0
        try:
            for fr in seq.stereo_frames(stop_index=max_frames):
                t = fr.stamp_ns / 1e9
                k = feed_imu_until(vio, imu, k, t)  # keeps feeding until a still start, as a run does
                pose = vio.add_frame(t, to_grey(fr.left_bgr), right_grey=to_grey(fr.right_bgr))
                if vio.last_stats is not None:
                    pairs.append(vio.last_stats.gate_pairs())
                    gated_out += int(vio.last_stats.n_gated_out)
                if pose is not None:
                    stamps.append(pose.stamp_s)
                    ps.append(pose.p_world)
                    qs.append(pose.q_world_imu_xyzw)
                    nees.add(vio.filter, pose.stamp_s)
        except FilterDivergedError as exc:
            failed[seed] = exc.reason
            continue
        finally:
            gate_stats.append(frames_gate_statistics(pairs))
        traj = Trajectory(np.asarray(stamps), np.asarray(ps).reshape(-1, 3), np.asarray(qs).reshape(-1, 4),
                          has_orientation=True)
        try:
            ate[seed], truth_ate = _scores(traj, prepared)
        except EvalInputError as exc:
            failed[seed] = f"evaluation: {exc}"
            continue
        if truth_ate is not None:
            ate_truth[seed] = truth_ate
        nees_stats.append(nees.stats())
    return {"ate": ate, "ate_truth": ate_truth, "failed": failed, "chain": "", "order": 0, "gated_out": gated_out,
            **{k: float(np.nanmedian([g[k] for g in gate_stats])) if gate_stats else float("nan")
               for k in ("gamma_per_dof_median", "chi2_noise_scale")},
            **_mean_nees(nees_stats)}
