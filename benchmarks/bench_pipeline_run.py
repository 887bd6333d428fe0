"""What a whole ``depth-*`` run costs inside the pipeline, per frame, with and without shared tracks (issue 16).

Runs ``agrivio run-sequence PRESET --variants depth-raw,depth-inpainted --runs 1 --executor serial`` (bag decode,
depth read, σ maps, VIO, frame log, evaluation, record: the pipeline's own code path, one process, one core)
twice per repeat, into fresh output folders with the same cache:

* ``live``: ``AGRIVIO_TRACK_CACHE=off``: both runs track features themselves (the behaviour before shared tracks);
* ``shared``: the ``depth-raw`` run tracks and records its tracks, the ``depth-inpainted`` run replays them
  (:mod:`pipeline.track_cache`; the recording is deleted before each repeat so that it is made again).

The two modes alternate (live first on even repeats, shared first on odd ones) so both see the same machine load.
Per run it reads the record's ``frame_ms_median`` (VIO time per frame: front end + depth read + back end) and
``run_s`` (the whole run: bag decode, IMU, depth read, VIO, frame log), and checks that each shared run's
``estimate.tum`` is byte-identical to the live run's.

    .venv/bin/python benchmarks/bench_pipeline_run.py [--preset rosario-like-02] [--duration 120]
        [--method paper] [--repeats 2] [--json PATH]

Prints a table of medians over the repeats and writes JSON (default ``<cache>/benchmarks/bench_pipeline_run.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.cli import main as agrivio  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.run_job import TRACK_CACHE_ENV  # noqa: E402

VARIANTS = ("depth-raw", "depth-inpainted")


def _argv(args: argparse.Namespace, out: Path) -> list[str]:
    """``run-sequence`` of both depth variants, one seed, in this process, into ``out``."""
    return ["run-sequence", args.preset, "--duration", str(args.duration), "--variants", ",".join(VARIANTS),
            "--inpaint", args.method, "--runs", "1", "--executor", "serial", "--out", str(out)]


def _run(mode: str, out: Path, args: argparse.Namespace) -> dict[str, dict]:
    """One ``run-sequence`` of both depth variants in ``mode``; each run's record by variant."""
    if mode == "shared":
        shutil.rmtree(cache_dir() / "tracks", ignore_errors=True)  # record afresh: the first run must track
        os.environ.pop(TRACK_CACHE_ENV, None)
    else:
        os.environ[TRACK_CACHE_ENV] = "off"
    try:
        code = agrivio(_argv(args, out))
    finally:
        os.environ.pop(TRACK_CACHE_ENV, None)
    if code != 0:
        raise SystemExit(f"run-sequence failed ({code}) in mode {mode}")
    name = args.preset
    return {v: json.loads((out / name / v / "seed0" / "record.json").read_text()) for v in VARIANTS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--method", default="paper", help="inpainting method of the depth-inpainted run")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows: dict[tuple[str, str], list[dict]] = {}
    identical: list[bool] = []
    with tempfile.TemporaryDirectory(prefix="bench_pipeline_run_") as tmp:
        agrivio(_argv(args, Path(tmp) / "warm"))  # simulation, depth and inpainting cached; numba kernels compiled
        for rep in range(args.repeats):
            order = ("live", "shared") if rep % 2 == 0 else ("shared", "live")
            got = {}
            for mode in order:
                t0 = time.perf_counter()
                got[mode] = _run(mode, Path(tmp) / f"{mode}{rep}", args)
                print(f"repeat {rep}: {mode} {time.perf_counter() - t0:.1f} s", flush=True)
            for mode, recs in got.items():
                for v, rec in recs.items():
                    rows.setdefault((mode, v), []).append(rec)
            for v in VARIANTS:
                a, b = (Path(tmp) / f"{m}{rep}" / args.preset / v / "seed0" / "estimate.tum"
                        for m in ("live", "shared"))
                identical.append(a.read_bytes() == b.read_bytes())
    table = []
    print(f"\n{args.preset}, {args.duration:g} s, depth-inpainted = {args.method}, {args.repeats} repeat(s), "
          f"one process, one core; medians over repeats")
    print(f"{'mode':8s} {'variant':16s} {'tracks':9s} {'frame ms':>9s} {'run s':>7s} {'frames':>7s}  run s per repeat")
    for (mode, v), recs in sorted(rows.items()):
        frame_ms = statistics.median(r["timings"]["frame_ms_median"] for r in recs)
        run_s = statistics.median(r["timings"]["run_s"] for r in recs)
        tracks = "/".join(sorted({str(r.get("tracks")) for r in recs}))
        each = [round(r["timings"]["run_s"], 1) for r in recs]
        table.append({"mode": mode, "variant": v, "tracks": tracks, "frame_ms_median": frame_ms, "run_s": run_s,
                      "run_s_each": each, "frames": recs[0].get("frames"),
                      "ate_rmse_m": recs[0]["metrics"].get("ate_rmse_m")})
        print(f"{mode:8s} {v:16s} {tracks:9s} {frame_ms:9.1f} {run_s:7.1f} {recs[0].get('frames')!s:>7s}  "
              f"(each: {', '.join(f'{x:.1f}' for x in each)})")
    by = {(r["mode"], r["variant"]): r for r in table}
    ratios = {v: by[("live", v)]["run_s"] / by[("shared", v)]["run_s"] for v in VARIANTS}
    both_live = sum(by[("live", v)]["run_s"] for v in VARIANTS)
    both_shared = sum(by[("shared", v)]["run_s"] for v in VARIANTS)
    print("run time live / shared: " + ", ".join(f"{v} {r:.2f}×" for v, r in ratios.items())
          + f"; both runs {both_live / both_shared:.2f}×")
    print(f"estimates byte-identical live vs shared: {sum(identical)} of {len(identical)}")
    out = args.json or cache_dir() / "benchmarks" / "bench_pipeline_run.json"
    write_json_atomic(out, {"preset": args.preset, "duration_s": args.duration, "method": args.method,
                            "repeats": args.repeats, "rows": table, "run_time_ratio_live_over_shared": ratios,
                            "both_runs_ratio": both_live / both_shared, "identical": identical,
                            "machine": platform.platform(), "cpus": os.cpu_count()})
    print(f"written: {out}")


if __name__ == "__main__":
    main()
