"""Speed of the whole VIO (front end + back end) per frame on a simulated Rosario sequence, one core.

Runs :class:`msckf.vio.Msckf` with the default config (Rosario grid, 30/50 per cell, ≈ 620 features) over a
simulated preset (``rosario-like-02``, 10 s = 150 frames by default), variants ``stereo`` (left/right KLT) and
``depth-raw`` (left image + the raw SGBM depth of the pipeline's depth cache, with the per-pixel σ of the
pipeline). Every frame is decoded into memory first, so only the VIO is timed: per frame the front end
(``frontend.process``) and the back end (``add_features``) separately, as the calling thread's CPU time
(``time.thread_time``: with one OpenCV thread all work runs on this thread; the figure least disturbed by other
jobs on a shared machine) and as wall time. Frames before the filter initialises are excluded.

Before/after in one run: ``--baseline-src DIR`` names a source tree of another version (e.g.
``git archive <commit> | tar -x -C DIR``). Its ``msckf`` package is imported into this process next to this tree's
(each under the usual module names, swapped into ``sys.modules`` around its calls), and in every pass both VIOs
take each frame in turn, the order alternating per frame: both see the same machine load, and the speed-up is
the median over frames of the paired per-frame ratio (robust on a shared, noisy machine). The poses' digest and
the ATE show whether the outputs are identical. Only ``msckf`` is swapped; ``pipeline`` (data loading) and
``eval`` are this tree's.

Usage: .venv/bin/python benchmarks/bench_vio.py [--preset rosario-like-02] [--duration 10] [--repeats 3]
       [--variants stereo,depth-raw] [--baseline-src DIR] [--config JSON] [--baseline-config JSON] [--out PATH]
Prints a table and writes JSON (default: <cache>/benchmarks/bench_vio.json).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import platform
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, as the pipeline's runs
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from eval.variants import DEPTH_RAW, STEREO  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def _load(preset: str, duration_s: float, variant: str, max_frames: int | None) -> dict:
    """Decode the sequence's frames (and depth) into memory; fills the depth cache when missing."""
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import DepthParams, to_grey
    from pipeline.depth_cache import DepthCache, depth_stream
    from pipeline.depth_sigma import DepthSigmaModel
    from pipeline.paths import cache_dir
    from pipeline.sources import resolve_source

    root = cache_dir()
    src = resolve_source(preset, duration_s=duration_s, cache_root=root, progress=False)
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    imu_ns, imu = seq.imu_samples()
    frames = []
    store = None
    if variant == DEPTH_RAW:
        for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=root,
                              stop_index=max_frames):
            pass
        store = DepthCache(root, seq.identity(), DepthParams())
    sigma_model = DepthSigmaModel.for_rig(seq.calibration)
    for fr in seq.stereo_frames(stop_index=max_frames, right=variant == STEREO):
        item = {"stamp_ns": fr.stamp_ns, "left": to_grey(fr.left_bgr)}
        if variant == STEREO:
            item["right"] = to_grey(fr.right_bgr)
        else:
            d = store.get(fr.index, grey=False)
            item["depth"] = np.asarray(d.depth_m, dtype=np.float32)
            item["valid"] = np.asarray(d.valid, dtype=bool)
            item["sigma"] = np.asarray(sigma_model.raw_sigma(d.depth_m, d.valid), dtype=np.float32)
        frames.append(item)
    return {"rig": seq.calibration, "imu_ns": imu_ns, "imu": imu, "frames": frames, "gt": src.gt,
            "lever": (src.lever_arms or {}).get("lever_arm_imu")}


_MSCKF_MODULES = ("msckf", "msckf.camera", "msckf.config", "msckf.errors", "msckf.types", "msckf.rotation",
                  "msckf.state", "msckf.frontend_config", "msckf.frontend_grid", "msckf.frontend_geometry",
                  "msckf.frontend_depth", "msckf.frontend", "msckf.triangulation", "msckf.update",
                  "msckf.propagation", "msckf.augmentation", "msckf.init", "msckf.filter", "msckf.vio")


