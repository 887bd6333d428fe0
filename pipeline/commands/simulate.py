"""``agrivio simulate``: render a Rosario-like soybean-field sequence (bag, calibration, ground truth, depth)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from pipeline.errors import AgrivioError


def register(subparsers: argparse._SubParsersAction) -> None:
    from pipeline.sim.presets import preset_names

    p = subparsers.add_parser(
        "simulate", help="simulate a Rosario-like sequence (bag + GT + exact depth [+ EuRoC])",
        description="Render a soybean-field sequence through the Rosario stereo rig and write a Rosario-layout "
                    "bag, the Kalibr camchain, TUM ground truth (antenna, like the real one, and full 6-DoF body), "
                    "the exact depth of every left frame, and optionally an EuRoC/ASL folder.")
    p.add_argument("preset", nargs="?", default="rosario-like-01",
                   help=f"preset name ({', '.join(preset_names())}); default rosario-like-01")
    p.add_argument("--config", type=Path, default=None,
                   help="JSON file with a full or partial config (sections as in meta.json 'config') applied on "
                        "top of the preset")
    p.add_argument("--seed", type=int, default=0, help="noise/vibration/world seed (default 0)")
    p.add_argument("--duration", type=float, default=None, help="seconds (default: the preset's)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default <cache>/sim/<preset>-s<seed>-<duration>s)")
    p.add_argument("--compression", choices=("none", "lz4", "bz2"), default="none",
                   help="bag chunk compression (the served Rosario bags are BZ2; it is slow to write)")
    p.add_argument("--euroc", action="store_true", help="also write an EuRoC/ASL folder")
    p.add_argument("--right-depth", action="store_true", help="also store the rectified right depth")
    p.add_argument("--workers", type=int, default=None,
                   help="render processes (default: min(2, CPU count)); results do not depend on it")
    p.add_argument("--max-frames", type=int, default=None, help="render only the first N stereo frames")
    p.add_argument("--ae-warmup", type=int, default=3, help="renders of frame 0 to settle auto exposure (3)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _config(args: argparse.Namespace):
    from pipeline.sim.config import SimConfig
    from pipeline.sim.presets import get_preset

    try:
        cfg = get_preset(args.preset)
    except KeyError as exc:
        raise AgrivioError(str(exc.args[0])) from None
    if args.config is not None:
        if not args.config.is_file():
            raise AgrivioError(f"{args.config}: config file not found")
        try:
            patch = json.loads(args.config.read_text())
        except json.JSONDecodeError as exc:
            raise AgrivioError(f"{args.config}: not valid JSON ({exc})") from None
        base = cfg.to_dict()
        for key, value in patch.items():
            if isinstance(value, dict) and isinstance(base.get(key), dict):
                base[key].update(value)
            else:
                base[key] = value
        try:
            cfg = SimConfig.from_dict(base)
        except (TypeError, ValueError) as exc:
            raise AgrivioError(f"{args.config}: {exc}") from None
    return cfg


def run(args: argparse.Namespace) -> int:
    from pipeline.sim.sequence import simulate_sequence

    cfg = _config(args)
    workers = args.workers if args.workers is not None else min(2, os.cpu_count() or 1)
    seq = simulate_sequence(cfg, args.out, seed=args.seed, duration_s=args.duration,
                            compression=None if args.compression == "none" else args.compression,
                            export_euroc=args.euroc, progress=not args.quiet, right_depth=args.right_depth,
                            max_frames=args.max_frames, workers=workers, ae_warmup=args.ae_warmup)
    m = seq.meta
    print(f"sequence   {seq.root}")
    print(f"bag        {seq.bag_path.name} ({seq.bag_path.stat().st_size / 1e6:.1f} MB, {m['duration_s']:g} s, "
          f"{m['counts']['frames']} stereo frames, {m['counts']['imu']} IMU, {m['counts']['gps']} GPS, "
          f"{m['counts']['odom']} odometry)")
    print(f"truth      {seq.gt_path.name} (antenna, like the real GT), {seq.body_gt_path.name} (6-DoF IMU), "
          f"depth/ (exact, rectified left)")
    if seq.euroc_path is not None:
        print(f"euroc      {seq.euroc_path}")
    print(f"wall time  {m['wall_s']:.1f} s ({m['counts']['frames'] / max(m['wall_s'], 1e-9):.2f} frames/s)")
    return 0
