"""Does the paper method's own candidate agreement predict its fill error better than the distance to a measured
pixel (the fill σ model of pipeline/depth_sigma.py)?

On simulated frames (real SGBM holes, exact depth known), ``paper`` is run with a pass observer: in its last
full-resolution pass, the per-pixel range (max − min) of the valid candidate blocks it fuses, relative to their
mean, is pasted with the method's own tent-window averaging into a "candidate spread" map. Per filled pixel the
relative error |Z_fill − Z_exact| / Z_exact is then compared with each predictor: Spearman rank correlation, and
the median error in each predictor quintile. Prints a table, writes JSON (default
<cache>/benchmarks/measure_fill_uncertainty.json).

    .venv/bin/python benchmarks/measure_fill_uncertainty.py [--presets 01 02 03] [--every 30]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import rankdata, spearmanr  # noqa: E402

from inpaint.c2f import inpaint_paper_c2f  # noqa: E402
from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.bag_reader import RosarioSequence  # noqa: E402
from pipeline.depth import DepthParams  # noqa: E402
from pipeline.depth_cache import DepthCache, depth_stream  # noqa: E402
from pipeline.depth_sigma import fill_distance_px  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.sim.sequence import SimulatedSequence  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402


def spread_map(depth: np.ndarray, hole: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(filled depth, candidate spread) of one frame: ``paper`` with an observer of its level-0 passes."""
    h_img, w_img = depth.shape
    state: dict[str, np.ndarray] = {}

    def observe(lv, centres, cands, est_blk, known_blk, q, valid):
        if lv != 0:
            return
        vm = valid[:, :, None, None]
        lo = np.where(vm, cands, np.inf).min(axis=1)
        hi = np.where(vm, cands, -np.inf).max(axis=1)
        mid = np.abs(np.where(vm, cands, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1)[:, None, None])
        rel = np.where(np.isfinite(hi - lo), (hi - lo) / np.maximum(mid, 1e-6), 0.0)
        b = cands.shape[-1]
        h = b // 2
        off = np.arange(-h, h + 1)
        tent = (h + 1 - np.abs(off)).astype(np.float64)
        win = np.outer(tent, tent)
        acc = np.zeros((h_img, w_img))
        wacc = np.zeros((h_img, w_img))
        ys = np.clip(centres[:, 0, None, None] + off[None, :, None], 0, h_img - 1)
        xs = np.clip(centres[:, 1, None, None] + off[None, None, :], 0, w_img - 1)
        ys, xs = np.broadcast_arrays(ys, xs)
        np.add.at(acc, (ys, xs), rel * win)
        np.add.at(wacc, (ys, xs), np.broadcast_to(win, rel.shape))
        state["spread"] = np.where(wacc > 0, acc / np.maximum(wacc, 1e-12), np.nan)

    filled = inpaint_paper_c2f(np.nan_to_num(depth, nan=0.0).astype(np.float32), hole, None, observer=observe)
    return filled, state.get("spread", np.full(depth.shape, np.nan))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["01", "02", "03"])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--every", type=int, default=30, help="use every N-th frame")
    ap.add_argument("--max-depth", type=float, default=20.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    cache = cache_dir()
    err, dist, spr = [], [], []
    for p in args.presets:
        preset = f"rosario-like-{p}" if not p.startswith("rosario") else p
        src = simulate_cached(preset, duration_s=args.duration, progress=False)
        sim = SimulatedSequence(Path(src.sim_dir))
        seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
        for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=cache):
            pass
        raw = DepthCache(cache, seq.identity(), DepthParams())
        for i in range(0, raw.n_frames or 0, args.every):
            r = raw.get(i, grey=False)
            exact = sim.depth(i)
            filled, spread = spread_map(r.depth_m, ~r.valid)
            sel = ~r.valid & np.isfinite(exact) & (exact > 0.3) & (exact <= args.max_depth) & np.isfinite(spread) \
                & np.isfinite(filled) & (filled > 0)
            err.append(np.abs(filled[sel] - exact[sel]) / exact[sel])
            dist.append(fill_distance_px(r.valid)[sel])
            spr.append(spread[sel])
            print(f"{preset} frame {i}: {int(sel.sum())} filled pixels", flush=True)
    e, d, s = (np.concatenate(x) for x in (err, dist, spr))
    out: dict[str, dict] = {}
    print(f"\n{len(e)} filled pixels; median |rel. error| {np.median(e):.1%}\n")
    print("| predictor | Spearman ρ with |rel. error| | median |rel. error| by predictor quintile (low → high) |")
    print("|---|---|---|")
    for name, x in (("distance to a measured pixel (px)", d), ("candidate spread (relative)", s)):
        rho = float(spearmanr(x, e).statistic)
        qs = np.quantile(x, [0.2, 0.4, 0.6, 0.8])
        bins = np.minimum((5 * (rankdata(x) - 1) / len(x)).astype(int), 4)  # by rank: ties do not empty a bin
        med = [float(np.median(e[bins == k])) for k in range(5)]
        out[name] = {"spearman": rho, "quintile_median_rel_error": med, "quintile_edges": qs.tolist()}
        print(f"| {name} | {rho:.3f} | {' / '.join(f'{m:.1%}' for m in med)} |")
    path = args.json or cache / "benchmarks" / "measure_fill_uncertainty.json"
    write_json_atomic(path, {"args": {k: str(v) for k, v in vars(args).items()}, "n": int(len(e)),
                             "median_rel_error": float(np.median(e)), "predictors": out})
    print(f"JSON: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
