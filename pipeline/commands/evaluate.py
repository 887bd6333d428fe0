"""``agrivio evaluate EST.tum GT.tum``: ATE / RPE of one estimate against ground truth (TUM files)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from eval.alignment import ALIGN_METHODS
from eval.evaluate import EvalOptions, Evaluation, evaluate
from eval.trajectory import read_tum
from pipeline.atomic import write_json_atomic
from pipeline.rotation_check import roll_uncertainty_deg, rotation_is_determined


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "evaluate", help="ATE/RPE of an estimated trajectory against ground truth (TUM files)",
        description="Associate the estimate with the ground truth by time stamp, align (default SE(3) Umeyama on "
                    "positions, as the Rosario authors' `evo --align --t_max_diff 0.02`), and report the absolute "
                    "trajectory error and the relative pose error over travelled distances.")
    p.add_argument("estimate", type=Path, help="estimated trajectory, TUM text 't x y z qx qy qz qw'")
    p.add_argument("ground_truth", type=Path, help="reference trajectory, TUM text (identity quaternions = "
                                                   "position only, as Rosario's GPS)")
    p.add_argument("--align", choices=ALIGN_METHODS, default="se3",
                   help="alignment: se3 (default), sim3 (with scale), posyaw (4-DoF: translation + yaw), none")
    p.add_argument("--max-diff", type=float, default=0.02, metavar="S",
                   help="largest time difference of an associated pair, seconds (default 0.02)")
    p.add_argument("--offset", type=float, default=0.0, metavar="S",
                   help="time offset added to the estimate's stamps for the association, seconds (default 0)")
    p.add_argument("--interpolate", action="store_true",
                   help="interpolate the ground truth at the estimate's stamps instead of nearest-stamp matching")
    p.add_argument("--first-n", type=int, default=None, metavar="N",
                   help="fit the alignment on the first N pairs only (default: all)")
    p.add_argument("--lever-arm", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="express the estimate at this body-frame point before comparing (e.g. the GPS antenna), "
                        "metres; needs the estimate's orientation")
    p.add_argument("--rpe", type=float, nargs="+", default=None, metavar="M",
                   help="RPE segment lengths in metres (default: 10 20 50, or 10..50 %% of a short path)")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the metrics as JSON")
    p.set_defaults(func=run)


def format_evaluation(ev: Evaluation, est_name: str, gt_name: str) -> str:
    """Human-readable summary of an evaluation."""
    a = ev.alignment
    t = ev.ate.trans
    lines = [
        f"estimate     {est_name}",
        f"reference    {gt_name}" + ("" if ev.ref.has_orientation else "  (position only)"),
        f"pairs        {len(ev.association)} (max |dt| {ev.association.max_dt_s * 1e3:.1f} ms, "
        f"{ev.ref.duration_s:.1f} s, {ev.ref_path_length_m:.1f} m of reference path)",
        f"alignment    {a.method}: yaw {a.yaw_deg():+.3f} deg, t = ({a.translation[0]:.3f}, {a.translation[1]:.3f}, "
        f"{a.translation[2]:.3f}) m" + (f", scale {a.scale:.6f}" if a.method == "sim3" else ""),
        "",
        "ATE translation (m)",
        f"  rmse {t.rmse:.6f}   mean {t.mean:.6f}   median {t.median:.6f}   std {t.std:.6f}   "
        f"min {t.min:.6f}   max {t.max:.6f}",
    ]
    if ev.ate.rot is not None:
        r = ev.ate.rot
        lines.append(f"ATE rotation (deg)\n  rmse {r.rmse:.4f}   mean {r.mean:.4f}   max {r.max:.4f}")
    if ev.rpe:
        lines += ["", f"RPE ({ev.rpe[0].mode}; pairs on the reference path, tolerance "
                      f"{ev.options.rpe_rel_tol * 100:g} %)",
                  f"  {'delta m':>8} {'pairs':>7} {'rmse m':>10} {'mean m':>10} {'drift %':>8} {'rot deg':>8}"]
        for r in ev.rpe:
            rot = f"{r.rot.rmse:8.3f}" if r.rot is not None and r.rot.n else f"{'–':>8}"
            lines.append(f"  {r.delta_m:8.2f} {r.trans.n:7d} {r.trans.rmse:10.4f} {r.trans.mean:10.4f} "
                         f"{r.drift.mean:8.3f} {rot}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    options = EvalOptions(align=args.align, max_diff_s=args.max_diff, offset_s=args.offset,
                          interpolate=args.interpolate, first_n=args.first_n,
                          lever_arm_m=tuple(args.lever_arm) if args.lever_arm else None,
                          rpe_distances_m=tuple(args.rpe) if args.rpe else None)
    est = read_tum(args.estimate)
    gt = read_tum(args.ground_truth)
    ev = evaluate(gt, est, options)
    text = format_evaluation(ev, str(args.estimate), str(args.ground_truth))
    metrics = ev.metrics()
    if ev.ate.rot is not None and not rotation_is_determined(ev.alignment.method, ev.ref.positions,
                                                             ev.ate.trans.rmse):
        # roll about the direction of travel is not fixed by a position fit on this path: the rotation ATE of
        # that alignment measures the alignment; report it after a pos+yaw alignment (roll/pitch from gravity)
        sigma = roll_uncertainty_deg(ev.ref.positions, ev.ate.trans.rmse)
        r = evaluate(gt, est, dataclasses.replace(options, align="posyaw")).ate.rot
        head, _, tail = text.partition("ATE rotation (deg)\n")
        tail = tail.split("\n", 1)[1] if "\n" in tail else ""
        text = (head + f"ATE rotation (deg), after a posyaw alignment: the {ev.alignment.method} fit leaves the roll "
                f"about the direction of travel undetermined on this nearly straight path (±{sigma:.1f} deg)\n"
                f"  rmse {r.rmse:.4f}   mean {r.mean:.4f}   max {r.max:.4f}" + ("\n" + tail if tail else ""))
        metrics.update(ate_rot_rmse_deg=r.rmse, ate_rot_mean_deg=r.mean, ate_rot_align="posyaw")
    print(text)
    if args.json is not None:
        payload = {"estimate": str(args.estimate), "ground_truth": str(args.ground_truth),
                   "options": options.to_dict(), "metrics": metrics, "alignment": ev.alignment.to_dict()}
        write_json_atomic(args.json, json.loads(json.dumps(payload)))
        print(f"\nwrote {args.json}")
    return 0
