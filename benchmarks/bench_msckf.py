"""Benchmark the MSCKF back end on the simulated feature world (msckf/synthetic.py): speed, accuracy
ablations, and a longer Monte-Carlo NEES check.

Speed: per-frame time of ``MsckfFilter.feed_features`` (IMU propagation, augmentation, lost-feature update,
pruning — the whole back end) at Rosario feature counts, median / p95 / mean after the window has filled.
Wall time and process CPU time are both reported (the CPU time is the fairer figure on a shared machine).
The baseline, measured in the same run, is ``update_method="qr"``: the literal S-MSCKF update (per-feature QR
null space, stacked QR, Joseph form) inside the same filter.

Ablations (accuracy): χ² gate / feature-noise pairings (ours vs S-MSCKF's 5 % quantile), OC-EKF on/off, and for
depth-map observations the inverse-depth row on/off. World: 2 % of observations are 30-px outliers; metric:
position RMSE over the run (the filter starts at the true state, so no alignment) and final error / distance.

One core: BLAS threads are pinned to 1 before numpy is imported.

    .venv/bin/python benchmarks/bench_msckf.py [--quick] [--json PATH]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from msckf.filter import MsckfFilter  # noqa: E402
from msckf.synthetic import FX, anees_bounds, make_world, nees_run, perturbed_filter  # noqa: E402
from msckf.synthetic import matched_config as _config  # noqa: E402
from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402

WARMUP_FRAMES = 25


def _run(world, cfg):
    """Feed a world; per frame, time (wall and process CPU) the IMU samples fed since the last image plus
    ``feed_features`` — everything the back end does for that frame."""
    flt = MsckfFilter(cfg, world.T_cam0_imu, world.T_cam1_cam0)
    flt.initialize(world.t0, world.R0, world.p0, world.v0, world.b_g0, world.b_a0, 9.81)
    times, cpu, stages, err, used = [], [], {}, [], []
    i = 0
    for m, obs in enumerate(world.frames):
        t0, c0 = time.perf_counter(), time.process_time()
        while i < len(world.imu_t) and world.imu_t[i] <= obs.stamp_s:
            flt.feed_imu(world.imu_t[i], world.gyro[i], world.acc[i])
            i += 1
        pose = flt.feed_features(obs)
        t1, c1 = time.perf_counter(), time.process_time()
        st = flt.last_stats
        if m >= WARMUP_FRAMES:
            times.append((t1 - t0) * 1e3)
            cpu.append((c1 - c0) * 1e3)
            for k, v in st.timings.items():
                stages.setdefault(k, []).append(v * 1e3)
        err.append(np.linalg.norm(pose.p_world - world.p_w[m]))
        used.append(st.n_lost_used + st.n_pruned_used)
    dist = float(np.sum(np.linalg.norm(np.diff(world.p_w, axis=0), axis=1)))
    return dict(times=np.array(times), cpu=np.array(cpu), stages={k: float(np.median(v)) for k, v in stages.items()},
                rmse=float(np.sqrt(np.mean(np.square(err)))), final=float(err[-1]), dist=dist,
                used=float(np.mean(used)), resets=flt.n_online_resets)


def speed(args) -> list[dict]:
    counts = (100, 300) if args.quick else (100, 300, 600, 1000)
    rows = []
    print("\n== back-end time per frame (ms), simulated world, stereo observations ==")
    print(f"{'features':>8} {'method':>7} {'median':>8} {'p95':>8} {'mean':>8} {'cpu med':>8} {'cpu p95':>8} "
          f"{'fps(med)':>9} {'qr/this':>8}  stages (median ms, wall)")
    for nf in counts:
        w = make_world(seed=0, duration=args.duration, max_features=nf, n_landmarks=max(4000, 12 * nf),
                       track_end_prob=0.05)
        feats = float(np.mean([len(f) for f in w.frames[WARMUP_FRAMES:]]))
        res = {}
        for method in ("schur", "qr"):
            res[method] = _run(w, _config(update_method=method))
        for method in ("schur", "qr"):
            t, c = res[method]["times"], res[method]["cpu"]
            ratio = float(np.median(res["qr"]["cpu"]) / np.median(c))
            row = dict(features=feats, method=method, median_ms=float(np.median(t)),
                       p95_ms=float(np.percentile(t, 95)), mean_ms=float(np.mean(t)),
                       cpu_median_ms=float(np.median(c)), cpu_p95_ms=float(np.percentile(c, 95)),
                       fps=float(1e3 / np.median(t)), qr_cpu_over_this=ratio, stages_ms=res[method]["stages"],
                       rmse_m=res[method]["rmse"], frames=len(t))
            rows.append(row)
            stg = " ".join(f"{k}={v:.2f}" for k, v in row["stages_ms"].items() if k != "total")
            print(f"{feats:8.0f} {method:>7} {row['median_ms']:8.2f} {row['p95_ms']:8.2f} {row['mean_ms']:8.2f} "
                  f"{row['cpu_median_ms']:8.2f} {row['cpu_p95_ms']:8.2f} {row['fps']:9.1f} {ratio:8.2f}  {stg}")
    return rows


ABLATIONS = [
    # name, world kind, config overrides
    ("ours: chi2 0.95, dof=rows, sigma 1 px", "stereo", dict()),
    ("S-MSCKF gate: chi2 0.05, dof=#obs-1, sigma 1 px", "stereo", dict(chi2_quantile=0.05, chi2_dof="observations")),
    ("S-MSCKF Rosario pair: chi2 0.05, dof=#obs-1, sigma 0.035", "stereo",
     dict(chi2_quantile=0.05, chi2_dof="observations", feature_noise=0.035)),
    ("chi2 0.95, dof=rows, sigma 0.035 (Rosario sigma)", "stereo", dict(feature_noise=0.035)),
    ("chi2 0.95, dof=rows, sigma 0.007 (default, 2.5 px)", "stereo", dict(feature_noise=0.007)),
    ("ours without OC-EKF", "stereo", dict(observability_constrained=False)),
    ("ours, S-MSCKF 1500-row cap", "stereo", dict(max_update_rows=1500)),
    ("depth map -> virtual stereo (depth_row off)", "depth", dict()),
    ("depth map -> inverse-depth row (depth_row on)", "depth", "depth_row"),
    ("depth map, depth_row off, no depth seed", "depth", dict(depth_seed=False)),
]


def ablations(args) -> list[dict]:
    seeds = range(2 if args.quick else 4)
    fb = FX * 0.1187
    disp_sigma = 0.5
    rows = []
    print(f"\n== accuracy ablations: {args.ablation_features} features, {args.duration:.0f} s, 2 % 30-px outliers, "
          f"{len(seeds)} seeds (mean) ==")
    print(f"{'variant':<58} {'RMSE m':>8} {'final/dist %':>13} {'used/frame':>11} {'ms/frame':>9}")
    worlds = {}
    for name, kind, over in ABLATIONS:
        if over == "depth_row":
            over = dict(depth_row=True, depth_inv_sigma=disp_sigma / fb, depth_rel_sigma=0.0)
        acc = []
        for s in seeds:
            key = (kind, s)
            if key not in worlds:
                worlds[key] = make_world(seed=s, world_seed=100 + s, duration=args.duration,
                                         max_features=args.ablation_features, outlier_fraction=0.02,
                                         depth_mode=kind == "depth", depth_disp_sigma_px=disp_sigma)
            acc.append(_run(worlds[key], _config(**over)))
        row = dict(variant=name, world=kind, overrides=over, rmse_m=float(np.mean([a["rmse"] for a in acc])),
                   final_over_dist=float(np.mean([a["final"] / a["dist"] for a in acc])),
                   used_per_frame=float(np.mean([a["used"] for a in acc])),
                   ms_per_frame=float(np.mean([np.median(a["times"]) for a in acc])),
                   rmse_per_seed=[a["rmse"] for a in acc])
        rows.append(row)
        print(f"{name:<58} {row['rmse_m']:8.3f} {100 * row['final_over_dist']:13.2f} {row['used_per_frame']:11.1f} "
              f"{row['ms_per_frame']:9.2f}")
    return rows


def _with_stated_depth_sigma(w, disp_sigma_px: float, fb: float):
    """The world's depth observations with their σ_Z stated (disparity model: Z² σ_d / (f·b))."""
    import dataclasses

    frames = [dataclasses.replace(o, depth_sigma_m=np.where(np.isfinite(o.depth_m), o.depth_m ** 2 * disp_sigma_px / fb,
                                                            np.nan)) for o in w.frames]
    return dataclasses.replace(w, frames=frames)