def _own_modules() -> dict:
    return {k: m for k, m in sys.modules.items() if k == "msckf" or k.startswith("msckf.")}


def _import_tree(src: Path | None) -> dict:
    """The ``msckf`` package of a source tree (None: this tree), imported under its usual names and then taken
    out of ``sys.modules``, so that two versions live in one process; :func:`_using` puts one back for a call."""
    import importlib

    saved = _own_modules()
    for k in saved:
        del sys.modules[k]
    path = str(src if src is not None else ROOT)
    sys.path.insert(0, path)
    try:
        for name in _MSCKF_MODULES:
            try:
                importlib.import_module(name)
            except ModuleNotFoundError:
                pass  # a module this version does not have
        mods = _own_modules()
    finally:
        sys.path.remove(path)
        for k in _own_modules():
            del sys.modules[k]
        sys.modules.update(saved)
    return mods


class _Using:
    """Context: ``sys.modules`` holds the given tree's ``msckf`` modules (for lazy imports inside calls)."""

    def __init__(self, mods: dict) -> None:
        self.mods = mods

    def __enter__(self) -> None:
        self.saved = _own_modules()
        for k in self.saved:
            del sys.modules[k]
        sys.modules.update(self.mods)

    def __exit__(self, *exc: object) -> None:
        for k in _own_modules():
            del sys.modules[k]
        sys.modules.update(self.saved)


class _Pass:
    """One VIO instance of one tree over the sequence, with its per-frame timings and poses."""

    def __init__(self, name: str, mods: dict, rig_pickle: bytes, variant: str, config: dict | None) -> None:
        self.name, self.mods, self.variant = name, mods, variant
        with _Using(mods):
            rig = pickle.loads(rig_pickle)  # an instance of this tree's StereoRig class
            self.vio = mods["msckf.vio"].Msckf(config, rig, variant="stereo" if variant == STEREO else "depth",
                                               seed=0)
        self.non_static = mods["msckf.init"].NonStaticStartError
        self.fe_cpu: list[float] = []
        self.be_cpu: list[float] = []
        self.wall: list[float] = []
        self.n_feat: list[int] = []
        self.stages: dict[str, list[float]] = {}
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []
        self.tracks = hashlib.blake2b(digest_size=8)   # every frame's published features (front-end output)

    def imu(self, t_s: float, gyro: np.ndarray, accel: np.ndarray) -> None:
        with _Using(self.mods):
            try:
                self.vio.add_imu(t_s, gyro, accel)
            except self.non_static:
                pass

    def frame(self, fr: dict) -> None:
        t = fr["stamp_ns"] / 1e9
        with _Using(self.mods):
            c0, w0 = time.thread_time(), time.perf_counter()
            if self.variant == STEREO:
                obs = self.vio.frontend.process(t, fr["left"], fr["right"])
            else:
                obs = self.vio.frontend.process(t, fr["left"], fr["depth"], fr["valid"], fr["sigma"], fr["valid"])
            c1 = time.thread_time()
            pose = self.vio.add_features(obs)
            c2, w2 = time.thread_time(), time.perf_counter()
        for a in (obs.ids, obs.cam0_xy, obs.cam1_xy, obs.depth_m, obs.source, obs.track_length):
            self.tracks.update(np.ascontiguousarray(a).tobytes())
        if pose is None:
            return
        self.fe_cpu.append(1e3 * (c1 - c0))
        self.be_cpu.append(1e3 * (c2 - c1))
        self.wall.append(1e3 * (w2 - w0))
        self.n_feat.append(len(obs))
        for s, ms in (getattr(self.vio.last_debug, "timings_ms", None) or {}).items():
            self.stages.setdefault(s, []).append(ms)
        self.stamps.append(pose.stamp_s)
        self.poses.append(np.concatenate([pose.p_world, pose.q_world_imu_xyzw]))

    def summary(self, gt: Path | None, lever) -> dict:
        poses = np.asarray(self.poses, dtype=np.float64)
        ate = None
        if gt is not None and len(self.stamps) > 3:
            from eval.evaluate import EvalOptions, evaluate
            from eval.trajectory import Trajectory, read_tum

            est = Trajectory(np.asarray(self.stamps), poses[:, :3], poses[:, 3:], has_orientation=True)
            opts = EvalOptions(align="se3", max_diff_s=0.02, lever_arm_m=lever)
            ate = evaluate(read_tum(gt), est, opts).metrics().get("ate_rmse_m")
        total = np.asarray(self.fe_cpu) + np.asarray(self.be_cpu)
        return {
            "tree": self.name, "source": str(Path(self.mods["msckf"].__file__).resolve().parent.parent),
            "variant": self.variant, "frames_timed": len(total),
            "features_mean": float(np.mean(self.n_feat)) if self.n_feat else 0.0,
            "frontend_cpu_median_ms": float(np.median(self.fe_cpu)),
            "backend_cpu_median_ms": float(np.median(self.be_cpu)),
            "vio_cpu_median_ms": float(np.median(total)), "vio_cpu_mean_ms": float(np.mean(total)),
            "vio_cpu_p95_ms": float(np.percentile(total, 95)), "vio_wall_median_ms": float(np.median(self.wall)),
            "frontend_stage_wall_median_ms": {s: float(np.median(v)) for s, v in self.stages.items()},
            "poses_digest": hashlib.blake2b(poses.tobytes(), digest_size=8).hexdigest(),
            "tracks_digest": self.tracks.hexdigest(), "ate_rmse_m": ate,
        }


