"""``agrivio run-sequence BAG_OR_PRESET``: the whole chain for one sequence, then its report and summary.

Examples::

    agrivio run-sequence rosario-like-01 --out runs/                       # simulated (cached) sequence
    agrivio run-sequence sequence01.bag --gt sequence01_gt.txt --out runs/ # a real Rosario bag (or .bag.00 parts)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.commands.report_summary import print_comparison
from pipeline.errors import AgrivioError
from pipeline.paths import cache_dir
from pipeline.report_stage import write_comparison_report
from pipeline.run_sequence import DEFAULT_VARIANTS, SequenceSpec, run_matrix


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options shared by run-sequence and demo."""
    p.add_argument("--variants", default=",".join(DEFAULT_VARIANTS),
                   help=f"comma-separated: {', '.join(DEFAULT_VARIANTS)} (default: all)")
    p.add_argument("--runs", type=int, default=5, help="seeded runs per variant (seeds 0..N-1; default 5)")
    p.add_argument("--inpaint", default="paper", metavar="METHOD",
                   help="inpainting method of depth-inpainted: paper, ebm, telea, ns, biharmonic, ipbasic")
    p.add_argument("--config", default=None, metavar="YAML", help="MSCKF parameter overrides (YAML)")
    p.add_argument("--executor", choices=("local", "serial", "ray"), default="local",
                   help="local process pool (default), serial, or ray")
    p.add_argument("--workers", type=int, default=None, help="processes for the local executor (default: all cores)")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local instance)")
    p.add_argument("--max-frames", type=int, default=None,
                   help="use only the first N stereo frames (every stage: depth, inpainting, VIO)")
    p.add_argument("--keep-failed", action="store_true",
                   help="keep failed run records instead of retrying them (default: retry)")


def parse_variants(text: str) -> list[str]:
    variants = [v.strip() for v in text.split(",") if v.strip()]
    if not variants:
        raise AgrivioError("--variants is empty")
    return variants


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("run-sequence", help="read → depth → inpaint → VIO × variants × seeds → report",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", help="a Rosario bag (plain, BZ2/LZ4, or byte-split stem) or a simulator preset")
    p.add_argument("--out", type=Path, required=True, help="output folder (runs, records, report)")
    p.add_argument("--gt", default=None, help="ground-truth TUM file (bags)")
    p.add_argument("--camchain", default=None, help="Kalibr camchain YAML (default: the published Rosario one)")
    p.add_argument("--duration", type=float, default=None, help="simulated duration in seconds (presets)")
    p.add_argument("--name", default=None, help="sequence name in reports (default: bag stem or preset)")
    add_run_options(p)
    p.set_defaults(func=run)


def check_run_options(args: argparse.Namespace) -> None:
    """Ranges of the numeric options, before anything runs."""
    if args.runs < 1:
        raise AgrivioError("--runs must be at least 1")
    if args.workers is not None and args.workers < 1:
        raise AgrivioError("--workers must be at least 1")
    if args.max_frames is not None and args.max_frames < 1:
        raise AgrivioError("--max-frames must be at least 1")


def failure_summary(records: list[dict]) -> int:
    """Print the end-of-job summary; return the exit status (1 when any requested run failed, else 0)."""
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    if n_failed:
        reasons = sorted({str(r.get("failure_reason") or "unknown")[:200] for r in records if r.get("status") != "ok"})
        print(f"agrivio: {n_failed} of {len(records)} run(s) failed; first reason: {reasons[0]}", file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    check_run_options(args)
    spec = SequenceSpec(args.source, name=args.name, gt=args.gt, camchain=args.camchain, duration_s=args.duration)
    records = run_matrix([spec], parse_variants(args.variants), range(args.runs), args.out, cache_dir(),
                         inpaint_method=args.inpaint, msckf_config=args.config, executor=args.executor,
                         workers=args.workers, ray_address=args.ray_address, max_frames=args.max_frames,
                         keep_failed=args.keep_failed)
    comparison = write_comparison_report(args.out, args.out / "report")
    print_comparison(comparison)
    report_dir = comparison.out
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    print(f"\n{len(records)} runs ({n_failed} failed). Report: {report_dir / 'report.html'}")
    return failure_summary(records)
