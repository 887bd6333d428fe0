"""``agrivio inpaint-bench``: the depth-inpainting benchmark (Table-1-shaped report, figure grid, timings)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from tqdm import tqdm

from pipeline.errors import AgrivioError
from pipeline.inpaint_bench import ABLATIONS, DEFAULT_METHODS, parse_method, procedural_frames, run_bench, write_bench
from pipeline.paths import cache_dir


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "inpaint-bench", help="benchmark depth inpainting methods on frames with ground truth",
        description="Fill holes (real SGBM masks from simulated frames, or seeded random masks) with each method "
                    "and score them on the hole pixels (RMSE, MAE, PSNR, SSIM). Writes results.md, results.json "
                    "and grid.png.")
    p.add_argument("--source", choices=("auto", "sim", "procedural"), default="auto",
                   help="frames: simulator (SGBM masks) or the procedural generator (default: sim if available)")
    p.add_argument("--frames", type=int, default=None, help="number of frames (default 3 with --small, else 12)")
    p.add_argument("--small", action="store_true",
                   help="demo size (≈1–2 min): 3 frames, and without the slow EBM baseline unless --methods names it")
    p.add_argument("--methods", default=None,
                   help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)}); variants as name:key=value,… "
                        "separated by ';' (e.g. 'paper;paper:fusion=mean')")
    p.add_argument("--ablations", action="store_true",
                   help="also run the paper's ablations: " + ", ".join(ABLATIONS))
    p.add_argument("--paper-fusion", choices=("net", "mean", "best"), default="net",
                   help="fusion of the paper's method (ablation)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--peak", type=float, default=20.0, help="PSNR/SSIM peak in metres (fixed; default 20)")
    p.add_argument("--max-depth", type=float, default=20.0, help="only score ground truth up to this depth (m)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: <cache>/inpaint_bench/<source>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _frames(args: argparse.Namespace, n: int):
    source = args.source
    if source in ("auto", "sim"):
        try:
            from pipeline.inpaint_bench import sim_frames  # available once the simulator is
        except ImportError:
            sim_frames = None
        if sim_frames is not None:
            return "sim", sim_frames(n, seed=args.seed, progress=not args.quiet)
        if source == "sim":
            raise AgrivioError("inpaint-bench: --source sim needs the simulator (pipeline/sim), which is not available")
    return "procedural", procedural_frames(n, seed=args.seed)


def run(args: argparse.Namespace) -> int:
    n = args.frames if args.frames is not None else (3 if args.small else 12)
    if n < 1:
        raise AgrivioError(f"inpaint-bench: --frames must be ≥ 1, got {n}")
    methods = args.methods.split(";") if args.methods and ":" in args.methods else (
        args.methods.split(",") if args.methods else [m for m in DEFAULT_METHODS if not (args.small and m == "ebm")])
    if args.ablations:
        methods += [a for a in ABLATIONS if a not in methods]
    from inpaint import METHODS

    try:
        bad = [m for m in methods if parse_method(m)[0] not in METHODS]
    except ValueError as exc:
        raise AgrivioError(f"inpaint-bench: {exc}") from None
    if bad:
        raise AgrivioError(f"inpaint-bench: unknown method(s) {bad}; available: {sorted(METHODS)}")
    source, frames = _frames(args, n)
    out = args.out or cache_dir() / "inpaint_bench" / source
    options = {"paper": {"fusion": args.paper_fusion}}
    bar = tqdm(total=len(frames) * len(methods), desc="inpaint-bench", disable=args.quiet, unit="run")
    t0 = time.perf_counter()
    res = run_bench(frames, methods, options, peak=args.peak, max_depth=args.max_depth,
                    progress=lambda f, m: (bar.set_postfix_str(f"{f} {m}"), bar.update()))
    bar.close()
    md = write_bench(res, out, source, time.perf_counter() - t0)
    print(md)
    print(f"written: {out / 'results.md'}, {out / 'results.json'}, {out / 'grid.png'}")
    return 0
