"""The replay stage: gather run folders, their ground truth, depth caches and external estimates into the plain
arrays of :mod:`pipeline.replay` and write the rerun recording (the ``agrivio replay`` command only parses its
arguments and prints the path).

Each run folder (``OUT/<sequence>/<variant>/seed<k>``) is drawn in the ground-truth frame exactly as its ATE was
computed (lever arm, association, alignment of the run record). The depth views read the caches the runs read:
their directories follow from the record's input-key parts (bag identity, depth key, inpainting key), not from
default parameters.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.alignment import apply_lever_arm
from eval.errors import EvalInputError
from eval.evaluate import EvalOptions, Evaluation, evaluate
from eval.records import RunRecord
from eval.trajectory import Trajectory, read_tum
from eval.variants import DEPTH_INPAINTED, ODOMETRY
from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthParams
from pipeline.depth_cache import CacheKey, DepthCache
from pipeline.errors import AgrivioError
from pipeline.external_tracks import ExternalTrack, evaluate_external, load_external
from pipeline.inpaint_stage import InpaintParams
from pipeline.replay import ReplayFrame, ReplayRun, write_replay
from pipeline.replay_features import feature_classes
from pipeline.report_stage import options_for
from pipeline.rosario_layout import TOPIC_LEFT_IMAGE
from pipeline.run_job import ESTIMATE_NAME, FRAMES_NAME


@dataclass
class LoadedRun:
    """A run folder read for the replay: its record, evaluation options, ``run`` (features still with msckf's
    ``DepthSource``), the ground truth it was evaluated against (or None) and its raw per-frame feature log."""

    record: dict
    options: dict
    eval_options: EvalOptions
    run: ReplayRun
    gt: Trajectory | None
    raw_features: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]


def placed_like_ate(ev: Evaluation, est: Trajectory) -> tuple[Trajectory, Trajectory]:
    """The whole estimate ``est`` in the GT frame as its evaluation ``ev`` compared it: at the point the ground
    truth measures (lever arm applied) and as body poses.

    The alignment is fitted on the lever-arm-shifted estimate, so it is applied to the shifted estimate for the
    path compared with the ground truth (applying it to the unshifted one drew paths a lever arm off the GT); the
    same rigid transform gives the body orientations.
    """
    lever = ev.options.lever_arm_m
    shifted = apply_lever_arm(est, np.asarray(lever)) if lever is not None else est
    return ev.alignment.apply(shifted), ev.alignment.apply(est)


def load_run(run_dir: Path) -> LoadedRun:
    """Read one run folder (record, estimate, GT, frame log); AgrivioError naming the file on bad input."""
    rec_path = run_dir / "record.json"
    try:
        record = json.loads(rec_path.read_text())
    except FileNotFoundError:
        raise AgrivioError(f"{rec_path}: no run record here (is this a run folder OUT/<seq>/<variant>/seed<k>?)"
                           ) from None
    except json.JSONDecodeError as exc:
        raise AgrivioError(f"{rec_path}: not valid JSON ({exc})") from None
    opts = record.get("job") or {}  # the run's inputs (bag, camchain, cache root, method), as run_job recorded them
    variant = str(record.get("variant"))
    name = f"{variant} seed{record.get('seed')}"
    est_path = run_dir / ESTIMATE_NAME
    if not est_path.is_file():
        raise AgrivioError(f"{est_path}: the run left no estimate (status {record.get('status')}: "
                           f"{record.get('failure_reason')})")
    try:
        est = read_tum(est_path)
        rr_rec = RunRecord.from_dict(record, source=str(rec_path))
        eval_options = options_for(rr_rec)
    except EvalInputError as exc:
        raise AgrivioError(str(exc)) from None
    kind = "odometry" if variant == ODOMETRY else "VIO"
    run = ReplayRun(name=name, stamps_s=est.stamps_s, positions=est.positions, quats_xyzw=est.quats_xyzw, kind=kind)
    gt = None
    gt_path = record.get("gt_path")
    if gt_path and Path(gt_path).is_file() and len(est.stamps_s) >= 3:
        try:
            gt = read_tum(gt_path)
            ev = evaluate(gt, est, eval_options)
            at_point, body = placed_like_ate(ev, est)
        except EvalInputError as exc:
            raise AgrivioError(f"{est_path}: cannot be aligned with {gt_path}: {exc}") from None
        run.positions, run.quats_xyzw = at_point.positions, body.quats_xyzw
        run.gt_stamps_s, run.gt_errors_m = ev.association.est.stamps_s, ev.ate.errors_m
        recorded = rr_rec.metric("ate_rmse_m")
        run.ate_rmse_m = recorded if recorded is not None else float(ev.ate.trans.rmse)
    raw_features: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]] = {}
    frames_npz = run_dir / FRAMES_NAME
    if frames_npz.is_file():
        with np.load(frames_npz) as z:
            run.frame_stamps_s, run.n_features, run.frame_ms = z["stamps_s"], z["n_features"], z["frame_ms"]
            off = z["feature_offsets"]
            src_all = z["feature_source"]
            measured_all = z["feature_depth_measured"] if "feature_depth_measured" in z.files else None
            if "feature_depth_sigma_m" in z.files:
                with np.errstate(divide="ignore", invalid="ignore"):
                    sigma_rel_all = z["feature_depth_sigma_m"] / z["feature_depth_m"]
            else:
                sigma_rel_all = None
            run.n_with_depth = z["n_depth"] if "n_depth" in z.files else \
                np.array([np.count_nonzero(src_all[off[i]:off[i + 1]]) for i in range(len(off) - 1)])
            for i in range(len(run.frame_stamps_s)):
                sl = slice(off[i], off[i + 1])
                raw_features[i] = (z["feature_uv"][sl], z["feature_track_length"][sl], src_all[sl],
                                   measured_all[sl] if measured_all is not None else None)
                if sigma_rel_all is not None:
                    run.feature_sigma_rel[i] = sigma_rel_all[sl]
    return LoadedRun(record, opts, eval_options, run, gt, raw_features)


def external_run(track: ExternalTrack, gt: Trajectory, options: EvalOptions) -> ReplayRun:
    """An external estimate as a replay run, aligned like agrivio's VIO runs."""
    ev = evaluate_external(track, gt, options)
    at_point, body = placed_like_ate(ev, track.trajectory)
    return ReplayRun(name=track.label, stamps_s=track.trajectory.stamps_s, positions=at_point.positions,
                     quats_xyzw=body.quats_xyzw,
                     gt_stamps_s=ev.association.est.stamps_s, gt_errors_m=ev.ate.errors_m,
                     ate_rmse_m=float(ev.ate.trans.rmse), kind="external")


