"""How large is SGBM's depth error at a tracked point, as a function of the disparity span around it?

The depth front end reads the raw SGBM map at each tracked feature and states σ_d = 0.545 px of disparity for it
(``pipeline.depth_sigma.RAW_DISPARITY_SIGMA_PX``, the robust σ over all valid pixels). At a depth discontinuity the
matching window straddles two surfaces and the error has heavy tails. On simulated sequences the tracked point's
depth is known (its true-pose triangulation, ``pipeline.depth_oracle.true_track_depths``: only tracks that are a
consistent 3-D point); for every raw reading the front end accepted at such a track this prints, by bin of the
*span* (max − min of the measured disparities within the raw span rule's neighbourhood,
``DepthSigmaModel.disparity_span``): the share of readings, median |Δd|, robust σ (1.4826 · median |Δd|), RMS,
90th percentile, the share off by ≥ 5 px, and the slope ``a = sqrt(RMS² − σ_d²) / span`` the raw span rule
(``sqrt(σ_d² + (a · span)²)``) would need to state that RMS. Prints a table, writes JSON (default
<cache>/benchmarks/measure_raw_span_sigma.json). One seed's tracks per preset.

    .venv/bin/python benchmarks/measure_raw_span_sigma.py [--presets 01 02] [--duration 12] [--every 1]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.bag_reader import RosarioSequence  # noqa: E402
from pipeline.depth import DepthParams  # noqa: E402
from pipeline.depth_cache import DepthCache  # noqa: E402
from pipeline.depth_oracle_run import default_config, prepare_oracle  # noqa: E402
from pipeline.depth_sigma import RAW_DISPARITY_SIGMA_PX, DepthSigmaModel  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.sim.presets import PRESETS  # noqa: E402
from pipeline.sim.sequence import SimulatedSequence  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402

SPAN_EDGES = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, np.inf)


def readings(preset: str, duration: float, seed: int, every: int) -> np.ndarray:
    """(M, 3) ``[|Δd| px, span px, true disparity px]`` of the raw readings at consistent-point tracks."""
    src = simulate_cached(preset, duration_s=duration, progress=False)
    prep = prepare_oracle(src.sim_dir, cache_dir(), [], default_config(), [seed])
    sim = SimulatedSequence(Path(src.sim_dir))
    seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
    raw = DepthCache(cache_dir(), seq.identity(), DepthParams())
    rig = prep["rig"]
    model = DepthSigmaModel.for_rig(rig)
    fB = model.fx_baseline
    log = prep["logs"][seed]
    out = []
    for i, fr in enumerate(log.frames):
        if i % every:
            continue
        z, t = fr.z_rect.get("raw"), np.asarray(log.truth[i], dtype=np.float64)
        ok = np.isfinite(z) & np.isfinite(t)
        if not ok.any():
            continue
        f = raw.get(fr.index)
        span = model.disparity_span(f.depth_m, f.valid)
        u = np.clip(np.round(fr.rect_px[ok, 0]).astype(int), 0, span.shape[1] - 1)
        v = np.clip(np.round(fr.rect_px[ok, 1]).astype(int), 0, span.shape[0] - 1)
        out.append(np.stack([np.abs(fB / z[ok] - fB / t[ok]), span[v, u], fB / t[ok]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3))


def span_table(r: np.ndarray, sigma_d: float = RAW_DISPARITY_SIGMA_PX) -> list[dict[str, float]]:
    """Per span bin statistics of the readings ``r`` (see :func:`readings`)."""
    dd, span = r[:, 0], r[:, 1]
    rows = []
    for lo, hi in zip(SPAN_EDGES[:-1], SPAN_EDGES[1:]):
        m = (span >= lo) & (span < hi)
        if not m.any():
            continue
        d = dd[m]
        rms = float(np.sqrt(np.mean(d ** 2)))
        mid = float(np.median(span[m]))
        rows.append({"span_lo": lo, "span_hi": hi, "n": int(m.sum()), "share": float(m.mean()),
                     "median_abs": float(np.median(d)), "robust_sigma": float(1.4826 * np.median(d)), "rms": rms,
                     "p90": float(np.percentile(d, 90)), "share_5px": float(np.mean(d >= 5.0)),
                     "median_span": mid,
                     "slope": float(np.sqrt(max(rms ** 2 - sigma_d ** 2, 0.0)) / mid) if mid > 0 else float("nan")})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["01", "02"])
    ap.add_argument("--duration", type=float, default=12.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=1, help="use every N-th frame")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    presets = [p if p.startswith("rosario") else f"rosario-like-{p}" for p in args.presets]
    unknown = [p for p in presets if p not in PRESETS]
    if unknown:
        ap.error(f"--presets: unknown {', '.join(unknown)} (known: {', '.join(p for p in PRESETS if p != 'tiny')})")
    if args.every < 1:
        ap.error("--every must be >= 1")
    result = {}
    for preset in presets:
        r = readings(preset, args.duration, args.seed, args.every)
        rows = span_table(r)
        result[preset] = rows
        print(f"\n### {preset} ({args.duration:g} s, seed {args.seed}, every {args.every}. frame): {len(r)} raw "
              f"readings at consistent-point tracks, {np.mean(r[:, 0] >= 5.0):.2%} off by ≥ 5 px")
        print("| span (px) | readings | median \\|Δd\\| | robust σ | RMS | p90 | ≥ 5 px | slope a |")
        print("|---|---|---|---|---|---|---|---|")
        for row in rows:
            print(f"| {row['span_lo']:g}–{row['span_hi']:g} | {row['n']} ({row['share']:.1%}) | "
                  f"{row['median_abs']:.2f} | {row['robust_sigma']:.2f} | {row['rms']:.2f} | {row['p90']:.2f} | "
                  f"{row['share_5px']:.2%} | {row['slope']:.2f} |")
    out = args.json or cache_dir() / "benchmarks" / "measure_raw_span_sigma.json"
    write_json_atomic(out, {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                            "sigma_d_px": RAW_DISPARITY_SIGMA_PX, "results": result})
    print(f"JSON: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
