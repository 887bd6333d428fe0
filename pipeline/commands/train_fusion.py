"""``agrivio train-fusion``: train the paper's block-fusion network and write the shipped weights + record."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from tqdm import tqdm

from pipeline.atomic import atomic_path, write_json_atomic
from pipeline.errors import AgrivioError

#: Network size of the coarse-to-fine method's fusion (the PLIP-softmax architecture of inpaint.fusion_net with
#: fewer channels): it runs on every hole block of every level, so it must be cheap (738 parameters; a 4-channel
#: decoder since issue 12, the 8-channel one measured no better).
C2F_NET = {"features": 4, "growth": 4, "dense_layers": 1, "hidden": 4}


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train-fusion", help="train the inpainting fusion network (self-supervised, CPU)",
        description="Hide known depth with realistic masks, run the paper's fill, and train the fusion network "
                    "to reconstruct the hidden blocks. Writes fusion_net.pt and fusion_net.json.")
    p.add_argument("--formulation", choices=("c2f", "greedy"), default="c2f",
                   help="whose candidates the net learns to fuse: 'c2f' (method paper, writes fusion_net_c2f.*) or "
                        "'greedy' (method paper-greedy, writes fusion_net.*)")
    p.add_argument("--source", choices=("auto", "sim", "procedural", "mixed", "mixed-rooms"), default="mixed",
                   help="training depth: 'mixed' (default: procedural fields + procedural object scenes + simulator "
                        "frames, a third each; the shipped c2f weights), 'mixed-rooms' (the same and procedural rooms "
                        "/ corridors, a quarter each), 'procedural' (fields only: the shipped greedy weights), 'sim'")
    p.add_argument("--frames", type=int, default=20, help="number of ground-truth frames")
    p.add_argument("--masks-per-frame", type=int, default=2)
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--max-minutes", type=float, default=5.0, help="cap on the optimisation loop (wall clock)")
    p.add_argument("--max-examples", type=int, default=40000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clamp-training", action="store_true",
                   help="c2f: train through the per-pixel candidate-range clamp that the method applies (measured "
                        "worse on the simulator benchmark than training without it: 0.904 vs 0.888 m hole RMSE)")
    p.add_argument("--noise-fraction", type=float, default=0.0,
                   help="c2f: share of the masks whose known pixels carry stereo-matching noise (ground truth exact)")
    p.add_argument("--hidden", type=int, default=None,
                   help=f"decoder channels of the c2f network (default {C2F_NET['hidden']})")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: the package's inpaint/weights, i.e. the shipped weights)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def _frames(source: str, n: int, seed: int):
    from inpaint.train import TrainingFrame

    if source in ("mixed", "mixed-rooms"):
        from inpaint.synthetic import field_depth, object_depth, room_depth

        rooms = source == "mixed-rooms"
        k = max(1, n // (4 if rooms else 3))
        frames = [TrainingFrame(f.depth, f.valid) for f in (field_depth(seed=10_000 + seed * 1000 + i)
                                                             for i in range(k))]
        frames += [TrainingFrame(f.depth, f.valid) for f in (object_depth(seed=20_000 + seed * 1000 + i)
                                                              for i in range(k))]
        desc = (f"{k} procedural field maps (field_depth seeds {10_000 + seed * 1000}..), {k} procedural object "
                f"scenes (object_depth seeds {20_000 + seed * 1000}..)")
        if rooms:
            frames += [TrainingFrame(f.depth, f.valid) for f in (room_depth(seed=30_000 + seed * 1000 + i)
                                                                  for i in range(k))]
            desc += f", {k} procedural rooms / corridors (room_depth seeds {30_000 + seed * 1000}..)"
        try:
            from pipeline.inpaint_bench import sim_training_frames
        except ImportError:
            return frames, desc + "; simulator not available"
        sim, sdesc = sim_training_frames(n - len(frames), seed=seed, progress=True)
        return frames + sim, desc + "; " + sdesc

    if source in ("auto", "sim"):
        try:
            from pipeline.inpaint_bench import sim_training_frames
        except ImportError:
            sim_training_frames = None
        if sim_training_frames is not None:
            frames, desc = sim_training_frames(n, seed=seed, progress=True)
            return frames, desc
        if source == "sim":
            raise AgrivioError("train-fusion: --source sim needs the simulator (pipeline/sim), which is not available")
    from inpaint.synthetic import field_depth

    frames = [TrainingFrame(f.depth, f.valid) for f in (field_depth(seed=10_000 + seed * 1000 + i) for i in range(n))]
    return frames, (f"{n} procedural field depth maps (inpaint.synthetic.field_depth, seeds "
                    f"{10_000 + seed * 1000}..{10_000 + seed * 1000 + n - 1}; 376×672; the simulator was not used)")


def _c2f_net(args: argparse.Namespace) -> dict:
    net = dict(C2F_NET)
    if args.hidden is not None:
        if args.hidden < 1:
            raise AgrivioError("train-fusion: --hidden must be ≥ 1")
        net["hidden"] = args.hidden
    return net


def run(args: argparse.Namespace) -> int:
    from inpaint.fusion_net import WEIGHTS_DIR
    from inpaint.train import TrainConfig, collect_examples, train_fusion

    if args.frames < 1 or args.masks_per_frame < 1 or args.epochs < 1:
        raise AgrivioError("train-fusion: --frames, --masks-per-frame and --epochs must be ≥ 1")
    t0 = time.perf_counter()
    frames, desc = _frames(args.source, args.frames, args.seed)
    c2f = args.formulation == "c2f"
    cfg = TrainConfig(seed=args.seed, masks_per_frame=args.masks_per_frame, epochs=args.epochs,
                      max_seconds=args.max_minutes * 60.0, max_examples=args.max_examples,
                      formulation=args.formulation, net=_c2f_net(args) if c2f else {}, clamp=args.clamp_training,
                      noise_fraction=args.noise_fraction if c2f else 0.0)
    bar = tqdm(total=len(frames) * cfg.masks_per_frame, desc="collect blocks", disable=args.quiet)
    ex = collect_examples(frames, cfg, progress=lambda d, n: bar.update(d - bar.n))
    bar.close()
    t_collect = time.perf_counter() - t0
    bar = tqdm(total=cfg.epochs, desc="train", disable=args.quiet)
    res = train_fusion(ex, cfg, progress=lambda e, n, v: (bar.set_postfix_str(f"val {v:.4f}"), bar.update()))
    bar.close()
    meta = dict(res.meta)
    meta["training_data"] = desc
    meta["collect_wall_s"] = t_collect
    meta["total_wall_s"] = time.perf_counter() - t0
    meta["formulation"] = args.formulation
    out = args.out or WEIGHTS_DIR
    stem = "fusion_net_c2f" if c2f else "fusion_net"
    with atomic_path(out / f"{stem}.pt", suffix=".pt") as tmp:
        tmp.write_bytes(res.weights_bytes())
    write_json_atomic(out / f"{stem}.json", meta)
    print(f"examples {meta['n_examples']}  epochs {meta['epochs_run']}  final train loss {meta['final_train_loss']:.4f}"
          f"  val loss {meta['final_val_loss']:.4f} (softmax-mean fusion {meta['val_loss_softmax_mean_fusion']:.4f},"
          f" best single block {meta['val_loss_best_single_block']:.4f})  wall {meta['total_wall_s']:.0f} s")
    print(f"written: {out / (stem + '.pt')}, {out / (stem + '.json')}")
    return 0
