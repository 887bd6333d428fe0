"""``agrivio batch CONFIG.yaml``: a matrix of sequences × variants × seeds, resumable, local or on Ray.

Config (paths relative to the config file)::

    out: runs/                    # run folders, records and the report
    runs: 5                       # seeds 0..4 (or `seeds: [0, 3, 7]`)
    variants: [stereo, depth-raw, depth-inpainted, odometry]
    inpaint: paper                # method of depth-inpainted
    msckf_config: null            # YAML of MSCKF overrides
    executor: local               # local | serial | ray   (the --executor flag wins)
    workers: null                 # local pool size (default: all cores)
    ray_address: null             # e.g. ray://head:10001 or auto; null starts a local Ray instance
    max_frames: null
    sequences:
      - source: rosario-like-01   # simulator preset ...
        duration: 30
      - source: /data/rosario/sequence01.bag   # ... or a bag (plain, compressed or byte-split stem)
        gt: /data/rosario/sequence01_gt.txt
        name: rosario-01

Killed and restarted with the same config, it redoes only the runs that have no record yet.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml

from pipeline.commands.compare import write_comparison_report
from pipeline.errors import AgrivioError
from pipeline.paths import cache_dir
from pipeline.run_sequence import DEFAULT_VARIANTS, SequenceSpec, run_matrix

_KEYS = {"out", "runs", "seeds", "variants", "inpaint", "msckf_config", "executor", "workers", "ray_address",
         "max_frames", "sequences"}
_SEQ_KEYS = {"source", "name", "gt", "camchain", "duration", "sim_seed"}


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("batch", help="run a sequences × variants × seeds matrix (resumable; local or Ray)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", type=Path, help="batch YAML (see the description)")
    p.add_argument("--executor", choices=("local", "serial", "ray"), default=None, help="override the config")
    p.add_argument("--workers", type=int, default=None, help="override the config's local pool size")
    p.add_argument("--ray-address", default=None, help="override the config's Ray address")
    p.set_defaults(func=run)


def _relative(base: Path, value: str | None) -> str | None:
    if value is None:
        return None
    p = Path(value).expanduser()
    if p.is_absolute():
        return str(p)
    candidate = base / p
    # a preset name is not a path: keep it as is unless a file of that name exists beside the config
    return str(candidate) if candidate.exists() or "/" in value or value.endswith((".bag", ".txt", ".yaml")) else value


def load_batch_config(path: Path) -> dict[str, Any]:
    """Read and check a batch YAML; errors name the file and the key."""
    try:
        cfg = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise AgrivioError(f"{path}: batch config not found") from None
    except yaml.YAMLError as exc:
        raise AgrivioError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(cfg, dict):
        raise AgrivioError(f"{path}: a batch config is a mapping (see `agrivio batch --help`)")
    unknown = set(cfg) - _KEYS
    if unknown:
        raise AgrivioError(f"{path}: unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(_KEYS))}")
    if not cfg.get("sequences"):
        raise AgrivioError(f"{path}: 'sequences' must list at least one sequence")
    if "out" not in cfg:
        raise AgrivioError(f"{path}: 'out' (output folder) is required")
    base = path.parent
    specs = []
    for i, item in enumerate(cfg["sequences"]):
        if isinstance(item, str):
            item = {"source": item}
        if not isinstance(item, dict) or "source" not in item:
            raise AgrivioError(f"{path}: sequences[{i}] needs a 'source' (bag path or preset)")
        bad = set(item) - _SEQ_KEYS
        if bad:
            raise AgrivioError(f"{path}: sequences[{i}]: unknown key(s) {', '.join(sorted(bad))}")
        specs.append(SequenceSpec(source=_relative(base, str(item["source"])), name=item.get("name"),
                                  gt=_relative(base, item.get("gt")), camchain=_relative(base, item.get("camchain")),
                                  duration_s=item.get("duration"), sim_seed=int(item.get("sim_seed", 0))))
    if "seeds" in cfg:
        seeds = [int(s) for s in cfg["seeds"]]
    else:
        seeds = list(range(int(cfg.get("runs", 5))))
    if not seeds:
        raise AgrivioError(f"{path}: no seeds to run")
    variants = cfg.get("variants", list(DEFAULT_VARIANTS))
    if isinstance(variants, str):
        variants = [v.strip() for v in variants.split(",")]
    return {"specs": specs, "seeds": seeds, "variants": list(variants), "out": base / str(cfg["out"]),
            "inpaint": cfg.get("inpaint", "paper"), "msckf_config": _relative(base, cfg.get("msckf_config")),
            "executor": cfg.get("executor", "local"), "workers": cfg.get("workers"),
            "ray_address": cfg.get("ray_address"), "max_frames": cfg.get("max_frames")}


def run(args: argparse.Namespace) -> int:
    cfg = load_batch_config(args.config)
    records = run_matrix(cfg["specs"], cfg["variants"], cfg["seeds"], cfg["out"], cache_dir(),
                         inpaint_method=cfg["inpaint"], msckf_config=cfg["msckf_config"],
                         executor=args.executor or cfg["executor"], workers=args.workers or cfg["workers"],
                         ray_address=args.ray_address or cfg["ray_address"], max_frames=cfg["max_frames"])
    report_dir, _ = write_comparison_report(cfg["out"], cfg["out"] / "report")
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    print(f"\n{len(records)} runs ({n_failed} failed). Report: {report_dir / 'report.html'}")
    return 0
