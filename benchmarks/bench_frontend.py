"""Speed of the MSCKF front ends at the Rosario resolution (672×376) and feature counts.

Renders short sequences with the exact plane renderer of the front-end tests (pipeline/plane_scene.py)
through the Rosario rig, feeds gyro samples at 150 Hz, and times ``process()`` per frame (the first frame,
which only detects, is excluded). OpenCV runs single-threaded unless ``--threads`` says otherwise. Each
configuration runs ``--repeats`` times and the run with the lowest CPU-time median is reported (the machine is
shared and noisy; the medians of every repeat are in the JSON). Both wall time and the thread's CPU time
(``time.thread_time``; with one OpenCV thread all work runs on the calling thread) are reported: CPU time is the
figure least disturbed by other jobs on a shared machine.

Scenes:
    wall   a textured wall 4 m ahead; the camera sways sideways/forwards and yaws.
    field  a textured ground 1 m below a camera pitched 15° down, a tree line 40 m ahead, moving forward at
           0.8 m/s with a yaw wobble (Rosario-like flow: large at the bottom, small at the horizon).

The baseline measured in the same loop is one bare ``cv2.calcOpticalFlowPyrLK`` pass (same window, levels and
criteria) of the previous frame's features into the current frame; ``/KLT`` is the front end's CPU median over
that baseline's.

Variants: ``stereo`` (S-MSCKF faithful), ``stereo-reuse`` (``stereo_reuse_disparity=True``), ``depth`` (depth-map
front end on the exact rectified depth), each with the Rosario grid (30/50 per cell, ~600 features), half of it
(15/25, ~300 features) and the EuRoC grid (3/4 per cell, ≤ 80 features) for scale.

Usage: .venv/bin/python benchmarks/bench_frontend.py [--frames 40] [--threads 1] [--repeats 3] [--out PATH]
Prints a table and writes JSON (default: <cache>/benchmarks/bench_frontend.json).
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from msckf.frontend import DepthFrontend, StereoFrontend
from msckf.frontend_config import FrontendConfig
from pipeline.atomic import write_json_atomic
from pipeline.paths import cache_dir
from pipeline.plane_scene import (
    Plane,
    gyro_samples,
    make_texture,
    pose_from,
    rectified_depth,
    render,
    scene_rig,
    stereo_pose,
)
from pipeline.rosario_layout import RATE_CAMERA_HZ

RATE_HZ = RATE_CAMERA_HZ  # the Rosario camera rate
IMU_HZ = 150.0  # the plane scene's gyro rate (not Rosario's 142 Hz: the synthetic scene's own choice)


def _scene(name: str):
    """(planes, pose_fn) of a named scene; pose_fn(t) -> T_cam0_world."""
    tex = make_texture(7, 2048)
    if name == "wall":
        planes = [Plane.wall(4.0, tex, 0.004)]

        def pose_fn(t: float) -> np.ndarray:
            R = Rotation.from_rotvec([0.0, 0.08 * np.sin(1.3 * t), 0.02 * np.sin(0.7 * t)]).as_matrix()
            return pose_from(R, (0.4 * np.sin(0.9 * t), 0.05 * np.sin(2.0 * t), 0.4 * np.sin(0.6 * t)))
        return planes, pose_fn
    if name == "field":
        ground = Plane(np.array([0.0, 1.0, 0.0]), 1.0, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), tex,
                       0.004)
        trees = Plane.wall(40.0, make_texture(8, 2048), 0.05)
        pitch = Rotation.from_rotvec([-np.radians(15.0), 0.0, 0.0])

        def pose_fn(t: float) -> np.ndarray:
            yaw = Rotation.from_rotvec([0.0, 0.05 * np.sin(1.1 * t), 0.0])
            return pose_from((yaw * pitch).as_matrix(), (0.1 * np.sin(0.8 * t), 0.0, 0.8 * t))
        return [ground, trees], pose_fn
    raise ValueError(name)


def _render_sequence(name: str, frames: int):
    rig = scene_rig()
    planes, pose_fn = _scene(name)
    seq = []
    for k in range(frames):
        t = k / RATE_HZ
        T0 = pose_fn(t)
        seq.append((t, render(rig.left, T0, planes), render(rig.right, stereo_pose(rig, T0), planes),
                    rectified_depth(rig, T0, planes)))
    imu = gyro_samples(pose_fn, -0.1, (frames - 1) / RATE_HZ + 0.05, IMU_HZ, rig.T_left_imu[:3, :3])
    return rig, seq, imu


def _run(variant: str, config: FrontendConfig, rig, seq, imu) -> dict:
    cls = DepthFrontend if variant == "depth" else StereoFrontend
    fe = cls(config, rig, rig.T_left_imu, seed=0)
    times, cpu, klt, n_feat, stages = [], [], [], [], {}
    j = 0
    for k, (t, left, right, depth) in enumerate(seq):
        while j < len(imu) and imu[j][0] <= t:
            fe.add_imu(*imu[j])
            j += 1
        valid = np.isfinite(depth)
        c0, t0 = time.thread_time(), time.perf_counter()
        if variant == "depth":
            obs = fe.process(t, left, depth, valid)
        else:
            obs = fe.process(t, left, right)
        dt, dc = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
        if k == 0:
            prev_left, prev_px = left, fe.last_debug.cam0_px
            continue
        times.append(dt)
        cpu.append(dc)
        # Baseline in the same loop: one bare pyramidal-KLT pass (same window/levels/criteria) of the previous
        # frame's features into this frame, no initial flow: the front end does two or three of these.
        c0 = time.thread_time()
        cv2.calcOpticalFlowPyrLK(prev_left, left, prev_px.astype(np.float32).reshape(-1, 1, 2), None,
                                 winSize=(config.patch_size, config.patch_size), maxLevel=config.pyramid_levels,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, config.max_iteration,
                                           config.track_precision))
        klt.append((time.thread_time() - c0) * 1e3)
        prev_left, prev_px = left, fe.last_debug.cam0_px
        n_feat.append(len(obs))
        for stage, ms in fe.last_debug.timings_ms.items():
            stages.setdefault(stage, []).append(ms)
    times = np.array(times)
    return {
        "median_ms": float(np.median(times)), "p95_ms": float(np.percentile(times, 95)),
        "cpu_median_ms": float(np.median(cpu)), "cpu_p95_ms": float(np.percentile(cpu, 95)),
        "klt_pass_cpu_median_ms": float(np.median(klt)),
        "cpu_ratio_to_one_klt_pass": float(np.median(cpu) / np.median(klt)),
        "mean_ms": float(times.mean()), "features_mean": float(np.mean(n_feat)),
        "stage_median_ms": {s: float(np.median(v)) for s, v in stages.items()},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--threads", type=int, default=1, help="cv2.setNumThreads (default 1: one core)")
    ap.add_argument("--scenes", default="wall,field")
    ap.add_argument("--repeats", type=int, default=3,
                    help="runs per configuration; the run with the lowest CPU median is reported (shared machine)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    cv2.setNumThreads(args.threads)
    grids = {"rosario": dict(grid_min_feature_num=30, grid_max_feature_num=50),
             "half": dict(grid_min_feature_num=15, grid_max_feature_num=25),
             "euroc": dict(grid_min_feature_num=3, grid_max_feature_num=4)}
    variants = {"stereo": {}, "stereo-reuse": {"stereo_reuse_disparity": True}, "depth": {}}
    results = []
    print(f"{'scene':6} {'grid':8} {'variant':13} {'feat':>5} {'wall ms':>7} {'p95':>7} {'cpu ms':>7} {'p95':>7}"
          f" {'/KLT':>5}  stages (wall, median ms)")
    for scene in args.scenes.split(","):
        rig, seq, imu = _render_sequence(scene, args.frames)
        for grid, gkw in grids.items():
            for variant, vkw in variants.items():
                cfg = FrontendConfig(**gkw, **vkw)
                runs = [_run(variant, cfg, rig, seq, imu) for _ in range(args.repeats)]
                r = min(runs, key=lambda x: x["cpu_median_ms"])
                r.update(scene=scene, grid=grid, variant=variant,
                         median_ms_all_repeats=[x["median_ms"] for x in runs],
                         cpu_median_ms_all_repeats=[x["cpu_median_ms"] for x in runs])
                results.append(r)
                st = " ".join(f"{s}={v:.2f}" for s, v in r["stage_median_ms"].items())
                print(f"{scene:6} {grid:8} {variant:13} {r['features_mean']:5.0f} {r['median_ms']:7.2f} "
                      f"{r['p95_ms']:7.2f} {r['cpu_median_ms']:7.2f} {r['cpu_p95_ms']:7.2f} "
                      f"{r['cpu_ratio_to_one_klt_pass']:5.2f}  {st}", flush=True)
    out = args.out or cache_dir() / "benchmarks" / "bench_frontend.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, {
        "benchmark": "msckf front end per-frame time", "image": "672x376 Rosario rig", "frames": args.frames,
        "opencv_threads": args.threads, "opencv": cv2.__version__, "numpy": np.__version__,
        "python": platform.python_version(), "machine": platform.processor() or platform.machine(),
        "results": results,
    })
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