def _recorded_caches(loaded: Sequence[LoadedRun], bag_identity: str) -> tuple[DepthCache | None, DepthCache | None]:
    """The raw and the inpainted depth cache the runs read, or None where absent (not computed, other cache root).

    Their directories come from the records' input-key parts (``depth``: :meth:`DepthParams.key`, ``inpaint``:
    :meth:`InpaintParams.key`), so a run made with other parameters shows the depth it was given. Where no run
    was inpainted, the inpainted view is the default method's fill of the same raw depth, shown only when the
    runs' depth parameters are the defaults (otherwise there is no way to name that cache: no view).
    """
    roots = {lr.options.get("cache_root") for lr in loaded} - {None}
    if not roots:
        return None, None
    root = next(iter(roots))
    parts = [lr.record.get("input_key_parts") or {} for lr in loaded]
    depth_keys = [p["depth"] for p in parts if p.get("depth")]
    inpaint_keys = [p["inpaint"] for p in parts if p.get("inpaint")]
    default_depth_key = DepthParams().key()
    depth_key = depth_keys[0] if depth_keys else default_depth_key
    if inpaint_keys:
        inpaint_key = inpaint_keys[0]
    elif depth_key == default_depth_key:
        inpaint_key = InpaintParams().key()
    else:
        inpaint_key = None

    def opened(key: str | None) -> DepthCache | None:
        if key is None:
            return None
        store = DepthCache(root, bag_identity, CacheKey(key))
        return store if store.has(0) else None  # complete, or the first --max-frames frames

    return opened(depth_key), opened(inpaint_key)


def _exact_depth_reader(bag: str):
    """The simulator's exact-depth chunks next to a simulated bag, or None (real bags)."""
    from pipeline.sim.export import DepthChunkReader

    folder = Path(bag).parent / "depth"
    return DepthChunkReader(folder) if (folder / "chunk_00000.npz").is_file() else None


