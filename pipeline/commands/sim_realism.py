"""``agrivio sim-realism``: simulate presets, run the depth stage on them, and report how realistic they are.

Writes ``realism.md``, ``realism.json`` and ``gallery_<preset>.png`` (left, right, exact depth, SGBM depth, holes
by cause) into the output folder. See ``pipeline/sim/realism.py`` for the measurements.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.errors import AgrivioError
from pipeline.rosario_layout import RATE_CAMERA_HZ


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


def _sequence(preset: str, args: argparse.Namespace):
    from pipeline.paths import cache_dir
    from pipeline.sim.presets import get_preset
    from pipeline.sim.sequence import SIM_VERSION, SimulatedSequence, resolve_config, simulate_sequence

    try:
        cfg = resolve_config(get_preset(preset), args.duration)
    except KeyError as exc:
        raise AgrivioError(str(exc.args[0])) from None
    root = cache_dir() / "sim" / f"{preset}-s{args.seed}-{cfg.duration_s:g}s-realism"
    if not args.resimulate and (root / "meta.json").is_file():
        seq = SimulatedSequence(root)
        # reuse only a sequence of this simulator version, configuration and seed
        if seq.meta.get("config") == json.loads(json.dumps(cfg.to_dict())) and seq.meta["seed"] == args.seed \
                and seq.meta.get("simulator_version") == SIM_VERSION:
            return seq
    workers = args.workers if args.workers is not None else min(2, os.cpu_count() or 1)
    return simulate_sequence(cfg, root, seed=args.seed, right_depth=True, progress=not args.quiet,
                             workers=workers)


def run(args: argparse.Namespace) -> int:
    import cv2

    from pipeline.atomic import atomic_path, write_json_atomic, write_text_atomic
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import DepthParams
    from pipeline.paths import cache_dir
    from pipeline.sim.realism import SequenceRealism, analyse_frame, gallery_png, klt_track_lengths, markdown

    if args.stride < 1 or args.klt_frames < 0:
        raise AgrivioError("sim-realism: --stride must be ≥ 1 and --klt-frames ≥ 0")
    out = args.out or cache_dir() / "sim_realism"
    params = DepthParams()
    summaries, per_frame = [], {}
    t0 = time.perf_counter()
    for preset in args.presets:
        seq = _sequence(preset, args)
        rig = seq.rig()
        cfg = seq.config
        first_moving = int(np.ceil((cfg.route.still_s + 0.5) * RATE_CAMERA_HZ))
        n = seq.n_frames
        gallery_index = min(n - 1, max(first_moving, int(0.6 * n)))
        rep = SequenceRealism(preset)
        klt_frames: list[np.ndarray] = []
        right = "rdepth" in seq.meta.get("depth", {}).get("stored", ["rdepth"])
        bar = tqdm(total=n, desc=f"realism {preset}", unit="frame", disable=args.quiet)
        with RosarioSequence(seq.bag_path, camchain=seq.camchain_path) as bag:
            for f in bag.stereo_frames():
                i = f.index
                if first_moving <= i < first_moving + args.klt_frames:
                    klt_frames.append(cv2.cvtColor(f.left_bgr, cv2.COLOR_BGR2GRAY))
                if i % args.stride == 0 or i == gallery_index:
                    try:
                        rd = seq.right_depth(i) if right else None
                    except KeyError:
                        rd, right = None, False
                    fr, d, causes = analyse_frame(i, rig, f.left_bgr, f.right_bgr, seq.depth(i), seq.labels(i),
                                                  seq.glare(i), params, rd)
                    if i % args.stride == 0:
                        rep.frames.append(fr)
                    if i == gallery_index:
                        png = gallery_png(f.left_bgr, f.right_bgr, seq.depth(i), d.depth_m, causes,
                                          f"{preset} frame {i} (holes {100 * fr.hole_ratio:.1f} %)")
                        with atomic_path(out / f"gallery_{preset}.png", suffix=".png") as tmp:
                            tmp.write_bytes(png)
                bar.update()
        bar.close()
        rep.klt = klt_track_lengths(klt_frames)
        s = rep.summary()
        s["sequence"] = str(seq.root)
        s["occlusion_from"] = "right exact depth" if right else "disparity jumps"
        summaries.append(s)
        per_frame[preset] = {"index": [f.index for f in rep.frames], "hole_ratio": [f.hole_ratio for f in rep.frames],
                             "fast_corners": [f.fast_corners for f in rep.frames]}
    note = (f"{args.duration:g} s per preset, seed {args.seed}, every {args.stride} frame(s) analysed; KLT over "
            f"{args.klt_frames} consecutive moving frames. Depth stage: pipeline.depth defaults "
            f"(SGBM {params.mode}, {params.num_disparities} disparities, block {params.block_size}, LR check).")
    write_text_atomic(out / "realism.md", markdown(summaries, note))
    write_json_atomic(out / "realism.json", {"summaries": summaries, "per_frame": per_frame, "note": note,
                                             "wall_s": time.perf_counter() - t0})
    print(markdown(summaries, note))
    print(f"written: {out / 'realism.md'}, {out / 'realism.json'}, gallery_<preset>.png")
    return 0
