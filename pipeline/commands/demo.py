"""``agrivio demo`` (interim): write a small synthetic Rosario-layout bag, run the depth stage, print a summary.

Replaced by the end-to-end demo later. Takes a few seconds; data go to the agrivio cache dir.
"""

from __future__ import annotations

import argparse

import numpy as np

from pipeline.bag_reader import RosarioSequence
from pipeline.commands.depth import print_summary, run_depth
from pipeline.depth import DepthParams
from pipeline.depth_cache import depth_stream
from pipeline.paths import cache_dir
from pipeline.synthetic_scene import StereoRenderer, write_synthetic_bag

DEMO_FRAMES = 30


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help="interim demo: synthetic bag -> stereo depth stage -> summary")
    p.add_argument("--frames", type=int, default=DEMO_FRAMES, help=f"stereo frames to simulate ({DEMO_FRAMES})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    root = cache_dir()
    bag = root / "demo" / f"synthetic_{args.frames}f_seed0.bag"
    if not bag.exists():
        print(f"writing synthetic bag {bag} ({args.frames} stereo frames, IMU, GPS, odom, tf_static) ...")
        write_synthetic_bag(bag, n_frames=args.frames, seed=0, compression="lz4")
    seq = RosarioSequence(bag)
    print(f"bag                 {bag} ({seq.size_bytes / 1e6:.1f} MB, {seq.duration_s:.2f} s)")
    params = DepthParams()
    summary = run_depth(seq, params, cache=True, cache_root=root, max_frames=None, progress=True)
    print_summary(summary)

    # The synthetic scene knows its depth: check the stage against it (valid pixels only, holes stay holes).
    renderer = StereoRenderer(seq.calibration)
    errors = []
    for frame in depth_stream(seq, params, cache=True, progress=False, cache_root=root, stop_index=5):
        pose = np.eye(4)
        pose[0, 3] = 0.5 * (frame.stamp_ns - seq.start_ns) / 1e9  # write_synthetic_bag's default motion
        gt = renderer.rectified_depth(pose)
        m = frame.valid & np.isfinite(gt)
        errors.append(np.abs(frame.depth_m[m] - gt[m]) / gt[m])
    err = np.concatenate(errors)
    print(f"depth vs truth      median rel. error {np.median(err) * 100:.2f} %, "
          f"p95 {np.percentile(err, 95) * 100:.2f} % (first 5 frames, valid pixels)")
    return 0
