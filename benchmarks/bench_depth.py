"""Benchmark the depth stage at 672×376: rectify, SGBM (left, right), LR check, whole ``compute_depth``.

Prints a table of per-frame medians and p90 (ms) and writes JSON. The baseline is one plain left SGBM call,
measured in the same run; the whole stage is reported as a ratio to it.

    .venv/bin/python benchmarks/bench_depth.py [--frames 60] [--json PATH]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.calibration import rig_from_camchain
from pipeline.depth import DepthParams, compute_depth, disparity_right, disparity_sgbm, left_right_check, rectify_grey
from pipeline.paths import ROSARIO_CAMCHAIN, cache_dir
from pipeline.synthetic_scene import StereoRenderer


def _timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t0) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="timed frames (distinct poses, cycled)")
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_depth.json")
    args = ap.parse_args()

    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    params = DepthParams()
    renderer = StereoRenderer(rig)
    pairs = []
    for i in range(20):  # distinct raw frames (rendering is not timed)
        pose = np.eye(4)
        pose[0, 3] = 0.05 * i
        pairs.append(renderer.render(pose))
    for left, right in pairs[:3]:  # warm-up (matcher creation, caches, rectification maps)
        compute_depth(rig, left, right, params)

    rows: dict[str, list[float]] = {k: [] for k in ("rectify", "sgbm_left", "sgbm_right", "lr_check", "stage")}
    holes = []
    for k in range(args.frames):
        left, right = pairs[k % len(pairs)]
        (lg, rg), t = _timed(rectify_grey, rig, left, right)
        rows["rectify"].append(t)
        dl, t = _timed(disparity_sgbm, lg, rg, params)
        rows["sgbm_left"].append(t)
        dr, t = _timed(disparity_right, lg, rg, params)
        rows["sgbm_right"].append(t)
        _, t = _timed(left_right_check, dl, dr, params.lr_max_diff_px)
        rows["lr_check"].append(t)
        frame, t = _timed(compute_depth, rig, left, right, params)
        rows["stage"].append(t)
        holes.append(frame.hole_ratio)

    base = float(np.median(rows["sgbm_left"]))
    result = {
        "image": "672x376", "frames": args.frames, "params": params.__dict__, "opencv": cv2.__version__,
        "opencv_threads": cv2.getNumThreads(), "cpu": platform.processor() or platform.machine(),
        "hole_ratio_median": float(np.median(holes)),
        "ms": {k: {"median": float(np.median(v)), "p90": float(np.percentile(v, 90))} for k, v in rows.items()},
        "stage_over_single_sgbm": float(np.median(rows["stage"]) / base),
    }
    print(f"depth stage, 672x376, {args.frames} frames, OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    print(f"{'step':<12} {'median ms':>10} {'p90 ms':>8}")
    for k, v in result["ms"].items():
        print(f"{k:<12} {v['median']:>10.1f} {v['p90']:>8.1f}")
    print(f"whole stage / one left SGBM (same run): {result['stage_over_single_sgbm']:.2f}x")
    write_json_atomic(args.json, result)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
