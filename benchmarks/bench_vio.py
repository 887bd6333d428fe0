"""Speed of the whole VIO (front end + back end) per frame on a simulated Rosario sequence, one core.

Runs :class:`msckf.vio.Msckf` with the default config (Rosario grid, 30/50 per cell, ≈ 620 features) over a
simulated preset (``rosario-like-02``, 10 s = 150 frames by default), variants ``stereo`` (left/right KLT) and
``depth-raw`` (left image + the raw SGBM depth of the pipeline's depth cache, with the per-pixel σ of the
pipeline). Every frame is decoded into memory first, so only the VIO is timed: per frame the front end
(``frontend.process``) and the back end (``add_features``) separately, as the calling thread's CPU time
(``time.thread_time``: with one OpenCV thread all work runs on this thread; the figure least disturbed by other
jobs on a shared machine) and as wall time. Frames before the filter initialises are excluded.

Before/after in one run: ``--baseline-src DIR`` names a source tree of another version (e.g.
``git archive <commit> | tar -x -C DIR``); each repeat then runs the current tree and the baseline in turn, each in
its own subprocess (``PYTHONPATH`` set to the tree), and the table gives both and their ratio. The poses' digest
and ATE show whether the outputs are identical.

Usage: .venv/bin/python benchmarks/bench_vio.py [--preset rosario-like-02] [--duration 10] [--repeats 3]
       [--variants stereo,depth-raw] [--baseline-src DIR] [--out PATH]
Prints a table and writes JSON (default: <cache>/benchmarks/bench_vio.json).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, as the pipeline's runs
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if not os.environ.get("AGRIVIO_BENCH_SRC"):
    sys.path.insert(0, str(ROOT))


def _load(preset: str, duration_s: float, variant: str, max_frames: int | None) -> dict:
    """Decode the sequence's frames (and depth) into memory; fills the depth cache when missing."""
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import DepthParams
    from pipeline.depth_cache import DepthCache, depth_stream
    from pipeline.depth_sigma import DepthSigmaModel
    from pipeline.paths import cache_dir
    from pipeline.sources import resolve_source

    import cv2

    root = cache_dir()
    src = resolve_source(preset, duration_s=duration_s, cache_root=root, progress=False)
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    imu_ns, imu = seq.imu_samples()
    frames = []
    store = None
    if variant == "depth-raw":
        for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=root,
                              stop_index=max_frames):
            pass
        store = DepthCache(root, seq.identity(), DepthParams())
    sigma_model = DepthSigmaModel.for_rig(seq.calibration)
    for fr in seq.stereo_frames(stop_index=max_frames, right=variant == "stereo"):
        def grey(bgr: np.ndarray) -> np.ndarray:
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) if bgr.ndim == 3 else bgr
        item = {"stamp_ns": fr.stamp_ns, "left": grey(fr.left_bgr)}
        if variant == "stereo":
            item["right"] = grey(fr.right_bgr)
        else:
            d = store.get(fr.index, grey=False)
            item["depth"] = np.asarray(d.depth_m, dtype=np.float32)
            item["valid"] = np.asarray(d.valid, dtype=bool)
            item["sigma"] = np.asarray(sigma_model.raw_sigma(d.depth_m, d.valid), dtype=np.float32)
        frames.append(item)
    return {"rig": seq.calibration, "imu_ns": imu_ns, "imu": imu, "frames": frames, "gt": src.gt,
            "lever": (src.lever_arms or {}).get("lever_arm_imu")}


def _worker(preset: str, duration_s: float, variant: str, max_frames: int | None) -> dict:
    """One timed pass of the VIO over the sequence (this process's source tree)."""
    import cv2

    import msckf
    from msckf.init import NonStaticStartError
    from msckf.vio import Msckf

    cv2.setNumThreads(1)
    data = _load(preset, duration_s, variant, max_frames)
    vio = Msckf(None, data["rig"], variant="stereo" if variant == "stereo" else "depth", seed=0)
    imu_ns, imu = data["imu_ns"], data["imu"]
    k_imu = 0
    fe_cpu, be_cpu, fe_wall, be_wall, n_feat, stages = [], [], [], [], [], {}
    stamps, poses = [], []
    for fr in data["frames"]:
        k_end = max(int(np.searchsorted(imu_ns, np.int64(fr["stamp_ns"]), side="right")), k_imu)
        for k in range(k_imu, k_end):
            try:
                vio.add_imu(imu_ns[k] / 1e9, imu[k, 0:3], imu[k, 3:6])
            except NonStaticStartError:
                pass
        k_imu = k_end
        t = fr["stamp_ns"] / 1e9
        c0, w0 = time.thread_time(), time.perf_counter()
        if variant == "stereo":
            obs = vio.frontend.process(t, fr["left"], fr["right"])
        else:
            obs = vio.frontend.process(t, fr["left"], fr["depth"], fr["valid"], fr["sigma"], fr["valid"])
        c1, w1 = time.thread_time(), time.perf_counter()
        pose = vio.add_features(obs)
        c2, w2 = time.thread_time(), time.perf_counter()
        if pose is None:
            continue
        fe_cpu.append(c1 - c0)
        be_cpu.append(c2 - c1)
        fe_wall.append(w1 - w0)
        be_wall.append(w2 - w1)
        n_feat.append(len(obs))
        for s, ms in (getattr(vio.last_debug, "timings_ms", None) or {}).items():
            stages.setdefault(s, []).append(ms)
        stamps.append(pose.stamp_s)
        poses.append(np.concatenate([pose.p_world, pose.q_world_imu_xyzw]))
    poses_a = np.asarray(poses, dtype=np.float64)
    digest = hashlib.blake2b(poses_a.tobytes(), digest_size=8).hexdigest()
    ate = None
    if data["gt"] is not None and len(stamps) > 3:
        from eval.evaluate import EvalOptions, evaluate
        from eval.trajectory import Trajectory, read_tum

        est = Trajectory(np.asarray(stamps), poses_a[:, :3], poses_a[:, 3:], has_orientation=True)
        lever = data["lever"]
        opts = EvalOptions(align="se3", max_diff_s=0.02, lever_arm_m=tuple(lever) if lever is not None else None)
        ate = evaluate(read_tum(data["gt"]), est, opts).metrics().get("ate_rmse_m")
    ms = lambda v: 1e3 * np.asarray(v)  # noqa: E731
    total_cpu = ms(fe_cpu) + ms(be_cpu)
    return {
        "source": str(Path(msckf.__file__).resolve().parent.parent), "variant": variant,
        "frames_timed": len(fe_cpu), "features_mean": float(np.mean(n_feat)) if n_feat else 0.0,
        "frontend_cpu_median_ms": float(np.median(ms(fe_cpu))), "backend_cpu_median_ms": float(np.median(ms(be_cpu))),
        "vio_cpu_median_ms": float(np.median(total_cpu)), "vio_cpu_mean_ms": float(np.mean(total_cpu)),
        "vio_cpu_p95_ms": float(np.percentile(total_cpu, 95)),
        "vio_wall_median_ms": float(np.median(ms(fe_wall) + ms(be_wall))),
        "frontend_stage_wall_median_ms": {s: float(np.median(v)) for s, v in stages.items()},
        "poses_digest": digest, "ate_rmse_m": ate,
    }


