"""What a depth run pays per frame for its per-pixel depth σ: the numpy expressions (before) against the compiled
one-pass maps (``pipeline/depth_sigma_kernels.py``, now).

Takes the raw SGBM depth and the Telea-inpainted depth of a simulated preset through the pipeline's own stages
(cached: computed once) and times, per frame, what ``run_job`` calls: ``raw_sigma`` (every depth-raw frame) and
``filled`` (every depth-inpainted frame: far-field rule + fill σ), the latter with Telea's fill model (σ grows with
the distance to a measured pixel: a distance transform) and ``paper``'s (flat: none). CPU time of this thread, one
core, before and now alternating frame by frame so both see the same machine load. Checks that both give the same
values (NaN where NaN) on every frame.

    .venv/bin/python benchmarks/bench_depth_sigma.py [--preset rosario-like-02] [--duration 10] [--frames 150]
        [--repeats 3] [--json PATH]

Prints a table of medians and writes JSON (default ``<cache>/benchmarks/bench_depth_sigma.json``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.depth_sigma import DepthSigmaModel, fill_distance_px  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402


def numpy_raw_sigma(model: DepthSigmaModel, depth_m: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``DepthSigmaModel.raw_sigma`` as numpy expressions (before the compiled kernel)."""
    z = depth_m.astype(np.float32)
    s = z * z * np.float32(model.disparity_sigma_px / model.fx_baseline)
    return np.where(valid, s, np.nan).astype(np.float32)


def numpy_filled(model: DepthSigmaModel, depth_m: np.ndarray, valid: np.ndarray, raw_depth_m: np.ndarray,
                 raw_valid: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """``DepthSigmaModel.filled`` as numpy expressions (before): distance transform for every method."""
    ok = valid & ~model.far_open(raw_depth_m, raw_valid)
    rel0, per_px, rel_max = model.fill[method]
    z = depth_m.astype(np.float32)
    rel = np.minimum(np.float32(rel_max), np.float32(rel0) + np.float32(per_px) * fill_distance_px(raw_valid))
    s_raw = z * z * np.float32(model.disparity_sigma_px / model.fx_baseline)
    s = np.where(raw_valid, s_raw, np.maximum(z * rel, s_raw))
    s = np.where(np.isfinite(z) & (z > 0), s, np.nan).astype(np.float32)
    return ok, np.where(ok, s, np.nan).astype(np.float32)


def _maps(preset: str, duration_s: float, frames: int):
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import DepthParams
    from pipeline.depth_cache import DepthCache, depth_stream
    from pipeline.inpaint_stage import InpaintParams, inpainted_stream
    from pipeline.sources import resolve_source

    root = cache_dir()
    src = resolve_source(preset, duration_s=duration_s, cache_root=root, progress=True)
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    for _ in depth_stream(seq, DepthParams(), cache=True, progress=True, cache_root=root, stop_index=frames):
        pass
    for _ in inpainted_stream(seq, InpaintParams(method="telea"), root, progress=True):
        pass
    raw = DepthCache(root, seq.identity(), DepthParams())
    inp = DepthCache(root, seq.identity(), InpaintParams(method="telea"))
    model = DepthSigmaModel.for_rig(seq.calibration)
    return model, [(raw.get(i, grey=False), inp.get(i, grey=False)) for i in range(frames)]


def _cpu_ms(fn, *args):
    t0 = time.thread_time()
    out = fn(*args)
    return out, 1e3 * (time.thread_time() - t0)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a, b, equal_nan=True))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_depth_sigma.json")
    args = ap.parse_args(argv)
    model, maps = _maps(args.preset, args.duration, args.frames)
    r0, d0 = maps[0]
    model.raw_sigma(r0.depth_m, r0.valid)                                # compile / load the kernels first
    model.filled(d0.depth_m, d0.valid, r0.depth_m, r0.valid, "paper")
    cases = {
        "raw σ (depth-raw frame)": (lambda r, d: numpy_raw_sigma(model, r.depth_m, r.valid),
                                    lambda r, d: model.raw_sigma(r.depth_m, r.valid)),
        "filled, telea (depth-inpainted frame)": (
            lambda r, d: numpy_filled(model, d.depth_m, d.valid, r.depth_m, r.valid, "telea"),
            lambda r, d: model.filled(d.depth_m, d.valid, r.depth_m, r.valid, "telea")),
        "filled, paper (depth-inpainted frame)": (
            lambda r, d: numpy_filled(model, d.depth_m, d.valid, r.depth_m, r.valid, "paper"),
            lambda r, d: model.filled(d.depth_m, d.valid, r.depth_m, r.valid, "paper")),
        "  of which the far-field rule": (lambda r, d: model.far_open(r.depth_m, r.valid),
                                          lambda r, d: model.far_open(r.depth_m, r.valid)),
    }
    times: dict[str, dict[str, list[float]]] = {k: {"before": [], "now": []} for k in cases}
    identical = {k: True for k in cases}
    for _ in range(args.repeats):
        for r, d in maps:
            for name, (before, now) in cases.items():
                a, ta = _cpu_ms(before, r, d)
                b, tb = _cpu_ms(now, r, d)
                times[name]["before"].append(ta)
                times[name]["now"].append(tb)
                if isinstance(a, tuple):
                    identical[name] &= all(_same(x, y) for x, y in zip(a, b))
                else:
                    identical[name] &= _same(a, b)
    rows = {}
    print(f"\n{args.preset}, {args.duration:g} s, {len(maps)} frames × {args.repeats}, "
          f"{maps[0][0].depth_m.shape[1]}×{maps[0][0].depth_m.shape[0]} px, CPU ms per frame (median)\n")
    print("| per frame | before (numpy) | now (compiled) | speed-up | identical |")
    print("|---|---|---|---|---|")
    for name in cases:
        b, n = float(np.median(times[name]["before"])), float(np.median(times[name]["now"]))
        rows[name] = {"before_ms": b, "now_ms": n, "speedup": b / n if n > 0 else float("inf"),
                      "identical": identical[name]}
        print(f"| {name} | {b:.2f} | {n:.2f} | {b / n:.1f}× | {'yes' if identical[name] else 'NO'} |")
    write_json_atomic(args.json, {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                                  "machine": platform.platform(), "results": rows})
    print(f"\nJSON: {args.json}")
    return 0 if all(identical.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