def _frames(seq: RosarioSequence, raw: DepthCache | None, filled: DepthCache | None, exact, every: int,
            max_frames: int | None) -> Iterator[ReplayFrame]:
    for frame in seq.stereo_frames(stop_index=max_frames):
        if frame.index % every:
            continue
        d_raw = raw.get(frame.index, grey=False) if raw is not None else None
        d_fill = filled.get(frame.index, grey=False) if filled is not None else None
        truth = None
        if exact is not None:
            try:
                if exact.stamp_ns(frame.index) == frame.stamp_ns:
                    truth = exact.get(frame.index, "depth")
            except (FileNotFoundError, IndexError, KeyError):
                truth = None
        yield ReplayFrame(frame.index, frame.stamp_ns / 1e9, frame.left_bgr,
                          d_raw.depth_m if d_raw is not None else None,
                          d_fill.depth_m if d_fill is not None else None,
                          ~d_raw.valid if d_raw is not None else None, truth)


def _classify(loaded: LoadedRun, raw: DepthCache | None, rig) -> None:
    """Turn the run's msckf depth sources into replay feature classes. A depth-map feature of an inpainted run is
    "inpainted" when the run logged its depth as not measured (``feature_depth_measured``, what the filter was
    told); logs from before that field fall back to the raw cache's hole at the feature's pixel."""
    inpainted = loaded.record.get("variant") == DEPTH_INPAINTED
    out = {}
    for i, (uv, tl, src, measured) in loaded.raw_features.items():
        if not inpainted:
            out[i] = (uv, tl, feature_classes(src, uv))
        elif measured is not None:
            out[i] = (uv, tl, feature_classes(src, uv, measured=measured))
        else:
            d = raw.get(i, grey=False) if raw is not None else None
            valid = d.valid if d is not None else None
            out[i] = (uv, tl, feature_classes(src, uv, valid, rig if valid is not None else None))
    loaded.run.features = out


def replay_runs(run_dirs: Sequence[Path], out: Path, every: int = 1, max_frames: int | None = None,
                progress: bool = True, external: Sequence[str] = ()) -> Path:
    """Write the recording of ``run_dirs`` (one sequence) and ``external`` specs to ``out``; returns the path."""
    if every < 1:
        raise AgrivioError(f"--every {every}: must be ≥ 1")
    tracks = load_external(external)
    loaded = [load_run(Path(d)) for d in run_dirs]
    bags = {lr.options.get("bag") for lr in loaded}
    if len(bags) != 1 or None in bags:
        raise AgrivioError("replay: the run folders must come from the same sequence (one bag)")
    info = loaded[0].options
    seq = RosarioSequence(info["bag"], camchain=info.get("camchain"))
    rig = seq.calibration
    T_imu_cam = np.linalg.inv(rig.T_left_imu)
    for lr in loaded:
        lr.run.T_body_cam = None if lr.run.kind == "odometry" else T_imu_cam
    gt = next((lr.gt for lr in loaded if lr.gt is not None), None)
    raw, filled = _recorded_caches(loaded, seq.identity())
    for lr in loaded:
        _classify(lr, raw, rig)
    runs = [lr.run for lr in loaded]
    if tracks:
        if gt is None:
            raise AgrivioError("replay --external: none of the run folders has a ground truth to evaluate against")
        vio = next((lr for lr in loaded if lr.run.kind == "VIO"), loaded[0])
        for track in tracks:
            ext = external_run(track, gt, vio.eval_options)
            ext.T_body_cam = T_imu_cam
            runs.append(ext)
    n = seq.count(TOPIC_LEFT_IMAGE) if max_frames is None else max_frames
    exact = _exact_depth_reader(info["bag"])
    notes = [f"Images of every {every}-th frame (--every {every}); poses and metrics at full rate."] if every > 1 \
        else []
    frames = tqdm(_frames(seq, raw, filled, exact, every, max_frames), total=-(-n // every),
                  desc="replay", unit="frame", disable=not progress, leave=False)
    gt_positions = gt.positions if gt is not None else None
    return write_replay(out, runs, frames, gt_positions, rig.left.K, rig.left.size, notes=notes)


__all__ = ["LoadedRun", "external_run", "load_run", "placed_like_ate", "replay_runs"]
