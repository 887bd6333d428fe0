"""``agrivio experiment``: the paper's experiment (its Table 2) at a chosen scale, in one resumable command.

Three Rosario-like sequences × {stereo, depth-raw, depth-inpainted with the paper's method, depth-inpainted with
Telea, odometry} × five seeded runs, then the comparison report. Scales (simulated seconds per sequence):

* ``demo``: 10 s clips (what ``agrivio demo`` runs; a few minutes);
* ``standard`` (default): 120 s, about 100 m per sequence with the first headland turns;
* ``paper``: the presets' full length (445–450 s, 200–400 m each, rows, U-turns, stops and speed changes), the
  length of the Rosario sequences of the paper's Table 2.

It resumes: killed and started again with the same arguments, it reuses every cached simulation, depth and
inpainted frame and every run record made from the same inputs, and runs only what is missing (failed runs are
retried). Runs go on the local process pool (``--workers``) or on Ray (``--executor ray``). Progress: a bar for each
sequence's simulation and one for its preparation (SGBM depth and every inpainting method, frame by frame on one
pool: :mod:`pipeline.prep_stage`), then one bar with an ETA over every run of the matrix.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pipeline.commands.report_summary import print_comparison
from pipeline.commands.run_sequence import failure_summary, parse_variants
from pipeline.errors import AgrivioError
from pipeline.paths import cache_dir
from pipeline.report_stage import write_comparison_report
from pipeline.run_sequence import DEFAULT_VARIANTS, SequenceSpec, run_matrix
from pipeline.sources import check_source

#: Simulated seconds per sequence of each scale (None: the preset's own, full length).
SCALES: dict[str, float | None] = {"demo": 10.0, "standard": 120.0, "paper": None}
DEFAULT_SCALE = "standard"
PRESETS = ("rosario-like-01", "rosario-like-02", "rosario-like-03")
#: Inpainting methods of depth-inpainted: the paper's method first (Table 2's "after"), then the baseline.
DEFAULT_METHODS = ("paper", "telea")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("experiment", help="the paper's experiment (Table 2) at demo / standard / paper scale",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scale", choices=tuple(SCALES), default=DEFAULT_SCALE,
                   help=f"sequence length: demo 10 s, standard 120 s, paper = full length (default {DEFAULT_SCALE})")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds per sequence instead of the scale's (for other lengths)")
    p.add_argument("--presets", default=",".join(PRESETS), help="comma-separated simulator presets")
    p.add_argument("--runs", type=int, default=5, help="seeded runs per variant (default 5)")
    p.add_argument("--variants", default=",".join(DEFAULT_VARIANTS), help="comma-separated variants (default: all)")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help="inpainting methods of depth-inpainted, the first is Table 2's 'after' (default paper,telea)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: <cache>/experiment-<scale>)")
    p.add_argument("--executor", choices=("local", "serial", "ray"), default="local",
                   help="local process pool (default), serial (in this process) or Ray")
    p.add_argument("--workers", type=int, default=None, help="local pool size (default: all cores)")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray)")
    p.add_argument("--max-frames", type=int, default=None, help="only the first N frames of each sequence")
    p.set_defaults(func=run)


def experiment_specs(scale: str, presets: list[str], duration_s: float | None = None) -> list[SequenceSpec]:
    """The sequences of an experiment: each preset at the scale's length (``duration_s`` overrides it)."""
    if scale not in SCALES:
        raise AgrivioError(f"unknown scale {scale!r}; choose from {', '.join(SCALES)}")
    if duration_s is not None and not duration_s > 0:
        raise AgrivioError(f"--duration must be > 0 s, got {duration_s:g}")
    length = duration_s if duration_s is not None else SCALES[scale]
    return [SequenceSpec(p, duration_s=length) for p in presets]


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    if args.runs < 1:
        raise AgrivioError("--runs must be at least 1")
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    if not presets:
        raise AgrivioError("--presets names no preset")
    for preset in presets:  # before anything is simulated or run: not 5 × variants failed runs and a report later
        check_source(preset)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise AgrivioError("--methods names no inpainting method")
    variants = parse_variants(args.variants)
    specs = experiment_specs(args.scale, presets, args.duration)
    out: Path = args.out or cache_dir() / f"experiment-{args.scale}"
    length = "full length" if specs[0].duration_s is None else f"{specs[0].duration_s:g} s"
    print(f"agrivio experiment ({args.scale}): {len(specs)} sequences × {length}, variants {', '.join(variants)}"
          f" (depth-inpainted: {', '.join(methods)}), {args.runs} runs each → {out}")
    records = run_matrix(specs, variants, range(args.runs), out, cache_dir(), inpaint_method=methods[0],
                         extra_inpaint_methods=methods[1:], executor=args.executor, workers=args.workers,
                         ray_address=args.ray_address, max_frames=args.max_frames, keep_going=True)
    comparison = write_comparison_report(out, out / "report", after_method=methods[0])
    print_comparison(comparison)
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    print(f"\n{len(records)} runs ({n_failed} failed) in {(time.perf_counter() - t_start) / 60:.1f} min. "
          f"Report: {comparison.out / 'report.html'}")
    return failure_summary(records)