#: NEES cases: name → (observation kind, config overrides)
NEES_CASES = {
    "oc": ("stereo", dict(observability_constrained=True)),
    "standard_ekf": ("stereo", dict(observability_constrained=False)),
    "depth_virtual_stereo": ("depth", dict(observability_constrained=True)),
    "depth_inverse_depth_row": ("depth", dict(observability_constrained=True, depth_row=True)),
}


def nees(args) -> dict:
    n_runs, duration = (6, 8.0) if args.quick else (args.nees_runs, args.nees_duration)
    P0 = np.r_[[1e-4] * 3, [1e-6] * 3, [1e-3] * 3, [1e-4] * 3, [1e-4] * 3, [3.0462e-4] * 3, [2.5e-5] * 3]
    disp_sigma = 0.5
    out = {}
    for case, (kind, over) in NEES_CASES.items():
        npos, nrot = [], []
        for seed in range(n_runs):
            w = make_world(seed=seed, world_seed=0, duration=duration, max_features=150,
                           depth_mode=kind == "depth", depth_disp_sigma_px=disp_sigma if kind == "depth" else 0.0)
            if kind == "depth":
                fb = FX * float(np.linalg.norm(w.T_cam1_cam0[:3, 3]))
                w = _with_stated_depth_sigma(w, disp_sigma, fb)
            flt = perturbed_filter(w, _config(**over), P0, np.random.default_rng(500 + seed))
            a, b = nees_run(w, flt)
            npos.append(a)
            nrot.append(b)
        lo, hi = anees_bounds(n_runs)
        res = {}
        for name, arr in (("position", npos), ("orientation", nrot)):
            an = np.mean(arr, axis=0)
            res[name] = dict(anees_mean=float(an.mean()), anees_last_second=float(an[-15:].mean()),
                             frac_in_bounds=float(np.mean((an > lo) & (an < hi))))
        res["bounds"] = [float(lo), float(hi)]
        out[case] = res
    print(f"\n== NEES, {n_runs} Monte-Carlo runs x {duration:.0f} s (expected 3; 95 % bounds "
          f"[{out['oc']['bounds'][0]:.2f}, {out['oc']['bounds'][1]:.2f}]; depth cases: every observation has a "
          f"depth with {disp_sigma} px disparity noise, σ stated) ==")
    for k, r in out.items():
        for name in ("position", "orientation"):
            q = r[name]
            print(f"{k:>24} {name:<12} ANEES mean {q['anees_mean']:.2f}  last 1 s {q['anees_last_second']:.2f}  "
                  f"in bounds {100 * q['frac_in_bounds']:.0f} %")
    out["runs"], out["duration_s"] = n_runs, duration
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer counts, seeds and NEES runs")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per run (15 Hz images)")
    ap.add_argument("--ablation-features", type=int, default=300)
    ap.add_argument("--nees-runs", type=int, default=20)
    ap.add_argument("--nees-duration", type=float, default=20.0)
    ap.add_argument("--skip", nargs="*", default=[], choices=["speed", "ablations", "nees"])
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_msckf.json")
    args = ap.parse_args()
    if args.quick:
        args.duration = min(args.duration, 10.0)
    result = dict(machine=platform.platform(), processor=platform.processor(), python=platform.python_version(),
                  numpy=np.__version__, blas_threads=os.environ.get("OPENBLAS_NUM_THREADS"),
                  duration_s=args.duration, warmup_frames=WARMUP_FRAMES)
    if "speed" not in args.skip:
        result["speed"] = speed(args)
    if "ablations" not in args.skip:
        result["ablations"] = ablations(args)
    if "nees" not in args.skip:
        result["nees"] = nees(args)
    write_json_atomic(args.json, result)
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
