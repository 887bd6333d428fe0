"""The depth oracle ladder: does the depth-aided VIO get more accurate when its depth gets more accurate?

On simulated sequences (truth known), the depth front end's tracks are recorded once per seed; each rung then
replaces only the depth values attached to those tracks and re-runs the back end (pipeline/depth_oracle.py):

    depth-raw                 SGBM depth at every raw-valid feature (what the pipeline's depth-raw run gets)
    depth-raw@tracked-point   the same, only at features whose track is a consistent 3-D point
    exact@raw-valid           the tracked point's true depth at those same features
    exact-everywhere          the tracked point's true depth at every feature that has one (holes included)
    exact+1/3/10%             exact-everywhere × (1 + N(0, level)), σ stated to the filter
    inpainted[exact]          a perfect inpainting: SGBM where measured, the truth in the holes, flagged as fills
    inpainted[METHOD]         the inpainted map (raw where measured), as the depth-inpainted run gets it
    stereo                    the stereo front end (KLT left→right), for reference

ATE RMSE against the simulator's true IMU trajectory at the estimate's own stamps (SE(3); ``--against gt``: the
true antenna positions of the 5 Hz GT file, 20 ms, as a run is evaluated — whose pairing alone costs the true
trajectory ≈ 7 mm on a 10 s clip). The verdict
(``ladder monotone: yes|no``) checks every chain of rungs with paired per-seed differences
(pipeline/depth_oracle_run.ladder_verdict). Prints tables, writes JSON (default
<cache>/benchmarks/bench_depth_oracle.json). One core: BLAS threads pinned.

    .venv/bin/python benchmarks/bench_depth_oracle.py [--presets 02 03] [--seeds 0 1 2] [--duration 10]
        [--methods telea] [--config '{"depth_sigma_scale": 8.2}'] [--no-sigma] [--no-stereo]
        [--noise-levels 0.005 0.01 0.02 0.03 0.05] [--track-noise 0.01 0.03]
        [--structure] [--only-rungs depth-raw exact-everywhere ...] [--true-acc-bias] [--exact-pixels]

``--true-acc-bias`` (diagnostic): every back end, stereo included, gets the IMU with the simulator's accelerometer
bias subtracted and keeps its bias estimate at zero, so the table shows what the accelerometer-bias estimate costs
(a tilt error hides behind a bias error while the robot drives straight; the rungs' NEES split into tilt and yaw).

``--exact-pixels`` (diagnostic): every track that is a 3-D point gets the exact projection of that point as its pixels,
so the table separates what the KLT pixel errors of the observations a depth adds cost from what their depths cost.

``--structure`` adds diagnostic rungs that keep SGBM's errors at the tracked points but break their structure
(shuffled within a frame / within the run, random signs, or Gaussian at the raw σ; ``structure_rungs``).

``--non-point`` adds diagnostic rungs that split depth-raw by track class: the tracks that are not consistent 3-D
points read the exact map instead of SGBM (``raw+map@non-point``), or only they keep their SGBM depth
(``raw@non-point``; ``non_point_rungs``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.depth_oracle import (  # noqa: E402
    EXACT_SIGMA_REL,
    Rung,
    non_point_rungs,
    standard_rungs,
    structure_rungs,
)
from pipeline.depth_oracle_run import default_config, ladder_verdict  # noqa: E402
from pipeline.oracle_stage import AGAINSTS, check_line, ladder_checks, rung_table, sequence_ladder  # noqa: E402
from pipeline.oracle_truth import PINNED_ACC_BIAS  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["02", "03"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--methods", nargs="*", default=["telea"])
    ap.add_argument("--config", default=None, help="MSCKF overrides as a JSON mapping")
    ap.add_argument("--no-sigma", action="store_true", help="do not pass per-pixel depth σ to the filter")
    ap.add_argument("--no-stereo", action="store_true")
    ap.add_argument("--no-far-open", action="store_true",
                    help="keep the fills open to the far field (disable pipeline.depth_sigma's far-field rule)")
    ap.add_argument("--far-open-radius", type=int, default=None,
                    help="geodesic reach (px) of the far-field rule (default: pipeline.depth_sigma's)")
    ap.add_argument("--fill-edge-sigmas", type=float, default=None,
                    help="the occlusion-edge rule's threshold: drop fills whose raw neighbourhood spans more than this "
                         "many √2·σ_d of disparity (pipeline.depth_sigma.EDGE_DISPARITY_SIGMAS; 0 = rule off)")
    ap.add_argument("--noise-levels", nargs="+", type=float, default=[0.01, 0.03, 0.10],
                    help="σ_Z/Z of the exact+N%% rungs (per-frame noise, stated to the filter), e.g. 0.005 0.01 0.03")
    ap.add_argument("--track-noise", nargs="*", type=float, default=[],
                    help="extra rungs: exact depth with one relative error per track, e.g. 0.01 0.03")
    ap.add_argument("--structure", action="store_true",
                    help="extra diagnostic rungs: SGBM's errors at tracked points shuffled / sign-flipped / "
                         "replaced by Gaussian noise at the raw σ (pipeline.depth_oracle.structure_rungs)")
    ap.add_argument("--non-point", action="store_true",
                    help="extra diagnostic rungs: depth-raw split by track class — the non-point tracks read the "
                         "exact map instead of SGBM, or only they get their SGBM depth "
                         "(pipeline.depth_oracle.non_point_rungs)")
    ap.add_argument("--only-rungs", nargs="*", default=None, help="run only these rung names (e.g. to save time)")
    ap.add_argument("--true-acc-bias", action="store_true",
                    help="diagnostic: every back end gets the IMU without the simulator's accelerometer bias and "
                         "keeps its bias estimate at zero (what the accelerometer-bias estimate costs)")
    ap.add_argument("--exact-pixels", action="store_true",
                    help="diagnostic: each track that is a 3-D point gets the exact projection of that point as its "
                         "pixels (no KLT error), so the ladder tells what the pixels of the features a depth adds "
                         "cost apart from their depths (the stereo reference keeps its own tracks)")
    ap.add_argument("--against", choices=AGAINSTS, default="truth",
                    help="what ATE is measured against (default: truth): the bag's GT file (5 Hz antenna path, "
                         "nearest stamp within 20 ms, as a run) or the simulator's true IMU trajectory at the "
                         "estimate's own stamps (pipeline.depth_oracle.ate_against_truth: no association artifact; "
                         "the GT file scores even the true trajectory at ≈ 7 mm on a 10 s clip)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    cache = cache_dir()
    overrides = json.loads(args.config) if args.config else {}
    if args.true_acc_bias:
        overrides = {**overrides, **PINNED_ACC_BIAS}
    config = default_config(overrides)
    results: dict[str, dict] = {}
    extra: dict[str, dict] = {}
    sigma_overrides: dict[str, float | int] = {}
    if args.no_far_open or args.far_open_radius is not None:
        sigma_overrides["far_open_radius_px"] = 0 if args.no_far_open else args.far_open_radius
    if args.fill_edge_sigmas is not None:
        sigma_overrides["edge_disparity_sigmas"] = args.fill_edge_sigmas

    def ladder_rungs() -> list[Rung]:
        # built afresh for every preset: some rungs keep per-seed state (structure_rungs' error pools)
        rungs = standard_rungs(args.methods, noise_levels=args.noise_levels, track_noise_levels=args.track_noise)
        if args.structure:
            rungs += structure_rungs()
        if args.non_point:
            rungs += non_point_rungs()
        return rungs

    if args.only_rungs is not None:
        known = [r.name for r in ladder_rungs()]
        unknown = [n for n in args.only_rungs if n not in known]
        if unknown or not args.only_rungs:
            # (an empty selection would make the ladder fall back to every standard rung)
            ap.error(f"--only-rungs: {'no rung named' if args.only_rungs else 'name at least one rung'}"
                     f"{' ' + ', '.join(repr(n) for n in unknown) if unknown else ''} "
                     f"(rungs with these options: {', '.join(known)})")
    t0 = time.perf_counter()
    for p in args.presets:
        preset = p if p.startswith("rosario") or p == "tiny" else f"rosario-like-{p}"
        src = simulate_cached(preset, duration_s=args.duration, progress=False)
        rungs = ladder_rungs()
        if args.only_rungs is not None:
            rungs = [r for r in rungs if r.name in args.only_rungs]
        res, extra[preset] = sequence_ladder(src.sim_dir, cache, args.methods, config, args.seeds, rungs=rungs,
                                             use_sigma=not args.no_sigma, stereo=not args.no_stereo,
                                             max_frames=args.max_frames, sigma_overrides=sigma_overrides,
                                             true_acc_bias=args.true_acc_bias, exact_pixels=args.exact_pixels,
                                             against=args.against)
        results[preset] = res
        print(f"\n### {preset} ({len(args.seeds)} seeds, {args.duration:g} s; config {overrides or 'default'}; "
              f"ATE against {'the true IMU trajectory' if args.against == 'truth' else 'the GT file'}; "
              f"{'IMU without the true accelerometer bias; ' if args.true_acc_bias else ''}"
              f"{'exact pixels on 3-D-point tracks; ' if args.exact_pixels else ''}"
              f"σ to the filter: {'no' if args.no_sigma else 'yes'}; far-field fills: "
              f"{'kept' if args.no_far_open else 'dropped'}"
              f"{'' if args.far_open_radius is None else f', reach {args.far_open_radius} px'}"
              f"{'' if args.fill_edge_sigmas is None else f'; occlusion-edge rule {args.fill_edge_sigmas:g} σ'})")
        print("\n".join(rung_table(res, args.seeds)))
        for name, r in res.items():
            for seed, why in sorted(r.get("failed", {}).items()):
                print(f"failed: {name}, seed {seed}: {why}")
        tri = np.mean([v["triangulated"] for v in extra[preset]["truth"].values()])
        srel = np.mean([v.get("median_sigma_rel", np.nan) for v in extra[preset]["truth"].values()])
        print(f"\nobservations with a tracked-point truth: {tri:.1%} (the rest: tracks that are not a consistent "
              f"3-D point against the true poses, or outside the depth range); the truth's own σ_Z/Z at 0.5 px of "
              f"tracking noise: median {srel:.2%} (the exact rungs state {EXACT_SIGMA_REL:.1%})")
        for m, e in extra[preset]["depth_error_at_tracked_points"].items():
            print(f"depth at tracked points, {m}: median |rel. error| {e['median_abs_rel']:.2%}, "
                  f"median rel. error {e['median_rel']:+.2%} (n = {e['n']})")
    ok, bad = ladder_verdict(results)
    for b in bad:
        print("violation:", b)
    checks = ladder_checks(results)
    for preset, c in checks.items():
        print(check_line(preset, c))
    print(f"ladder monotone: {'yes' if ok else 'no'}")
    out = args.json or cache / "benchmarks" / "bench_depth_oracle.json"
    write_json_atomic(out, {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                            "config_overrides": overrides, "results": results, "extra": extra,
                            "monotone": ok, "violations": bad, "checks": checks,
                            "wall_s": time.perf_counter() - t0})
    print(f"JSON: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
