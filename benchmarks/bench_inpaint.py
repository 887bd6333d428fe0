"""Speed and quality of the depth-inpainting methods on 672×376 frames (prints tables, writes JSON).

Usage: ``python benchmarks/bench_inpaint.py [--frames N] [--speed-frames N] [--repeats R] [--methods a,b]
[--sources] [--no-sim] [--out FILE]``

Three parts, every method measured in the same run with Telea as the base of the time ratios:

1. **15–25 % holes** (speed): procedural field depth (``inpaint.synthetic.field_depth``) with seeded masks at 15,
   20 and 25 % (mixed blobs / stripes / specks, and blobs); ``repeats`` runs per frame; median ms per frame.
2. **Simulator frames, ≈ 50 % holes** (speed and quality): ``pipeline.inpaint_bench.sim_frames`` — exact rendered
   depth of the three Rosario-like presets with their real StereoSGBM invalid masks (45–58 % holes), ``--frames``
   of them (default 12, 4 per preset). Median ms per frame; hole RMSE / PSNR / SSIM (``eval.depth_metrics``, peak
   20 m, ground truth ≤ 20 m) averaged per preset and over all frames.
3. ``--sources``: quality per synthetic source — procedural fields, procedural object scenes (boxes, poles,
   plates), procedural rooms / corridors (planes, steps, door openings, posts), and ``stereo-noise`` (the three kinds
   in turn, with the known pixels measured as a stereo matcher would: sub-pixel disparity noise and 1/16 px
   quantisation, ``inpaint.synthetic.stereo_noise``; scored against the exact depth) — random masks 15–40 % and
   stereo-occlusion masks; other seeds than training.

Each method call is timed on one thread of work (the torch calls of ``paper`` pin one thread) as wall-clock time and
as the process's CPU time (``time.process_time``: all threads, less sensitive to other jobs on a shared machine);
machine load is not controlled: compare ratios measured in the same run, not absolute times across runs.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from eval.depth_metrics import depth_metrics
from inpaint import inpaint
from inpaint.masks import occlusion_mask, random_mask
from inpaint.synthetic import field_depth, object_depth, room_depth, stereo_noise
from pipeline.atomic import write_json_atomic
from pipeline.paths import cache_dir

ALL = ("paper", "paper-greedy", "telea", "ns", "biharmonic", "ipbasic")
PEAK = MAX_DEPTH = 20.0


def _parse_methods(spec: str) -> list[str]:
    return [m for m in spec.split(",") if m]


def _call(method: str, depth: np.ndarray, mask: np.ndarray, guide=None) -> tuple[np.ndarray, float, float]:
    """(output, wall seconds, CPU seconds of the process)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = inpaint(depth, mask, guide, method=method)
    return out, time.perf_counter() - t0, time.process_time() - c0


def speed_small_holes(methods: list[str], n_frames: int, repeats: int) -> dict:
    ratios = (0.15, 0.20, 0.25)
    cases = []
    for i in range(n_frames):
        f = field_depth(376, 672, seed=500 + i)
        mask = random_mask(f.depth.shape, ratios[i % 3], "mixed" if i % 2 == 0 else "blobs", seed=600 + i)
        cases.append((np.where(mask, np.nan, f.depth).astype(np.float32), mask))
    times: dict[str, list[float]] = {m: [] for m in methods}
    cpu: dict[str, list[float]] = {m: [] for m in methods}
    for depth, mask in cases:
        for _ in range(repeats):
            for m in methods:
                _, wall, c = _call(m, depth, mask)
                times[m].append(wall)
                cpu[m].append(c)
    return {"hole_ratios": [float(m.mean()) for _, m in cases], "runs_s": times, "cpu_s": cpu,
            "median_ms": {m: 1000 * float(np.median(v)) for m, v in times.items()},
            "median_cpu_ms": {m: 1000 * float(np.median(v)) for m, v in cpu.items()}}


