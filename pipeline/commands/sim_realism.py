"""``agrivio sim-realism``: simulate presets, run the depth stage on them, and report how realistic they are.

Writes ``realism.md``, ``realism.json`` and ``gallery_<preset>.png`` (left, right, exact depth, SGBM depth, holes
by cause) into the output folder. See ``pipeline/sim/realism.py`` for the measurements.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from pipeline.errors import AgrivioError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("sim-realism", help="measure simulator realism (holes, depth error, features)",
                              description="Simulate presets (or reuse finished ones), run the stereo depth stage, "
                                          "and report SGBM hole ratios and causes, depth error against the exact "
                                          "depth, FAST corners and KLT track lengths, with a PNG gallery.")
    p.add_argument("presets", nargs="*", default=["rosario-like-01", "rosario-like-02", "rosario-like-03"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=20.0, help="seconds simulated per preset (default 20)")
    p.add_argument("--stride", type=int, default=3, help="analyse every N-th frame for holes/errors (default 3)")
    p.add_argument("--klt-frames", type=int, default=60, help="consecutive moving frames for KLT tracks (60)")
    p.add_argument("--out", type=Path, default=None, help="report folder (default <cache>/sim_realism)")
    p.add_argument("--workers", type=int, default=None, help="render processes (default min(2, CPUs))")
    p.add_argument("--resimulate", action="store_true", help="simulate even if a finished sequence exists")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pipeline.atomic import write_json_atomic, write_text_atomic
    from pipeline.depth import DepthParams
    from pipeline.paths import cache_dir
    from pipeline.sim.realism import markdown
    from pipeline.sim.realism_stage import measure_realism, realism_sequence

    if args.stride < 1 or args.klt_frames < 0:
        raise AgrivioError("sim-realism: --stride must be ≥ 1 and --klt-frames ≥ 0")
    out = args.out or cache_dir() / "sim_realism"
    params = DepthParams()
    workers = args.workers if args.workers is not None else min(2, os.cpu_count() or 1)
    summaries, per_frame = [], {}
    t0 = time.perf_counter()
    for preset in args.presets:
        seq = realism_sequence(preset, args.seed, args.duration, workers, args.resimulate, progress=not args.quiet)
        result = measure_realism(preset, seq, params, args.stride, args.klt_frames, out, progress=not args.quiet)
        summaries.append(result.summary)
        per_frame[preset] = result.per_frame
    note = (f"{args.duration:g} s per preset, seed {args.seed}, every {args.stride} frame(s) analysed; KLT over "
            f"{args.klt_frames} consecutive moving frames. Depth stage: pipeline.depth defaults "
            f"(SGBM {params.mode}, {params.num_disparities} disparities, block {params.block_size}, LR check).")
    write_text_atomic(out / "realism.md", markdown(summaries, note))
    write_json_atomic(out / "realism.json", {"summaries": summaries, "per_frame": per_frame, "note": note,
                                             "wall_s": time.perf_counter() - t0})
    print(markdown(summaries, note))
    print(f"written: {out / 'realism.md'}, {out / 'realism.json'}, gallery_<preset>.png")
    return 0