def _run_variant(trees: dict, configs: dict, preset: str, duration_s: float, variant: str, max_frames: int | None,
                 repeats: int) -> list[list[dict]]:
    """``repeats`` passes; in each, every tree's VIO takes each frame in turn (the order alternates per frame),
    so that all trees see the same machine load. Returns, per pass, one summary per tree plus paired ratios."""
    data = _load(preset, duration_s, variant, max_frames)
    rig_pickle = pickle.dumps(data["rig"])
    lever = data["lever"]
    lever = tuple(float(x) for x in np.asarray(lever).reshape(3)) if lever is not None else None
    out = []
    for _ in range(repeats):
        passes = [_Pass(name, mods, rig_pickle, variant, configs[name]) for name, mods in trees.items()]
        imu_ns, imu = data["imu_ns"], data["imu"]
        k_imu = 0
        for i, fr in enumerate(data["frames"]):
            k_end = max(int(np.searchsorted(imu_ns, np.int64(fr["stamp_ns"]), side="right")), k_imu)
            for k in range(k_imu, k_end):
                for p in passes:
                    p.imu(imu_ns[k] / 1e9, imu[k, 0:3], imu[k, 3:6])
            k_imu = k_end
            for p in (passes if i % 2 == 0 else passes[::-1]):
                p.frame(fr)
        res = [p.summary(data["gt"], lever) for p in passes]
        if len(passes) == 2 and len(passes[0].fe_cpu) == len(passes[1].fe_cpu):
            b, c = passes
            tb = np.asarray(b.fe_cpu) + np.asarray(b.be_cpu)
            tc = np.asarray(c.fe_cpu) + np.asarray(c.be_cpu)
            for r in res:
                r["paired_median_ratio_baseline_over_current"] = {
                    "frontend": float(np.median(np.asarray(b.fe_cpu) / np.asarray(c.fe_cpu))),
                    "backend": float(np.median(np.asarray(b.be_cpu) / np.asarray(c.be_cpu))),
                    "vio": float(np.median(tb / tc)),
                    "vio_total": float(tb.sum() / tc.sum()),
                    "backend_total": float(np.sum(b.be_cpu) / np.sum(c.be_cpu))}
        out.append(res)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--variants", default="stereo,depth-raw")
    ap.add_argument("--repeats", type=int, default=3, help="passes; the pass with the lowest current-tree CPU median "
                                                             "is shown (all are in the JSON)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--baseline-src", type=Path, default=None,
                    help="source tree of the version to compare against (its msckf runs in this process, frame by "
                         "frame alternately with this tree's)")
    ap.add_argument("--config", type=json.loads, default=None,
                    help="MSCKF overrides (JSON) for this tree, e.g. "
                         "'{\"frontend\": {\"stereo_reuse_disparity\": true}}'")
    ap.add_argument("--baseline-config", type=json.loads, default=None,
                    help="MSCKF overrides (JSON) for the baseline (with --baseline-src . : an option A/B in one tree)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    trees = {}
    if args.baseline_src is not None:
        trees["baseline"] = _import_tree(args.baseline_src.resolve())
    trees["current"] = _import_tree(None)
    results = []
    print(f"{'variant':10} {'tree':9} {'feat':>5} {'front ms':>8} {'back ms':>8} {'VIO ms':>7} {'frames/s':>8} "
          f"{'p95':>6} {'wall':>6}  {'ATE m':>8}  poses / tracks digest")
    for variant in args.variants.split(","):
        configs = {"baseline": args.baseline_config, "current": args.config}
        passes = _run_variant(trees, configs, args.preset, args.duration, variant, args.max_frames, args.repeats)
        best = min(passes, key=lambda res: res[-1]["vio_cpu_median_ms"])
        for res in passes:
            for r in res:
                r["shown"] = res is best
            results.extend(res)
        for r in best:
            ate = f"{r['ate_rmse_m']:.6f}" if r["ate_rmse_m"] is not None else "-"
            print(f"{variant:10} {r['tree']:9} {r['features_mean']:5.0f} {r['frontend_cpu_median_ms']:8.2f} "
                  f"{r['backend_cpu_median_ms']:8.2f} {r['vio_cpu_median_ms']:7.2f} "
                  f"{1e3 / r['vio_cpu_median_ms']:8.1f} {r['vio_cpu_p95_ms']:6.1f} {r['vio_wall_median_ms']:6.1f}  "
                  f"{ate:>8}  {r['poses_digest']} / {r['tracks_digest']}", flush=True)
        if len(best) == 2:
            b, c = best
            ratios = [res[0]["paired_median_ratio_baseline_over_current"] for res in passes
                      if "paired_median_ratio_baseline_over_current" in res[0]]
            if ratios:
                med = {k: float(np.median([x[k] for x in ratios]))
                       for k in ("frontend", "backend", "vio", "vio_total", "backend_total")}
                print(f"{variant:10} {'speed-up':9} {'':5} {med['frontend']:7.2f}x {med['backend']:7.2f}x "
                      f"{med['vio']:6.2f}x  (median over frames and passes of baseline/current, paired per frame; "
                      f"whole-sequence CPU: back end {med['backend_total']:.2f}x, VIO {med['vio_total']:.2f}x; "
                      f"tracks {'identical' if b['tracks_digest'] == c['tracks_digest'] else 'differ'}, poses "
                      f"{'identical' if b['poses_digest'] == c['poses_digest'] else 'differ'})", flush=True)
    from pipeline.atomic import write_json_atomic
    from pipeline.paths import cache_dir

    out = args.out or cache_dir() / "benchmarks" / "bench_vio.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, {
        "benchmark": "whole VIO (front end + back end) per frame, CPU time of one thread",
        "preset": args.preset, "duration_s": args.duration, "repeats": args.repeats,
        "baseline_src": str(args.baseline_src) if args.baseline_src else None,
        "config": args.config, "baseline_config": args.baseline_config,
        "numpy": np.__version__, "opencv": cv2.__version__, "python": platform.python_version(),
        "machine": platform.processor() or platform.machine(), "results": results,
    })
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
