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

Killed and restarted with the same config, it redoes only the runs without a reusable record: failed runs are
retried (``--keep-failed`` keeps them) and records made from other inputs are recomputed. A sequence whose inputs
are refused (unreadable bag, bad GT, ...) is recorded as failed runs with the reason and the others go on; the exit
status is then 1.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml

from pipeline.commands.report_summary import print_comparison
from pipeline.commands.run_sequence import failure_summary
from pipeline.errors import AgrivioError
from pipeline.paths import cache_dir
from pipeline.report_stage import write_comparison_report
from pipeline.run_sequence import DEFAULT_VARIANTS, SequenceSpec, run_matrix
from pipeline.validate import check_unknown_keys

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
    p.add_argument("--keep-failed", action="store_true",
                   help="keep failed run records instead of retrying them (default: retry)")
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
    check_unknown_keys(cfg, _KEYS, str(path), show_known=True)
    sequences = cfg.get("sequences")
    if not isinstance(sequences, list) or not sequences:
        raise AgrivioError(f"{path}: 'sequences' must be a list of at least one sequence (got "
                           f"{type(sequences).__name__}: {str(sequences)[:60]!r})")
    if "out" not in cfg or not isinstance(cfg["out"], str) or not cfg["out"].strip():
        raise AgrivioError(f"{path}: 'out' (output folder) is required and must be a path")
    base = path.parent
    specs = []
    for i, item in enumerate(sequences):
        if isinstance(item, str):
            item = {"source": item}
        if not isinstance(item, dict) or "source" not in item:
            raise AgrivioError(f"{path}: sequences[{i}] needs a 'source' (bag path or preset)")
        check_unknown_keys(item, _SEQ_KEYS, f"{path}: sequences[{i}]")
        where = f"{path}: sequences[{i}]"
        for key in ("source", "name", "gt", "camchain"):
            if item.get(key) is not None and not isinstance(item[key], str):
                raise AgrivioError(f"{where}.{key} must be a string, got {item[key]!r}")
        duration = item.get("duration")
        if duration is not None and (isinstance(duration, bool) or not isinstance(duration, (int, float))
                                     or not duration > 0):
            raise AgrivioError(f"{where}.duration must be a number of seconds > 0, got {duration!r}")
        specs.append(SequenceSpec(source=_relative(base, str(item["source"])), name=item.get("name"),
                                  gt=_relative(base, item.get("gt")), camchain=_relative(base, item.get("camchain")),
                                  duration_s=duration,
                                  sim_seed=_int(path, f"sequences[{i}].sim_seed", item.get("sim_seed", 0), 0)))
    if "seeds" in cfg:
        if not isinstance(cfg["seeds"], list):
            raise AgrivioError(f"{path}: 'seeds' must be a list of integers, got {cfg['seeds']!r}")
        seeds = [_int(path, "seeds[]", s, 0) for s in cfg["seeds"]]
        if len(set(seeds)) != len(seeds):
            raise AgrivioError(f"{path}: 'seeds' lists a seed twice: {cfg['seeds']!r}")
    else:
        seeds = list(range(_int(path, "runs", cfg.get("runs", 5), 1)))
    if not seeds:
        raise AgrivioError(f"{path}: no seeds to run")
    variants = cfg.get("variants", list(DEFAULT_VARIANTS))
    if isinstance(variants, str):
        variants = [v.strip() for v in variants.split(",") if v.strip()]
    if not isinstance(variants, list) or not variants or not all(isinstance(v, str) for v in variants):
        raise AgrivioError(f"{path}: 'variants' must be a list of variant names, got {cfg.get('variants')!r}")
    for key in ("inpaint", "msckf_config", "ray_address"):
        if cfg.get(key) is not None and not isinstance(cfg[key], str):
            raise AgrivioError(f"{path}: '{key}' must be a string, got {cfg[key]!r}")
    executor = cfg.get("executor", "local")
    if executor not in ("local", "serial", "ray"):
        raise AgrivioError(f"{path}: 'executor' must be local, serial or ray, got {executor!r}")
    workers = None if cfg.get("workers") is None else _int(path, "workers", cfg["workers"], 1)
    max_frames = None if cfg.get("max_frames") is None else _int(path, "max_frames", cfg["max_frames"], 1)
    return {"specs": specs, "seeds": seeds, "variants": list(variants), "out": base / str(cfg["out"]),
            "inpaint": cfg.get("inpaint", "paper"), "msckf_config": _relative(base, cfg.get("msckf_config")),
            "executor": executor, "workers": workers, "ray_address": cfg.get("ray_address"),
            "max_frames": max_frames}


def _int(path: Path, key: str, value: object, minimum: int) -> int:
    """``value`` as an integer ≥ ``minimum`` (YAML ints only: no strings, floats or booleans)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise AgrivioError(f"{path}: '{key}' must be an integer >= {minimum}, got {value!r}")
    return value


def run(args: argparse.Namespace) -> int:
    cfg = load_batch_config(args.config)
    records = run_matrix(cfg["specs"], cfg["variants"], cfg["seeds"], cfg["out"], cache_dir(),
                         inpaint_method=cfg["inpaint"], msckf_config=cfg["msckf_config"],
                         executor=args.executor or cfg["executor"], workers=args.workers or cfg["workers"],
                         ray_address=args.ray_address or cfg["ray_address"], max_frames=cfg["max_frames"],
                         keep_going=True, keep_failed=args.keep_failed)
    comparison = write_comparison_report(cfg["out"], cfg["out"] / "report")
    print_comparison(comparison)
    report_dir = comparison.out
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    print(f"\n{len(records)} runs ({n_failed} failed). Report: {report_dir / 'report.html'}")
    return failure_summary(records)
