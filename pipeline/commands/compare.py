"""``agrivio compare RUNS_DIR [--out DIR]``: five-run statistics and the before/after report of a runs folder.

Reads every ``*.json`` under RUNS_DIR (any depth) that is a run record (``"record_type": "run"``), summarises
ATE per sequence × variant (a run found twice — same sequence, variant, method, seed and input key — counted
once; failed runs counted and listed), compares ``depth-raw`` with ``depth-inpainted``
(paper Table 2 layout, Welch test, bootstrap CI) and writes ``report.md``, ``report.html`` (self-contained),
``summary.json`` and ``figures/*.png`` into DIR (default RUNS_DIR/report). Records that point to their estimate
and ground-truth TUM files (``estimate_path``, ``gt_path``, relative to the record) add trajectory plots.

``--external NAME=path.tum`` (repeatable; ``NAME@SEQUENCE=path.tum`` when RUNS_DIR holds several sequences) adds a
trajectory from another system (OpenVINS, ORB-SLAM3, VINS-Fusion, … run on the ``agrivio simulate --euroc`` export,
body = IMU) as a row ``external: NAME``, evaluated against the same ground truth with the same association,
alignment and lever arm as the sequence's VIO runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.commands.report_summary import print_comparison
from pipeline.report_stage import DEFAULT_TITLE, write_comparison_report


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("compare", help="five-run statistics and the before/after inpainting report",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("runs_dir", type=Path, help="folder holding run records (*.json, any depth)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: RUNS_DIR/report)")
    p.add_argument("--title", default=DEFAULT_TITLE,
                   help="report title")
    p.add_argument("--no-trajectories", action="store_true",
                   help="skip loading estimate/GT files (no top-view and error-over-time figures)")
    p.add_argument("--external", action="append", default=[], metavar="NAME=path.tum",
                   help="another system's TUM trajectory (body = IMU), evaluated like the VIO runs (repeatable; "
                        "NAME@SEQUENCE=path.tum to pick the sequence)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    print_comparison(write_comparison_report(args.runs_dir, args.out, args.title,
                                             trajectories=not args.no_trajectories, external=args.external))
    return 0
