"""``agrivio replay RUN_DIR [RUN_DIR ...] --out FILE.rrd``: a rerun recording of one or more runs side by side.

Each RUN_DIR is a run folder (``OUT/<sequence>/<variant>/seed<k>``) of the same sequence. Estimates are drawn in the
ground-truth frame exactly as their ATE was computed (lever arm, association, alignment of the run record), so each
path lies on the ground truth within its ATE. ``--external NAME=path.tum`` (repeatable) adds a trajectory from
another system (e.g. OpenVINS on the ``agrivio simulate --euroc`` export, body = IMU), evaluated like the VIO runs.
Every frame's images are logged unless ``--every N`` (then every N-th frame's images; poses and metrics stay at
full rate). Open the result with ``rerun FILE.rrd`` (``.venv/bin/rerun FILE.rrd``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.replay_stage import replay_runs


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="write a rerun .rrd of runs (images, features, depth, trajectories)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", type=Path, help="run folder(s) of one sequence (holding record.json)")
    p.add_argument("--out", type=Path, required=True, help="output .rrd file")
    p.add_argument("--every", type=int, default=1,
                   help="image stride: log the images of every N-th frame (default 1 = all frames); poses, "
                        "features counts and metrics are logged for every frame regardless")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--external", action="append", default=[], metavar="NAME=path.tum",
                   help="another system's TUM trajectory (body = IMU), evaluated like the VIO runs (repeatable)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    path = replay_runs(args.runs, args.out, args.every, args.max_frames, external=args.external)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it with: rerun {path}")
    return 0