def _spawn(src: Path | None, preset: str, duration_s: float, variant: str, max_frames: int | None) -> dict:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        env["AGRIVIO_BENCH_SRC"] = str(src)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--preset", preset, "--duration",
           str(duration_s), "--variants", variant]
    if max_frames is not None:
        cmd += ["--max-frames", str(max_frames)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"worker failed ({src or 'current tree'}, {variant}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--variants", default="stereo,depth-raw")
    ap.add_argument("--repeats", type=int, default=3, help="passes per tree; the lowest-CPU-median pass is shown")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--baseline-src", type=Path, default=None,
                    help="source tree of the version to compare against (measured alternately in the same run)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(_worker(args.preset, args.duration, args.variants, args.max_frames)))
        return 0
    trees: dict[str, Path | None] = {"current": None}
    if args.baseline_src is not None:
        trees = {"baseline": args.baseline_src.resolve(), "current": None}
    results = []
    print(f"{'variant':10} {'tree':9} {'feat':>5} {'front ms':>8} {'back ms':>8} {'VIO ms':>7} {'frames/s':>8} "
          f"{'p95':>6} {'wall':>6}  {'ATE m':>8}  poses")
    for variant in args.variants.split(","):
        runs: dict[str, list[dict]] = {name: [] for name in trees}
        for _ in range(args.repeats):
            for name, src in trees.items():  # alternated, so both see the same machine load
                runs[name].append(_spawn(src, args.preset, args.duration, variant, args.max_frames))
        best = {}
        for name, rs in runs.items():
            r = dict(min(rs, key=lambda x: x["vio_cpu_median_ms"]))
            r.update(tree=name, vio_cpu_median_ms_all_repeats=[x["vio_cpu_median_ms"] for x in rs],
                     frontend_cpu_median_ms_all_repeats=[x["frontend_cpu_median_ms"] for x in rs],
                     backend_cpu_median_ms_all_repeats=[x["backend_cpu_median_ms"] for x in rs])
            best[name] = r
            results.append(r)
            ate = f"{r['ate_rmse_m']:.6f}" if r["ate_rmse_m"] is not None else "-"
            print(f"{variant:10} {name:9} {r['features_mean']:5.0f} {r['frontend_cpu_median_ms']:8.2f} "
                  f"{r['backend_cpu_median_ms']:8.2f} {r['vio_cpu_median_ms']:7.2f} "
                  f"{1e3 / r['vio_cpu_median_ms']:8.1f} {r['vio_cpu_p95_ms']:6.1f} {r['vio_wall_median_ms']:6.1f}  "
                  f"{ate:>8}  {r['poses_digest']}", flush=True)
        if "baseline" in best:
            b, c = best["baseline"], best["current"]
            print(f"{variant:10} {'ratio':9} {'':5} {b['frontend_cpu_median_ms'] / c['frontend_cpu_median_ms']:7.2f}x "
                  f"{b['backend_cpu_median_ms'] / c['backend_cpu_median_ms']:7.2f}x "
                  f"{b['vio_cpu_median_ms'] / c['vio_cpu_median_ms']:6.2f}x  (baseline / current; poses "
                  f"{'identical' if b['poses_digest'] == c['poses_digest'] else 'differ'})", flush=True)
    from pipeline.atomic import write_json_atomic
    from pipeline.paths import cache_dir

    out = args.out or cache_dir() / "benchmarks" / "bench_vio.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, {
        "benchmark": "whole VIO (front end + back end) per frame, CPU time of one thread",
        "preset": args.preset, "duration_s": args.duration, "repeats": args.repeats,
        "baseline_src": str(args.baseline_src) if args.baseline_src else None,
        "numpy": np.__version__, "python": platform.python_version(),
        "machine": platform.processor() or platform.machine(), "results": results,
    })
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
