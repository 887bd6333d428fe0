"""``agrivio replay RUN_DIR [RUN_DIR ...] --out FILE.rrd``: a rerun recording of one or more runs side by side.

Each RUN_DIR is a run folder (``OUT/<sequence>/<variant>/seed<k>``) of the same sequence. Open the result with
``rerun FILE.rrd`` (the viewer ships with ``rerun-sdk``: ``.venv/bin/rerun FILE.rrd``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.evaluate import evaluate
from eval.records import RunRecord
from eval.trajectory import read_tum
from pipeline.bag_reader import RosarioSequence
from pipeline.commands.compare import options_for
from pipeline.depth import DepthParams
from pipeline.depth_cache import DepthCache
from pipeline.errors import AgrivioError
from pipeline.inpaint_stage import InpaintParams
from pipeline.replay import ReplayFrame, ReplayRun, write_replay
from pipeline.run_job import ESTIMATE_NAME, FRAMES_NAME


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="write a rerun .rrd of runs (images, features, depth, trajectories)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path, help="run folder(s) of one sequence (holding record.json)")
    p.add_argument("--out", type=Path, required=True, help="output .rrd file")
    p.add_argument("--every", type=int, default=1, help="log every N-th frame's images (default 1)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    p.set_defaults(func=run)


def _load_run(run_dir: Path) -> tuple[dict, ReplayRun, np.ndarray | None]:
    rec_path = run_dir / "record.json"
    try:
        record = json.loads(rec_path.read_text())
    except FileNotFoundError:
        raise AgrivioError(f"{rec_path}: no run record here (is this a run folder OUT/<seq>/<variant>/seed<k>?)")
    except json.JSONDecodeError as exc:
        raise AgrivioError(f"{rec_path}: not valid JSON ({exc})") from None
    job = record.get("job") or {}
    opts = job.get("options", job)
    name = f"{record.get('variant')} seed{record.get('seed')}"
    est_path = run_dir / ESTIMATE_NAME
    if not est_path.is_file():
        raise AgrivioError(f"{est_path}: the run left no estimate (status {record.get('status')}: "
                           f"{record.get('failure_reason')})")
    est = read_tum(est_path)
    gt_path = record.get("gt_path")
    positions, quats, ate_m, stamps = est.positions, est.quats_xyzw, np.full(len(est.stamps_s), np.nan), est.stamps_s
    gt_positions = None
    if gt_path and Path(gt_path).is_file() and len(est.stamps_s) >= 3:
        ref = read_tum(gt_path)
        ev = evaluate(ref, est, options_for(RunRecord.from_dict(record, source=str(rec_path))))
        # whole estimate in the GT frame (the alignment is rigid); errors at associated poses
        aligned = ev.alignment.apply(est)
        positions, quats = aligned.positions, aligned.quats_xyzw
        idx = np.searchsorted(est.stamps_s, ev.est_aligned.stamps_s)
        ate_m[np.clip(idx, 0, len(ate_m) - 1)] = np.linalg.norm(ev.est_aligned.positions - ev.ref.positions, axis=1)
        gt_positions = ref.positions
    frames_npz = run_dir / FRAMES_NAME
    features: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    f_stamps, n_feat, f_ms = np.zeros(0), np.zeros(0), np.zeros(0)
    if frames_npz.is_file():
        with np.load(frames_npz) as z:
            f_stamps, n_feat, f_ms = z["stamps_s"], z["n_features"], z["frame_ms"]
            off = z["feature_offsets"]
            for i in range(len(f_stamps)):
                sl = slice(off[i], off[i + 1])
                features[i] = (z["feature_uv"][sl], z["feature_track_length"][sl], z["feature_source"][sl])
    run = ReplayRun(name=name, stamps_s=stamps, positions=positions, quats_xyzw=quats, T_imu_cam=np.eye(4),
                    ate_m=ate_m, frame_stamps_s=f_stamps, n_features=n_feat, frame_ms=f_ms, features=features)
    return {"record": record, "options": opts}, run, gt_positions


def _frames(seq: RosarioSequence, raw: DepthCache | None, filled: DepthCache | None, every: int,
            max_frames: int | None) -> Iterator[ReplayFrame]:
    for frame in seq.stereo_frames(stop_index=max_frames):
        if frame.index % every:
            continue
        d_raw = raw.get(frame.index) if raw is not None else None
        d_fill = filled.get(frame.index) if filled is not None else None
        yield ReplayFrame(frame.index, frame.stamp_ns * 1e-9, frame.left_bgr,
                          d_raw.depth_m if d_raw is not None else None,
                          d_fill.depth_m if d_fill is not None else None,
                          ~d_raw.valid if d_raw is not None else None)


def replay_runs(run_dirs: Sequence[Path], out: Path, every: int = 1, max_frames: int | None = None,
                progress: bool = True) -> Path:
    """Write the recording of ``run_dirs`` (one sequence) to ``out``; returns the path."""
    loaded = [_load_run(Path(d)) for d in run_dirs]
    bags = {info["options"].get("bag") for info, _, _ in loaded}
    if len(bags) != 1 or None in bags:
        raise AgrivioError("replay: the run folders must come from the same sequence (one bag)")
    info = loaded[0][0]["options"]
    seq = RosarioSequence(info["bag"], camchain=info.get("camchain"))
    rig = seq.calibration
    T_imu_cam = np.linalg.inv(rig.T_left_imu)
    runs = []
    for _, run, _ in loaded:
        run.T_imu_cam = T_imu_cam
        runs.append(run)
    gt = next((g for _, _, g in loaded if g is not None), None)
    cache_root = info.get("cache_root")
    raw = filled = None
    if cache_root:
        raw_store = DepthCache(cache_root, seq.identity(), DepthParams())
        raw = raw_store if raw_store.get(0) is not None else None  # complete, or the first --max-frames frames
        methods = {i["record"].get("inpaint_method") for i, _, _ in loaded} - {None}
        method = next(iter(methods)) if methods else info.get("inpaint_method", "paper")
        fill_store = DepthCache(cache_root, seq.identity(), InpaintParams(method=method))
        filled = fill_store if fill_store.get(0) is not None else None
    n = seq.count("/stereo/left/image_raw") if max_frames is None else max_frames
    frames = tqdm(_frames(seq, raw, filled, max(1, every), max_frames), total=n // max(1, every),
                  desc="replay", unit="frame", disable=not progress, leave=False)
    return write_replay(out, runs, frames, gt, rig.left.K, rig.left.size)


def run(args: argparse.Namespace) -> int:
    path = replay_runs(args.runs, args.out, args.every, args.max_frames)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it with: rerun {path}")
    return 0
