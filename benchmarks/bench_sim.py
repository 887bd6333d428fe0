"""Benchmark the simulator: frames per second and peak memory for sequences of different lengths.

Each configuration runs ``agrivio simulate`` in a fresh subprocess (so that peak RSS is its own), and the wrapper
reports the main process's peak RSS and the largest worker's. Memory must not grow with the duration (frames are
streamed into the bag); time per frame is the quantity to compare (60 s = 900 stereo frames). Baseline: the
rendering of one frame alone, timed inline in this process (no bag, no depth, no IMU), in the same run.

    .venv/bin/python benchmarks/bench_sim.py [--durations 10 30] [--workers 2] [--preset rosario-like-01]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.paths import cache_dir

_WRAPPER = r"""
import json, resource, sys, time
from pipeline.sim import simulate_sequence
t = time.perf_counter()
seq = simulate_sequence(sys.argv[1], sys.argv[2], seed=0, duration_s=float(sys.argv[3]), workers=int(sys.argv[4]),
                        progress=False)
wall = time.perf_counter() - t
print(json.dumps({"wall_s": wall, "frames": seq.n_frames, "bag_mb": seq.bag_path.stat().st_size / 1e6,
                  "rss_main_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "rss_child_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
"""


def _render_baseline(preset: str, n: int = 12) -> dict[str, float]:
    """Inline render time of single frames (median ms), the building block of everything else."""
    from pipeline.calibration import rig_from_camchain
    from pipeline.paths import ROSARIO_CAMCHAIN
    from pipeline.sim.mount import mount_transform
    from pipeline.sim.presets import get_preset
    from pipeline.sim.trajectory import RobotTrajectory
    from pipeline.sim.workers import FrameJob, FrameRenderer

    cfg = get_preset(preset)
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    fr = FrameRenderer(rig, cfg, 0, 0, threads=1)
    traj = RobotTrajectory(cfg, fr.renderer.terrain, mount_transform(rig, cfg.camera.tilt_deg,
                                                                    cfg.camera.imu_position_m), 0)
    times = []
    for k in range(n + 3):
        t = 10.0 + k / 15.0
        t0 = time.perf_counter()
        fr.render(FrameJob(k, t, traj.pose_imu(t), 0.5))
        if k >= 3:
            times.append((time.perf_counter() - t0) * 1e3)
    return {"render_frame_ms_median": float(np.median(times)), "render_frame_ms_p90": float(np.percentile(times, 90))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 30.0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--preset", default="rosario-like-01")
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_sim.json")
    args = ap.parse_args()

    base = _render_baseline(args.preset)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_sim_") as tmp:
        for dur in args.durations:
            out = Path(tmp) / f"d{dur:g}"
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", _WRAPPER, args.preset, str(out), str(dur), str(args.workers)],
                                 capture_output=True, text=True, check=True, env={**os.environ})
            info = json.loads(res.stdout.strip().splitlines()[-1])
            info["duration_s"] = dur
            info["process_s"] = time.perf_counter() - t0
            info["ms_per_frame"] = 1e3 * info["wall_s"] / max(info["frames"], 1)
            info["frames_per_s"] = info["frames"] / info["wall_s"]
            info["projected_60s_s"] = info["ms_per_frame"] * 900 / 1e3
            rows.append(info)
    print(f"simulator benchmark: preset {args.preset}, {args.workers} render worker(s), {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"baseline: one frame rendered inline: median {base['render_frame_ms_median']:.0f} ms "
          f"(p90 {base['render_frame_ms_p90']:.0f} ms)")
    print(f"{'duration':>9} {'frames':>7} {'wall s':>8} {'ms/frame':>9} {'frames/s':>9} {'x baseline':>10} "
          f"{'60 s proj.':>10} {'RSS main':>9} {'RSS worker':>10} {'bag MB':>8}")
    for r in rows:
        print(f"{r['duration_s']:>9g} {r['frames']:>7d} {r['wall_s']:>8.1f} {r['ms_per_frame']:>9.0f} "
              f"{r['frames_per_s']:>9.2f} {r['ms_per_frame'] / base['render_frame_ms_median']:>10.2f} "
              f"{r['projected_60s_s']:>9.0f}s {r['rss_main_mb']:>8.0f}M {r['rss_child_mb']:>9.0f}M "
              f"{r['bag_mb']:>8.0f}")
    write_json_atomic(args.json, {"preset": args.preset, "workers": args.workers, "cpus": os.cpu_count(),
                                  "load_avg_1min": os.getloadavg()[0], "baseline": base, "runs": rows,
                                  "python": platform.python_version()})
    print(f"written: {args.json}")


if __name__ == "__main__":
    main()
