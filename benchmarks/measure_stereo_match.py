"""How wrong is the stereo front end's left→right match, and is its error white along a track? (simulated sequence)

The stereo front end (seed 0) runs over a simulated sequence; for every published stereo feature whose left pixel
lies on locally flat exact depth (5×5 window within 3 % of its Z, 0.5–20 m), the true right-image pixel of the
surface point seen at the *current* left pixel is computed from the exact depth and the rig; the matched right
pixel minus it is the match error (so the left track's own drift does not count). Prints its median, robust σ
(1.4826·MAD), RMS and the share above 1 px, the robust σ of its change from one frame to the next and after ≥ 8
frames along the same track (white errors change by √2·σ; a per-track constant changes by ~0), and per depth
band. Writes JSON (default <cache>/benchmarks/measure_stereo_match.json).

    .venv/bin/python benchmarks/measure_stereo_match.py [--preset 03] [--duration 10]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import median_abs_deviation  # noqa: E402

from msckf.config import load_config  # noqa: E402
from msckf.vio import Msckf  # noqa: E402
from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.bag_reader import RosarioSequence  # noqa: E402
from pipeline.depth import to_grey  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.run_job import feed_imu_until  # noqa: E402
from pipeline.sim.sequence import SimulatedSequence  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402


def _robust_sigma(x: np.ndarray) -> float:
    return float(median_abs_deviation(x, scale="normal")) if x.size else float("nan")


def match_errors(sim: SimulatedSequence, flat_rel: float = 0.03) -> np.ndarray:
    """(M, 5) rows ``frame, track id, error x px, error y px, Z m`` of the right-image match error."""
    seq = RosarioSequence(sim.bag_path, camchain=sim.camchain_path)
    rig = seq.calibration
    imu = seq.imu_array()
    vio = Msckf(load_config(None), rig, variant="stereo", seed=0)
    R_left_T, T_rl = rig.R_left.T, rig.T_right_left
    rows: list[tuple[int, int, float, float, float]] = []
    k = 0
    for fr in seq.stereo_frames():
        t = fr.stamp_ns / 1e9
        k = feed_imu_until(vio, imu, k, t)
        vio.add_frame(t, to_grey(fr.left_bgr), right_grey=to_grey(fr.right_bgr))
        dbg = vio.frontend.last_debug
        if dbg is None or not len(dbg.ids):
            continue
        ok = np.all(np.isfinite(dbg.cam1_px), axis=1)
        if not ok.any():
            continue
        Z = sim.depth(fr.index)
        rect = rig.rectify_left_pixels(dbg.cam0_px[ok])
        u, v = np.round(rect[:, 0]).astype(int), np.round(rect[:, 1]).astype(int)
        H, W = Z.shape
        for j in np.flatnonzero((u >= 3) & (v >= 3) & (u < W - 3) & (v < H - 3)):
            z = float(Z[v[j], u[j]])
            win = Z[v[j] - 2:v[j] + 3, u[j] - 2:u[j] + 3]
            if not (0.5 < z < 20.0 and np.all(np.isfinite(win)) and np.all(np.abs(win - z) < flat_rel * z)):
                continue
            p_rect = np.array([(rect[j, 0] - rig.cx) / rig.fx * z, (rect[j, 1] - rig.cy) / rig.fx * z, z])
            p_right = T_rl[:3, :3] @ (R_left_T @ p_rect) + T_rl[:3, 3]
            err = dbg.cam1_px[ok][j] - rig.right.project(p_right[None])[0]
            rows.append((fr.index, int(dbg.ids[ok][j]), float(err[0]), float(err[1]), z))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 5)


def summarise(a: np.ndarray) -> dict:
    ex, ey = a[:, 2], a[:, 3]
    lag1, lag8 = [], []
    for tid in np.unique(a[:, 1]):
        tr = a[a[:, 1] == tid]
        frames, e = tr[:, 0], tr[:, 2]
        step = np.flatnonzero(np.diff(frames) == 1)
        lag1 += list(e[step + 1] - e[step])
        lag8 += list(e[frames - frames[0] >= 8] - e[0])
    out = {"n": int(len(a)), "median_x_px": float(np.median(ex)), "median_y_px": float(np.median(ey)),
           "robust_sigma_x_px": _robust_sigma(ex), "robust_sigma_y_px": _robust_sigma(ey),
           "rms_x_px": float(np.sqrt(np.mean(ex ** 2))), "over_1px": float(np.mean(np.hypot(ex, ey) > 1.0)),
           "change_lag1_robust_sigma_px": _robust_sigma(np.asarray(lag1)),
           "change_lag8plus_robust_sigma_px": _robust_sigma(np.asarray(lag8)), "bands": {}}
    for lo, hi in ((0.5, 2.0), (2.0, 5.0), (5.0, 20.0)):
        m = (a[:, 4] >= lo) & (a[:, 4] < hi)
        if m.any():
            out["bands"][f"{lo:g}-{hi:g}"] = {"n": int(m.sum()), "median_x_px": float(np.median(ex[m])),
                                             "robust_sigma_x_px": _robust_sigma(ex[m])}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="03")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "measure_stereo_match.json")
    args = ap.parse_args()
    src = simulate_cached(f"rosario-like-{args.preset}", duration_s=args.duration, progress=True)
    s = summarise(match_errors(SimulatedSequence(src.sim_dir)))
    print(f"rosario-like-{args.preset}, {args.duration:g} s: {s['n']} matches on flat depth")
    print(f"  right-match error x: median {s['median_x_px']:+.3f} px, robust σ {s['robust_sigma_x_px']:.3f}, "
          f"RMS {s['rms_x_px']:.3f}; y: median {s['median_y_px']:+.3f}, robust σ {s['robust_sigma_y_px']:.3f}; "
          f"{100 * s['over_1px']:.1f} % off by > 1 px")
    print(f"  change along a track: next frame robust σ {s['change_lag1_robust_sigma_px']:.3f} px, after ≥ 8 frames "
          f"{s['change_lag8plus_robust_sigma_px']:.3f} px (white: √2 × {s['robust_sigma_x_px']:.3f} = "
          f"{np.sqrt(2) * s['robust_sigma_x_px']:.3f})")
    for band, b in s["bands"].items():
        print(f"  Z {band} m: n {b['n']}, median {b['median_x_px']:+.3f} px, robust σ {b['robust_sigma_x_px']:.3f}")
    write_json_atomic(args.json, {"preset": args.preset, "duration_s": args.duration, **s})
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