def _metrics(out, gt, valid, mask) -> dict:
    ok = valid & (gt <= MAX_DEPTH)
    m = depth_metrics(out, gt, mask, valid=ok, peak=PEAK)
    return {"rmse": m.rmse_hole, "psnr": m.psnr_hole, "ssim": m.ssim_hole}


def sim_part(methods: list[str], n_frames: int) -> dict:
    from pipeline.inpaint_bench import sim_frames

    frames = sim_frames(n_frames, seed=0)
    per: dict[str, dict] = {m: {"seconds": [], "cpu_seconds": [], "frames": []} for m in methods}
    for fr in frames:
        raw = np.where(fr.mask, np.nan, fr.depth_gt).astype(np.float32)
        preset = fr.source.split()[1]
        for m in methods:
            out, sec, c = _call(m, raw, fr.mask, fr.guide)
            per[m]["seconds"].append(sec)
            per[m]["cpu_seconds"].append(c)
            per[m]["frames"].append(dict(_metrics(out, fr.depth_gt, fr.valid, fr.mask), preset=preset,
                                         name=fr.name, hole_ratio=float(fr.mask.mean())))
    summary = {}
    presets = sorted({f["preset"] for f in per[methods[0]]["frames"]})
    for m in methods:
        rows = per[m]["frames"]
        s = {"median_ms": 1000 * float(np.median(per[m]["seconds"])),
             "median_cpu_ms": 1000 * float(np.median(per[m]["cpu_seconds"]))}
        for key in ("rmse", "psnr", "ssim"):
            s[key] = float(np.mean([r[key] for r in rows]))
            for p in presets:
                s[f"{key}:{p}"] = float(np.mean([r[key] for r in rows if r["preset"] == p]))
        summary[m] = s
    return {"presets": presets, "hole_ratios": [float(f.mask.mean()) for f in frames], "summary": summary,
            "per_frame": per}


SOURCES = {"field": lambda s: field_depth(376, 672, seed=700 + s),
           "objects": lambda s: object_depth(376, 672, seed=800 + s),
           "room": lambda s: room_depth(376, 672, seed=1700 + s),
           "stereo-noise": lambda s: (field_depth, object_depth, room_depth)[s % 3](376, 672, seed=1900 + s)}


