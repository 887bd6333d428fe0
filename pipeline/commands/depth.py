"""``agrivio depth BAG``: run (or read from the cache) the stereo depth stage of a bag and summarise it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pipeline.bag_reader import RosarioSequence
from pipeline.data_quality import check_stereo_pairing, sequence_quality, summary_lines
from pipeline.depth import DepthParams
from pipeline.depth_stage import run_depth
from pipeline.paths import cache_dir


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("depth", help="compute and cache stereo depth (SGBM + LR check) for a bag",
                              description="Rectify, StereoSGBM, left-right check; depth in metres with holes "
                                          "left empty. Results are cached per bag and parameter set.")
    p.add_argument("bag", type=Path, help="bag file, first split part, or split stem")
    p.add_argument("--out", type=Path, default=None,
                   help="cache root for the depth frames (default: the agrivio cache dir, $AGRIVIO_CACHE)")
    p.add_argument("--camchain", type=Path, default=None, help="Kalibr camchain YAML (default: shipped Rosario)")
    p.add_argument("--max-frames", type=int, default=None, help="only the first N stereo frames")
    p.add_argument("--no-cache", action="store_true", help="compute everything, store nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def print_summary(summary: dict[str, Any]) -> None:
    print(f"frames              {summary['frames']} ({summary['computed']} computed, {summary['cached']} from cache)")
    print(f"hole ratio          median {summary['hole_ratio_median']:.3f}  p10 {summary['hole_ratio_p10']:.3f}  "
          f"p90 {summary['hole_ratio_p90']:.3f}")
    per = summary["compute_s_per_frame"]
    print(f"time per frame      {per * 1e3:.1f} ms (rectify + 2x SGBM + LR check)" if per is not None else
          "time per frame      - (all frames from cache)")
    print(f"wall time           {summary['wall_s']:.2f} s")
    if summary.get("cache_dir"):
        print(f"cache               {summary['cache_dir']}")


def run(args: argparse.Namespace) -> int:
    seq = RosarioSequence(args.bag, camchain=args.camchain)
    quality = sequence_quality(seq, args.out or cache_dir())
    for line in summary_lines(quality):
        print(line)
    check_stereo_pairing(seq.path, quality)  # too few pairs: one line naming the offset, exit 2
    summary = run_depth(seq, DepthParams(), cache=not args.no_cache, cache_root=args.out,
                        max_frames=args.max_frames, progress=not args.quiet)
    print(f"bag                 {seq.path}")
    print_summary(summary)
    if summary["frames"] == 0:
        print("no depth frames (no stereo pairs in the requested range)")
    if summary["unpaired_left"] or summary["unpaired_right"]:
        print(f"unpaired images     left {summary['unpaired_left']}, right {summary['unpaired_right']} (skipped)")
    return 0
