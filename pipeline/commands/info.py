"""``agrivio info BAG``: topics, message counts, rates, duration and calibration of a Rosario bag."""

from __future__ import annotations

import argparse
from datetime import UTC, datetime
from pathlib import Path

from pipeline.bag_reader import RosarioSequence
from pipeline.calibration import summarize_rig
from pipeline.data_quality import measure, summary_lines


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("info", help="describe a Rosario bag (topics, counts, duration, calibration)",
                              description="Describe a Rosario v1 bag: plain, BZ2/LZ4-compressed, or split "
                                          "(x.bag.00, .01, ...: pass x.bag or the first part).")
    p.add_argument("bag", type=Path, help="bag file, first split part, or split stem")
    p.add_argument("--camchain", type=Path, default=None,
                   help="Kalibr camchain YAML for the extrinsics (default: the shipped Rosario one)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    seq = RosarioSequence(args.bag, camchain=args.camchain)
    dur = seq.duration_s
    start = datetime.fromtimestamp(seq.start_ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")
    parts = f"{len(seq.parts)} split parts" if len(seq.parts) > 1 else "1 file"
    print(f"bag        {seq.path} ({parts}, {seq.size_bytes / 1e6:.1f} MB)")
    print(f"identity   {seq.identity()}")
    print(f"start      {start}  ({seq.start_ns} ns)")
    print(f"duration   {dur:.3f} s")
    print()
    width = max(len(t.topic) for t in seq.topics.values())
    print(f"{'topic':<{width}}  {'type':<32} {'count':>8} {'rate Hz':>8}")
    for name in sorted(seq.topics):
        t = seq.topics[name]
        rate = (t.count - 1) / dur if dur > 0 and t.count > 1 else float("nan")
        print(f"{t.topic:<{width}}  {t.msgtype:<32} {t.count:>8d} {rate:>8.2f}")
    print()
    print("data quality (header stamps)")
    for line in summary_lines(measure(seq)):
        print(f"  {line}")
    print()
    print("calibration (camera_info K, D, R, P + camchain extrinsics)")
    print(summarize_rig(seq.calibration))
    return 0
