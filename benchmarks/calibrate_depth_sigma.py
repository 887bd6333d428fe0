"""Calibrate the depth σ models of pipeline/depth_sigma.py on simulated frames against the exact depth.

* Raw SGBM: the robust σ (1.4826·MAD) of the disparity error ``f·B/Z_sgbm − f·B/Z_exact`` over valid pixels
  within the depth range (per preset and pooled).
* Fills: for each inpainting method, the relative error ``(Z_fill − Z_exact)/Z_exact`` of filled pixels binned by
  the distance to the nearest measured pixel, and the fitted line ``rel_0 + rel_per_px · dist``
  (``depth_sigma.fit_fill_model``).

Prints the figures and writes JSON (default <cache>/benchmarks/calibrate_depth_sigma.json); the constants in
pipeline/depth_sigma.py are copied from its output (the record says which run).

    .venv/bin/python benchmarks/calibrate_depth_sigma.py [--presets 01 02 03] [--every 10] [--methods telea]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthParams
from pipeline.depth_cache import DepthCache, depth_stream
from pipeline.depth_sigma import fill_distance_px, fit_fill_model
from pipeline.inpaint_stage import InpaintParams, inpainted_stream
from pipeline.paths import cache_dir
from pipeline.sim.sequence import SimulatedSequence
from pipeline.sim_source import simulate_cached


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["01", "02", "03"])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--every", type=int, default=10, help="use every N-th frame")
    ap.add_argument("--methods", nargs="*", default=["telea"])
    ap.add_argument("--min-depth", type=float, default=0.3)
    ap.add_argument("--max-depth", type=float, default=20.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    cache = cache_dir()
    disp_err: list[np.ndarray] = []
    fills: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {m: ([], []) for m in args.methods}
    per_preset: dict[str, dict] = {}
    for p in args.presets:
        preset = f"rosario-like-{p}" if not p.startswith("rosario") else p
        src = simulate_cached(preset, duration_s=args.duration, progress=False)
        sim = SimulatedSequence(Path(src.sim_dir))
        seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
        fb = seq.calibration.fx * seq.calibration.baseline
        for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=cache):
            pass
        raw = DepthCache(cache, seq.identity(), DepthParams())
        stores = {}
        for m in args.methods:
            for _ in inpainted_stream(seq, InpaintParams(method=m), cache, progress=False):
                pass
            stores[m] = DepthCache(cache, seq.identity(), InpaintParams(method=m))
        de: list[np.ndarray] = []
        for i in range(0, raw.n_frames or 0, args.every):
            r = raw.get(i)
            exact = sim.depth(i)
            ok_e = np.isfinite(exact) & (exact >= args.min_depth) & (exact <= args.max_depth)
            sel = r.valid & ok_e
            de.append(fb / r.depth_m[sel] - fb / exact[sel])
            dist = fill_distance_px(r.valid)
            for m, st in stores.items():
                f = st.get(i)
                hole = ~r.valid & ok_e & f.valid
                fills[m][0].append((f.depth_m[hole] - exact[hole]) / exact[hole])
                fills[m][1].append(dist[hole])
        d = np.concatenate(de)
        disp_err.append(d)
        per_preset[preset] = {"disparity_sigma_px": float(1.4826 * np.median(np.abs(d - np.median(d)))),
                              "disparity_bias_px": float(np.median(d)), "n": int(len(d))}
        print(f"{preset}: SGBM disparity error robust σ {per_preset[preset]['disparity_sigma_px']:.3f} px, "
              f"median {per_preset[preset]['disparity_bias_px']:+.3f} px (n = {len(d)})")
    d = np.concatenate(disp_err)
    pooled = float(1.4826 * np.median(np.abs(d - np.median(d))))
    print(f"pooled: SGBM disparity robust σ {pooled:.3f} px")
    fits = {}
    for m, (errs, dists) in fills.items():
        e = np.concatenate(errs)
        di = np.concatenate(dists)
        fit = fit_fill_model(e, di)
        fits[m] = fit
        print(f"{m}: fill σ_Z/Z = {fit[0]:.4f} + {fit[1]:.5f}·dist_px (cap {fit[2]}), n = {len(e)}")
        for lo, hi in ((0, 4), (4, 16), (16, 64), (64, 1e9)):
            s = (di > lo) & (di <= hi)
            if np.count_nonzero(s) > 30:
                ee = e[s]
                print(f"    dist ({lo:g}, {hi:g}] px: robust σ {1.4826 * np.median(np.abs(ee - np.median(ee))):.3f}, "
                      f"median {np.median(ee):+.3f}, n = {int(s.sum())}")
    out = args.json or cache / "benchmarks" / "calibrate_depth_sigma.json"
    write_json_atomic(out, {"args": {k: str(v) for k, v in vars(args).items()}, "per_preset": per_preset,
                            "disparity_sigma_px_pooled": pooled, "fill_fits": fits})
    print(f"JSON: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