def sources_part(methods: list[str], n_per_source: int) -> dict:
    out: dict[str, dict] = {}
    for src, gen in SOURCES.items():
        rows: dict[str, list] = {m: [] for m in methods}
        for i in range(n_per_source):
            f = gen(i)
            if i % 3 == 2:
                mask = occlusion_mask(f.depth, 351.06 * 0.1187, 64)
            else:
                mask = random_mask(f.depth.shape, (0.15, 0.40)[i % 3], "mixed" if i % 2 == 0 else "blobs",
                                   seed=900 + i)
            measured = stereo_noise(f.depth, seed=2000 + i) if src == "stereo-noise" else f.depth
            raw = np.where(mask, np.nan, measured).astype(np.float32)
            gt = np.where(f.valid, f.depth, np.nan).astype(np.float32)
            for m in methods:
                res, sec, c = _call(m, raw, mask)
                rows[m].append(dict(_metrics(res, gt, f.valid, mask), seconds=sec, cpu_seconds=c))
        out[src] = {m: {k: float(np.mean([r[k] for r in v])) for k in ("rmse", "psnr", "ssim", "seconds",
                                                                        "cpu_seconds")}
                    for m, v in rows.items()}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12, help="simulator frames (≈50 %% holes), 4 per preset")
    ap.add_argument("--speed-frames", type=int, default=4, help="procedural frames at 15–25 %% holes")
    ap.add_argument("--repeats", type=int, default=2, help="runs per frame of the 15–25 %% part")
    ap.add_argument("--methods", default=",".join(ALL))
    ap.add_argument("--sources", action="store_true", help="also the per-synthetic-source quality table")
    ap.add_argument("--source-frames", type=int, default=6, help="frames per synthetic source (--sources)")
    ap.add_argument("--no-sim", action="store_true", help="skip the simulator part")
    ap.add_argument("--out", type=Path, default=cache_dir() / "benchmarks" / "bench_inpaint.json")
    args = ap.parse_args(argv)
    methods = _parse_methods(args.methods)
    if "telea" not in methods:
        methods.append("telea")  # the base of the time ratios
    for m in methods:  # compile / load once outside the timings
        f = field_depth(64, 96, seed=1)
        mk = random_mask(f.depth.shape, 0.3, "blobs", seed=1)
        inpaint(np.where(mk, np.nan, f.depth).astype(np.float32), mk, method=m)
    result: dict = {"methods": methods, "cpu_count": os.cpu_count(), "platform": platform.platform()}
    small = speed_small_holes(methods, args.speed_frames, args.repeats)
    result["small_holes"] = small
    base, cbase = small["median_ms"]["telea"], small["median_cpu_ms"]["telea"]
    print(f"\n15–25 % holes, 672×376, {args.speed_frames} procedural frames × {args.repeats} repeats")
    print(f"{'method':14s} {'median ms':>10s} {'× Telea':>8s} {'CPU ms':>8s} {'× Telea':>8s}")
    for m in methods:
        print(f"{m:14s} {small['median_ms'][m]:10.1f} {small['median_ms'][m] / base:8.2f} "
              f"{small['median_cpu_ms'][m]:8.1f} {small['median_cpu_ms'][m] / cbase:8.2f}")
    if not args.no_sim:
        sim = sim_part(methods, args.frames)
        result["sim"] = sim
        s = sim["summary"]
        base, cbase = s["telea"]["median_ms"], s["telea"]["median_cpu_ms"]
        hr = sim["hole_ratios"]
        print(f"\nsimulator frames, real SGBM masks ({len(hr)} frames, "
              f"holes {100 * min(hr):.0f}–{100 * max(hr):.0f} %, "
              f"median {100 * float(np.median(hr)):.0f} %); hole metrics, GT ≤ {MAX_DEPTH:g} m, PSNR peak {PEAK:g} m")
        head = (f"{'method':14s} {'median ms':>10s} {'× Telea':>8s} {'CPU ms':>8s} {'× Telea':>8s} {'RMSE m':>8s} "
                f"{'PSNR':>7s} {'SSIM':>7s}")
        for p in sim["presets"]:
            head += f" | {p[-2:]}: {'RMSE':>6s} {'PSNR':>6s} {'SSIM':>6s}"
        print(head)
        for m in methods:
            r = s[m]
            line = (f"{m:14s} {r['median_ms']:10.1f} {r['median_ms'] / base:8.2f} {r['median_cpu_ms']:8.1f} "
                    f"{r['median_cpu_ms'] / cbase:8.2f} {r['rmse']:8.3f} {r['psnr']:7.2f} {r['ssim']:7.4f}")
            for p in sim["presets"]:
                line += f" |     {r['rmse:' + p]:6.3f} {r['psnr:' + p]:6.2f} {r['ssim:' + p]:6.4f}"
            print(line)
    if args.sources:
        src = sources_part(methods, args.source_frames)
        result["sources"] = src
        for name, tab in src.items():
            print(f"\nsynthetic source '{name}' ({args.source_frames} frames, masks 15/40 % random + stereo occlusion)")
            print(f"{'method':14s} {'mean s':>8s} {'CPU s':>8s} {'RMSE m':>8s} {'PSNR':>7s} {'SSIM':>7s}")
            for m in methods:
                r = tab[m]
                print(f"{m:14s} {r['seconds']:8.3f} {r['cpu_seconds']:8.3f} {r['rmse']:8.3f} {r['psnr']:7.2f} "
                      f"{r['ssim']:7.4f}")
    result["load_avg"] = os.getloadavg()
    write_json_atomic(args.out, result)
    print(f"\nwritten: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
