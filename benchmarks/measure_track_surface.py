"""How far is the point a KLT track follows from the surface a perfect depth map shows at its pixel?

The depth front end attaches to a tracked feature the depth a map gives at the feature's pixel. The filter then
treats that depth as the depth of the 3-D point the track follows. On simulated sequences both are known: the
track's point is triangulated from its pixels with the simulator's *true* poses (pipeline/depth_oracle.py,
``true_track_depths``: only tracks that are a consistent 3-D point), and the simulator's *exact* depth map gives
the surface at every pixel. For every observation whose exact-map reading the front end accepts (its own
invalid / edge / range rules), this prints the relative difference ``Z_track / Z_map − 1`` with the map read

* ``bilinear`` at the pixel (the front end's default ``depth_sampling``),
* ``patch``: ``1 / mean(1 / Z)`` over the KLT window (``depth_sampling: patch``; a KLT flow is an average over
  its window and flow scales with 1/Z),
* ``patch, gradient-weighted``: the same mean weighted by the rectified left image's squared gradient (the
  weights Lucas–Kanade gives a pixel; not a front-end option: it needs the rectified image),

as median, robust σ (1.4826 · MAD), the share beyond 2 % and 5 %, and how much of it is shared along a track
(the robust σ of the per-track means against that of the deviations from them). Also the same for the raw SGBM
map, against the track's point. Prints a table, writes JSON (default
<cache>/benchmarks/measure_track_surface.json). One seed's tracks per preset (10 s by default).

    .venv/bin/python benchmarks/measure_track_surface.py [--presets 01 02 03] [--seed 0] [--duration 10]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import median_abs_deviation  # noqa: E402

from msckf.frontend_depth import sample_depth  # noqa: E402
from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.bag_reader import RosarioSequence  # noqa: E402
from pipeline.depth import rectify_grey  # noqa: E402
from pipeline.depth_oracle_run import default_config, prepare_oracle  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.sim.sequence import SimulatedSequence  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402

READINGS = ("bilinear", "patch", "patch, gradient-weighted", "raw SGBM (bilinear)")


def summarise(err: np.ndarray, track: np.ndarray) -> dict[str, float]:
    """Statistics of relative differences ``err`` (N,) of observations of tracks ``track`` (N,) ids."""
    if len(err) == 0:
        return {"n": 0}
    med = float(np.median(err))
    _, inv = np.unique(track, return_inverse=True)
    mean_t = np.bincount(inv, err) / np.bincount(inv)
    within = err - mean_t[inv]
    return {"n": int(len(err)), "median": med, "robust_sigma": robust_sigma(err),
            "beyond_2pct": float(np.mean(np.abs(err) > 0.02)), "beyond_5pct": float(np.mean(np.abs(err) > 0.05)),
            "per_track_robust_sigma": robust_sigma(mean_t), "within_track_robust_sigma": robust_sigma(within)}


def robust_sigma(x: np.ndarray) -> float:
    """The median absolute deviation scaled to a Gaussian's σ (1.4826 · MAD; insensitive to tails)."""
    return float(median_abs_deviation(x, scale="normal")) if len(x) else float("nan")


def gradient_weighted_depth(depth: np.ndarray, grad2: np.ndarray, px: np.ndarray, patch: int) -> np.ndarray:
    """(N,) ``1 / Σ(w / Z) · Σw`` over the ``patch`` window at ``rint(px)``, w = squared image gradient (NaN where
    the window holds an invalid depth or leaves the map)."""
    h, w = depth.shape
    half = patch // 2
    out = np.full(len(px), np.nan)
    for i, (u, v) in enumerate(np.rint(px).astype(int)):
        if half <= u < w - half and half <= v < h - half:
            win = depth[v - half:v + half + 1, u - half:u + half + 1].astype(np.float64)
            wgt = grad2[v - half:v + half + 1, u - half:u + half + 1].astype(np.float64)
            if np.all(np.isfinite(win) & (win > 0)) and wgt.sum() > 0:
                out[i] = wgt.sum() / np.sum(wgt / win)
    return out


def measure(preset: str, seed: int, duration_s: float) -> dict[str, dict[str, float]]:
    """The statistics of every reading (:data:`READINGS`) on one preset."""
    src = simulate_cached(preset, duration_s=duration_s, progress=False)
    config = default_config({})
    fc = config.frontend
    prep = prepare_oracle(src.sim_dir, cache_dir(), [], config, [seed])
    log, rig = prep["logs"][seed], prep["rig"]
    sim = SimulatedSequence(src.sim_dir)
    seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
    grad2: dict[int, np.ndarray] = {}
    wanted = {fr.index for fr in log.frames}
    for fr in seq.stereo_frames():
        if fr.index in wanted:
            g = rectify_grey(rig, fr.left_bgr, fr.right_bgr)[0].astype(np.float32)
            grad2[fr.index] = cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2
    rules = (fc.depth_edge_window, fc.depth_edge_threshold, fc.min_depth_m, fc.max_depth_m)
    errs: dict[str, list[np.ndarray]] = {k: [] for k in READINGS}
    tracks: dict[str, list[np.ndarray]] = {k: [] for k in READINGS}
    for fi, fr in enumerate(log.frames):
        on_point = log.truth_source[fi] == 1
        if not np.any(on_point):
            continue
        z_true = log.truth[fi]
        exact = sim.depth(fr.index)
        ok_map = np.isfinite(exact) & (exact > 0)
        z_b, _ = sample_depth(exact, ok_map, fr.rect_px, "bilinear", *rules)
        z_p, _ = sample_depth(exact, ok_map, fr.rect_px, "patch", *rules, patch_size=fc.patch_size)
        z_g = np.where(np.isfinite(z_b), gradient_weighted_depth(exact, grad2[fr.index], fr.rect_px,
                                                                  fc.patch_size), np.nan)
        readings = {"bilinear": z_b, "patch": z_p, "patch, gradient-weighted": z_g,
                    "raw SGBM (bilinear)": fr.z_rect["raw"]}
        for name, z in readings.items():
            m = on_point & np.isfinite(z) & np.isfinite(z_b)
            errs[name].append(z_true[m] / z[m] - 1.0)
            tracks[name].append(fr.ids[m])
    return {k: summarise(np.concatenate(errs[k]), np.concatenate(tracks[k])) for k in READINGS}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["01", "02", "03"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    results: dict[str, dict[str, dict[str, float]]] = {}
    print("Z_track / Z_map − 1 at the observations whose exact-map reading the front end accepts "
          f"(seed {args.seed}, {args.duration:g} s)\n")
    print("| preset | map read | n | median | robust σ | > 2 % | > 5 % | per-track robust σ | within-track robust σ |")
    print("|---|---|---|---|---|---|---|---|---|")
    for p in args.presets:
        preset = p if p.startswith("rosario") or p == "tiny" else f"rosario-like-{p}"
        results[preset] = measure(preset, args.seed, args.duration)
        for name, s in results[preset].items():
            if s["n"] == 0:
                continue
            print(f"| {preset} | {name} | {s['n']} | {s['median']:+.2%} | {s['robust_sigma']:.2%} | "
                  f"{s['beyond_2pct']:.0%} | {s['beyond_5pct']:.0%} | {s['per_track_robust_sigma']:.2%} | "
                  f"{s['within_track_robust_sigma']:.2%} |", flush=True)
    out = args.json or cache_dir() / "benchmarks" / "measure_track_surface.json"
    write_json_atomic(out, {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                            "results": results})
    print(f"\nJSON: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
