"""Benchmark the evaluator on a 100,000-pose trajectory: association + SE(3) alignment + ATE + RPE.

Prints a table of medians over repeats (ms) and writes JSON. Baseline measured in the same run: evo 1.38's
association + SE(3) alignment + APE on the same trajectories (evo's all-pairs RPE is O(N²) in Python and is
not timed); skipped when evo is not installed.

    .venv/bin/python benchmarks/bench_eval.py [--poses 100000] [--repeats 7] [--json PATH]
"""

from __future__ import annotations

import argparse
import copy
import platform
import time
from pathlib import Path

import numpy as np

from eval.alignment import fit_alignment
from eval.association import associate
from eval.evaluate import EvalOptions, evaluate
from eval.metrics import ate, rpe
from eval.synthetic import field_path, perturbed_estimate
from eval.trajectory import Trajectory
from pipeline.atomic import write_json_atomic
from pipeline.paths import cache_dir


def _median_ms(fn, repeats: int) -> tuple[float, float, object]:
    times = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), float(np.min(times)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_eval.json")
    args = ap.parse_args()

    rate = 20.0
    gt = field_path(duration_s=(args.poses - 1) / rate, rate_hz=rate, row_length_m=200.0)
    est = perturbed_estimate(gt, seed=0, yaw_drift_deg=5.0, time_offset_s=0.004)
    gps = Trajectory.from_positions(gt.stamps_s, gt.positions)
    print(f"{len(gt)} reference poses, {len(est)} estimate poses, path {gt.path_length_m():.0f} m, "
          f"{args.repeats} repeats")

    assoc = associate(gt, est)
    al = fit_alignment(assoc.ref, assoc.est, "se3")
    est_al = al.apply(assoc.est)
    d = assoc.ref.distances_m()
    rows: list[tuple[str, float, float]] = []

    def add(name: str, fn) -> object:
        med, best, out = _median_ms(fn, args.repeats)
        rows.append((name, med, best))
        return out

    add("associate (nearest, 20 ms)", lambda: associate(gt, est))
    add("SE(3) Umeyama", lambda: fit_alignment(assoc.ref, assoc.est, "se3"))
    add("apply alignment", lambda: al.apply(assoc.est))
    add("ATE (trans + rot)", lambda: ate(assoc.ref, est_al))
    add("RPE 10 m (all pairs)", lambda: rpe(assoc.ref, est_al, 10.0, 0.2, d))
    add("RPE 10+20+50 m", lambda: [rpe(assoc.ref, est_al, x, 0.2, d) for x in (10.0, 20.0, 50.0)])
    ev = add("evaluate() total, SE(3), GT with orientation", lambda: evaluate(gt, est, EvalOptions(align="se3")))
    add("evaluate() total, SE(3), position-only GT", lambda: evaluate(gps, est, EvalOptions(align="se3")))
    add("evaluate() total, posyaw, position-only GT", lambda: evaluate(gps, est, EvalOptions(align="posyaw")))

    baseline = None
    try:
        from evo.core import metrics as evo_metrics
        from evo.core import sync as evo_sync
        from evo.core.trajectory import PoseTrajectory3D

        def to_evo(t: Trajectory) -> PoseTrajectory3D:
            return PoseTrajectory3D(positions_xyz=np.array(t.positions), timestamps=np.array(t.stamps_s),
                                    orientations_quat_wxyz=np.roll(np.array(t.quats_xyzw), 1, axis=1))

        ref_e, est_e = to_evo(gt), to_evo(est)

        def evo_ape() -> float:
            r, e = evo_sync.associate_trajectories(ref_e, est_e, max_diff=0.02)
            e = copy.deepcopy(e)
            e.align(r, correct_scale=False)
            m = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
            m.process_data((r, e))
            return m.get_statistic(evo_metrics.StatisticsType.rmse)

        med, best, evo_rmse = _median_ms(evo_ape, max(3, args.repeats // 2))
        baseline = {"name": "evo 1.38 associate + SE(3) align + APE", "median_ms": med, "min_ms": best,
                    "ate_rmse_m": evo_rmse}
    except ImportError:
        print("evo not installed: no baseline")

    ours_ate = [r for r in rows if r[0] == "evaluate() total, SE(3), GT with orientation"][0][1]
    ours_parts = sum(r[1] for r in rows[:4])
    print(f"\n{'stage':<48} {'median ms':>10} {'min ms':>9}")
    for name, med, best in rows:
        print(f"{name:<48} {med:10.1f} {best:9.1f}")
    if baseline:
        print(f"{baseline['name']:<48} {baseline['median_ms']:10.1f} {baseline['min_ms']:9.1f}")
        print(f"\nassociation+alignment+ATE: ours {ours_parts:.1f} ms vs evo {baseline['median_ms']:.1f} ms "
              f"(x{baseline['median_ms'] / ours_parts:.1f}); ATE RMSE ours {ev.ate.trans.rmse:.9f} m, "
              f"evo {baseline['ate_rmse_m']:.9f} m")
    print(f"full evaluation (association + SE(3) + ATE + RPE at 10/20/50 m): median {ours_ate:.1f} ms")
    result = {"benchmark": "bench_eval", "poses": len(gt), "repeats": args.repeats,
              "machine": {"python": platform.python_version(), "processor": platform.processor(),
                          "machine": platform.machine()},
              "stages": [{"name": n, "median_ms": m, "min_ms": b} for n, m, b in rows],
              "baseline": baseline, "ate_rmse_m": ev.ate.trans.rmse,
              "rpe_pairs": {f"{r.delta_m:g}": r.trans.n for r in ev.rpe}}
    write_json_atomic(args.json, result)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
