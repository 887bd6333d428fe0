"""Peak RSS of streaming a Rosario bag: a long (~5,000 stereo frames) vs a short bag.

Each bag is read in a fresh child process that streams every stereo pair and every IMU, GPS and odometry
sample (touching the pixels); the child reports its peak RSS (``VmHWM``) and its RSS once the bag is open. The
bags are LZ4-compressed, 672×376 bgr8 at 15 Hz with IMU at 142 Hz, GPS 5 Hz, odom + tf_static 10 Hz. Their
images are smooth procedural patterns (so a 5,000-frame bag takes well under 1 GB on disk instead of 7.6 GB); every
image still decodes to its full 756 kB in memory. Bags go to the cache dir and are deleted unless ``--keep``.

    .venv/bin/python benchmarks/bench_reader_memory.py [--long 5000] [--short 100] [--keep] [--json PATH]

``--whole-run PRESET --durations 10 120 [--variants stereo,depth-raw]`` measures a whole run instead: the preset is
simulated at each duration (cached), its depth cache filled, then each variant runs once (seed 0) in a fresh child
process, in the pipeline's own code path (``run_matrix``, serial executor: checks, bag decode, depth read, VIO,
evaluation, record writing); the child reports its peak RSS (``VmHWM``). Flat memory means the peak does not grow
with the duration: the table and the JSON (``growth_mb_per_1000_frames``) give the slope of the peak between the
shortest and the longest duration. Run outputs go to a temporary folder of the system's temp dir (removed).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from eval.variants import ODOMETRY, STEREO
from pipeline.atomic import write_json_atomic
from pipeline.paths import cache_dir


def _status_mb(field: str) -> float:
    """A memory figure of this process from /proc/self/status, MB (VmRSS: now, VmHWM: peak).

    VmHWM belongs to the process image and restarts at exec; ``ru_maxrss`` would not do here, since Linux keeps
    it across fork+exec, so a child would report the parent's peak (e.g. from writing the long bag).
    """
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def write_bag(path: Path, n_frames: int) -> None:
    """A deterministic LZ4 bag in the Rosario layout with compressible images."""
    from pipeline.bag_writer import RosarioBagWriter
    from pipeline.calibration import rig_from_camchain
    from pipeline.paths import ROSARIO_CAMCHAIN

    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    t0 = 1_600_000_000_000_000_000
    yy, xx = np.mgrid[0:376, 0:672]
    cells = ((xx // 16) * 37 + (yy // 16) * 91) % 256  # flat 16x16 cells: LZ4 shrinks them ~100x
    base = np.stack([cells, 255 - cells, cells // 2], axis=-1).astype(np.uint8)
    n_imu = int(n_frames / 15.0 * 142.0)
    events = sorted([(t0 + round(i * 1e9 / 15.0), 0, i) for i in range(n_frames)]
                    + [(t0 + round(i * 1e9 / 142.0), 1, i) for i in range(n_imu)]
                    + [(t0 + round(i * 1e9 / 5.0), 2, i) for i in range(int(n_frames / 3))]
                    + [(t0 + round(i * 1e9 / 10.0), 3, i) for i in range(int(n_frames / 1.5))])
    statics = [("base_link", "imu", np.eye(4)), ("imu", "left", np.eye(4)), ("imu", "right", np.eye(4)),
               ("base_link", "gps", np.eye(4))]
    with RosarioBagWriter(path, compression="lz4", overwrite=True) as w:
        w.set_camera_info(rig)
        for t, kind, i in events:
            if kind == 0:
                left = np.roll(base, 16 * (i % 40), axis=1)
                w.write_stereo(t, left, np.roll(left, -16, axis=1))
            elif kind == 1:
                w.write_imu(t, np.array([0.0, 0.0, 0.01]), np.array([9.5, 0.0, -2.2]))
            elif kind == 2:
                w.write_gps_fix(t, -33.03 + i * 1e-6, -60.88, 25.0)
                w.write_gps_vel(t, 0.5, 0.0)
            else:
                w.write_odom(t, 0.05 * i, 0.0, 0.0, 0.5, 0.0)
                w.write_tf_static(t, statics)


def child(bag: Path) -> None:
    """Stream everything from ``bag``; print a JSON line with RSS figures (MB) and counts."""
    from pipeline.bag_reader import RosarioSequence

    seq = RosarioSequence(bag)
    rss_open = _status_mb("VmRSS")
    t0 = time.perf_counter()
    frames = checksum = 0
    for f in seq.stereo_frames():
        frames += 1
        checksum += int(f.left_bgr[100, 100, 0]) + int(f.right_bgr[200, 300, 2])
    t_frames = time.perf_counter() - t0
    imu = sum(1 for _ in seq.imu())
    gps = sum(1 for _ in seq.gps_fixes())
    odom = sum(1 for _ in seq.odometry())
    peak = _status_mb("VmHWM")
    print(json.dumps({"frames": frames, "imu": imu, "gps": gps, "odom": odom, "rss_after_open_mb": rss_open,
                      "peak_rss_mb": peak, "s_per_frame": t_frames / max(frames, 1), "checksum": checksum}))


def whole_run_child(preset: str, duration_s: float, variant: str, out: Path) -> None:
    """One run of ``variant`` on ``preset`` (caches warm) in this process; print a JSON line with peak RSS (MB)."""
    from pipeline.run_sequence import SequenceSpec, run_matrix

    t0 = time.perf_counter()
    records = run_matrix([SequenceSpec(preset, duration_s=duration_s)], [variant], [0], out, cache_dir(),
                         inpaint_method="telea", executor="serial", progress=False)
    rec = records[0]
    frames = rec.get("frames", (rec.get("extra") or {}).get("frames"))
    print(json.dumps({"status": rec.get("status"), "frames": frames,
                      "wall_s": time.perf_counter() - t0, "peak_rss_mb": _status_mb("VmHWM")}))


def growth_mb_per_1000_frames(rows: list[dict]) -> float:
    """Peak-RSS slope between the shortest and the longest run of ``rows`` (sorted by duration), MB per 1,000
    frames; NaN with fewer than two runs."""
    if len(rows) < 2:
        return float("nan")
    frames = [r["frames"] or 0 for r in rows]
    return (rows[-1]["peak_rss_mb"] - rows[0]["peak_rss_mb"]) / max(frames[-1] - frames[0], 1) * 1000


def whole_run(preset: str, durations: list[float], variants: list[str], json_path: Path) -> None:
    """Peak RSS of a whole run per (duration, variant); table + JSON (see the module docstring)."""
    import tempfile

    from pipeline.run_sequence import SequenceSpec, check_sequence, prepare_sequence

    results = []
    for duration in durations:
        spec = SequenceSpec(preset, duration_s=duration)
        need = [v for v in variants if v != ODOMETRY] or [STEREO]
        prepare_sequence(spec, need, cache_dir(), inpaint_method="telea",
                         checked=check_sequence(spec, need, cache_dir(), progress=True))
        for variant in variants:
            with tempfile.TemporaryDirectory(prefix="agrivio-bench-run-") as tmp:  # run outputs: system temp
                proc = subprocess.run([sys.executable, __file__, "--run-child", preset, str(duration), variant,
                                       tmp], capture_output=True, text=True, check=True)
            res = json.loads(proc.stdout.strip().splitlines()[-1])
            res.update(preset=preset, duration_s=duration, variant=variant)
            results.append(res)
            print(f"{preset} {duration:g} s {variant}: peak RSS {res['peak_rss_mb']:.0f} MB, {res['frames']} frames, "
                  f"{res['wall_s']:.0f} s ({res['status']})", flush=True)
    print(f"\n{'variant':<16} " + " ".join(f"{f'{d:g} s (MB)':>12}" for d in durations)
          + f" {'growth MB/1000 frames':>22}")
    slopes: dict[str, float | None] = {}
    for variant in variants:
        rows = [r for r in results if r["variant"] == variant]
        peaks = [r["peak_rss_mb"] for r in rows]
        slope = growth_mb_per_1000_frames(rows)
        slopes[variant] = None if np.isnan(slope) else slope
        print(f"{variant:<16} " + " ".join(f"{p:>12.0f}" for p in peaks) + f" {slope:>22.1f}")
    write_json_atomic(json_path, {"whole_run": results, "growth_mb_per_1000_frames": slopes})
    print(f"wrote {json_path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--long", type=int, default=5000, help="stereo frames of the long bag")
    ap.add_argument("--short", type=int, default=100, help="stereo frames of the short bag")
    ap.add_argument("--keep", action="store_true", help="keep the generated bags in the cache dir")
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_reader_memory.json")
    ap.add_argument("--whole-run", metavar="PRESET", default=None,
                    help="measure whole runs on this simulator preset instead of the reader (see the description)")
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 120.0],
                    help="simulated seconds of the whole-run sequences (default 10 120)")
    ap.add_argument("--variants", default="stereo,depth-raw", help="whole-run variants (default stereo,depth-raw)")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--run-child", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child)
        return
    if args.run_child:
        preset, duration, variant, out = args.run_child
        whole_run_child(preset, float(duration), variant, Path(out))
        return
    if args.whole_run:
        json_path = args.json if args.json != ap.get_default("json") else \
            cache_dir() / "benchmarks" / "bench_run_memory.json"
        whole_run(args.whole_run, sorted(args.durations), [v.strip() for v in args.variants.split(",") if v.strip()],
                  json_path)
        return

    folder = cache_dir() / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    results = {}
    for label, n in (("short", args.short), ("long", args.long)):
        bag = folder / f"reader_memory_{n}f.bag"
        if not bag.exists():
            t0 = time.perf_counter()
            write_bag(bag, n)
            print(f"wrote {bag} ({bag.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t0:.0f} s")
        proc = subprocess.run([sys.executable, __file__, "--child", str(bag)], capture_output=True, text=True,
                              check=True)
        res = json.loads(proc.stdout.strip().splitlines()[-1])
        res["bag_mb"] = bag.stat().st_size / 1e6
        res["messages"] = res["frames"] * 4 + res["imu"] + 2 * res["gps"] + 2 * res["odom"]
        results[label] = res
        if not args.keep:
            bag.unlink()
    print(f"{'bag':<6} {'frames':>7} {'messages':>9} {'bag MB':>7} {'RSS open MB':>12} {'peak RSS MB':>12} "
          f"{'ms/frame':>9}")
    for label, r in results.items():
        print(f"{label:<6} {r['frames']:>7d} {r['messages']:>9d} {r['bag_mb']:>7.0f} {r['rss_after_open_mb']:>12.1f} "
              f"{r['peak_rss_mb']:>12.1f} {r['s_per_frame'] * 1e3:>9.2f}")
    growth = results["long"]["peak_rss_mb"] - results["short"]["peak_rss_mb"]
    extra_msgs = results["long"]["messages"] - results["short"]["messages"]
    print(f"peak RSS long - short: {growth:+.1f} MB for {extra_msgs} more messages "
          f"({growth * 1e6 / max(extra_msgs, 1):.0f} B/message: rosbags' message index + chunk metadata)")
    results["peak_growth_mb"] = growth
    write_json_atomic(args.json, results)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
