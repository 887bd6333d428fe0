"""Wall time of a sequence's depth preparation (SGBM depth + the inpainting methods), from an empty depth cache.

What ``agrivio experiment`` / ``run-sequence`` do before the runs of a sequence: the raw depth of every frame and
its inpainting with ``paper`` and ``telea`` (the experiment's default methods), all cached. Each measurement runs
``pipeline.run_sequence.run_matrix`` with no seeds (preparation only) in a fresh process on a fresh cache folder
whose ``sim/`` and ``quality/`` entries link to the real cache (the simulated bag is not re-made, its data-quality
pass not re-run), on ``--frames`` frames of the preset, with the default local pool (all cores).

Before/after in one run: ``--baseline-src DIR`` names a source tree of another version (e.g. ``git archive <commit>
| tar -x -C DIR``); the two trees alternate (``--repeats`` each), so both see the same machine load, and the
speed-up is the ratio of their median wall times. The stored depth streams of the two trees are compared byte for
byte (every layer of every frame of every cache).

Usage: .venv/bin/python benchmarks/bench_prepare.py [--preset rosario-like-02] [--duration 120] [--frames 96]
       [--methods paper,telea] [--repeats 2] [--baseline-src DIR] [--out PATH]
Prints a table and writes JSON (default: <cache>/benchmarks/bench_prepare.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_CHILD = """
import json, sys, time
sys.path.insert(0, {src!r})
from pathlib import Path
from pipeline.run_sequence import SequenceSpec, run_matrix
def main():
    root = Path({root!r})
    spec = SequenceSpec({preset!r}, duration_s={duration!r})
    t0 = time.perf_counter()
    run_matrix([spec], ["depth-raw", "depth-inpainted"], [], root / "out", root, inpaint_method={first!r},
               extra_inpaint_methods={rest!r}, max_frames={frames!r}, progress=False)
    print(json.dumps({{"wall_s": time.perf_counter() - t0}}))
if __name__ == "__main__":
    main()
"""


def _fresh_root(base: Path, cache: Path) -> Path:
    """A new cache folder whose ``sim/*`` and ``quality/*`` link to ``cache``'s."""
    root = Path(tempfile.mkdtemp(prefix="prep-", dir=base))
    for sub in ("sim", "quality"):
        (root / sub).mkdir()
        for entry in (cache / sub).glob("*"):
            (root / sub / entry.name).symlink_to(entry.resolve())
    return root


def _measure(src: Path, root: Path, args: argparse.Namespace, methods: list[str]) -> float:
    code = _CHILD.format(src=str(src), root=str(root), preset=args.preset, duration=args.duration,
                         first=methods[0], rest=methods[1:], frames=args.frames)
    script = root / "child.py"
    script.write_text(code)
    env = dict(os.environ, AGRIVIO_CACHE=str(root))
    out = subprocess.run([sys.executable, str(script)], cwd=src, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{src}: preparation failed:\n{out.stderr[-3000:]}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["wall_s"])


def _streams(root: Path) -> dict[str, bytes]:
    """Every stored array of every depth-cache chunk below ``root`` (relative path/array → bytes)."""
    import numpy as np

    found = {}
    for path in sorted((root / "depth").rglob("chunk_*.npz")):
        with np.load(path) as z:
            for name in z.files:
                found[f"{path.relative_to(root)}/{name}"] = z[name].tobytes()
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--methods", default="paper,telea")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--baseline-src", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from pipeline.paths import cache_dir
    from pipeline.sources import resolve_source

    cache = cache_dir()
    resolve_source(args.preset, duration_s=args.duration, cache_root=cache, progress=False)  # simulate once
    methods = [m for m in args.methods.split(",") if m]
    trees = [("current", ROOT)] + ([("baseline", args.baseline_src.resolve())] if args.baseline_src else [])
    base = Path(tempfile.mkdtemp(prefix="bench-prepare-"))
    walls: dict[str, list[float]] = {name: [] for name, _ in trees}
    last_root: dict[str, Path] = {}
    try:
        for r in range(args.repeats):
            order = trees if r % 2 == 0 else trees[::-1]
            for name, src in order:
                root = _fresh_root(base, cache)
                walls[name].append(_measure(src, root, args, methods))
                print(f"  {name} repeat {r + 1}: {walls[name][-1]:.1f} s", flush=True)
                if name in last_root:
                    shutil.rmtree(last_root[name], ignore_errors=True)
                last_root[name] = root
        identical = None
        if len(trees) == 2:
            a, b = _streams(last_root["current"]), _streams(last_root["baseline"])
            identical = a == b and len(a) > 0
    finally:
        shutil.rmtree(base, ignore_errors=True)
    rows = []
    for name, _ in trees:
        med = statistics.median(walls[name])
        rows.append({"tree": name, "source": str(dict(trees)[name]), "wall_s": walls[name], "median_s": med,
                     "ms_per_frame": 1e3 * med / args.frames})
    print(f"\npreparation of {args.frames} frames of {args.preset} ({args.duration:g} s): depth + "
          f"{', '.join(methods)}, fresh depth cache, {os.cpu_count()} cores")
    print(f"{'tree':10} {'median s':>9} {'ms/frame':>9}  runs")
    for row in rows:
        print(f"{row['tree']:10} {row['median_s']:9.1f} {row['ms_per_frame']:9.1f}  "
              + " ".join(f"{w:.1f}" for w in row["wall_s"]))
    result = {"preset": args.preset, "duration_s": args.duration, "frames": args.frames, "methods": methods,
              "repeats": args.repeats, "rows": rows, "host": platform.node(), "cpus": os.cpu_count(),
              "when": time.strftime("%Y-%m-%dT%H:%M:%S")}
    if len(rows) == 2:
        result["speedup"] = rows[1]["median_s"] / rows[0]["median_s"]
        result["caches_byte_identical"] = identical
        print(f"speed-up current vs baseline: {result['speedup']:.2f}×; stored caches byte-identical: {identical}")
    from pipeline.atomic import write_json_atomic

    out = args.out or cache / "benchmarks" / "bench_prepare.json"
    write_json_atomic(out, result)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
