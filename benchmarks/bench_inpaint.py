"""Speed of the depth-inpainting methods on 672×376 frames with 15–25 % holes (prints a table, writes JSON).

Usage: ``python benchmarks/bench_inpaint.py [--frames N] [--repeats R] [--methods a,b] [--out FILE]``

Frames: procedural field depth (``inpaint.synthetic``) with seeded masks at 15, 20 and 25 % (mixed blobs /
stripes / specks, and blobs). Each method runs ``repeats`` times per frame; the table gives the median seconds per
frame over all runs, and each method's ratio to EBM (Criminisi) measured in the same run. Machine load is not
controlled: compare ratios, not absolute times, across runs.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from inpaint import inpaint  # noqa: E402
from inpaint.masks import random_mask  # noqa: E402
from inpaint.synthetic import field_depth  # noqa: E402
from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402

ALL = ("paper", "ebm", "biharmonic", "telea", "ns", "ipbasic")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--methods", default=",".join(ALL))
    ap.add_argument("--paper-options", default="", help="extra options for paper, e.g. fusion=mean")
    ap.add_argument("--out", type=Path, default=cache_dir() / "benchmarks" / "bench_inpaint.json")
    args = ap.parse_args(argv)
    methods = args.methods.split(",")
    paper_opts = dict(kv.split("=") for kv in args.paper_options.split(",") if kv)
    cases = []
    ratios = (0.15, 0.20, 0.25)
    for i in range(args.frames):
        f = field_depth(376, 672, seed=500 + i)
        ratio = ratios[i % len(ratios)]
        mask = random_mask(f.depth.shape, ratio, "mixed" if i % 2 == 0 else "blobs", seed=600 + i)
        cases.append((np.where(mask, np.nan, f.depth).astype(np.float32), mask))
    times: dict[str, list[float]] = {m: [] for m in methods}
    for depth, mask in cases:
        for _ in range(args.repeats):
            for m in methods:
                t0 = time.perf_counter()
                inpaint(depth, mask, method=m, **(paper_opts if m == "paper" else {}))
                times[m].append(time.perf_counter() - t0)
    med = {m: float(np.median(v)) for m, v in times.items()}
    base = med.get("ebm")
    print(f"{'method':12s} {'median s/frame':>15s} {'vs EBM':>8s}   (672×376, holes 15–25 %, {args.frames} frames × "
          f"{args.repeats} repeats)")
    for m in methods:
        ratio = f"{med[m] / base:8.3f}" if base else "       -"
        print(f"{m:12s} {med[m]:15.3f} {ratio}")
    out = {"median_s": med, "ratio_to_ebm": {m: (med[m] / base if base else None) for m in methods},
           "runs": times, "frames": args.frames, "repeats": args.repeats, "hole_ratios": list(ratios),
           "size": [376, 672], "paper_options": paper_opts, "cpu_count": os.cpu_count(),
           "platform": platform.platform(), "load_avg": os.getloadavg()}
    write_json_atomic(args.out, out)
    print(f"written: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
