"""How a KLT track's pixel error grows along the track (is it white noise, or drift?), on a simulated sequence.

For each track of the depth front end (seed 0) whose first observation lies on locally flat exact depth (5×5
window within 5 % of its Z), the surface point seen there is back-projected with the true pose and the exact
depth, then projected with the true poses into the later frames: the track's pixel minus that true track is the
tracking error. Prints, per lag (frames after the first observation), the per-axis variance and the robust σ
(1.4826·MAD) of the error; writes JSON (default <cache>/benchmarks/measure_track_drift.json). White noise gives a
flat σ; a random walk gives σ² growing linearly with the lag (the slope is ``track_drift_psd`` per frame).

    .venv/bin/python benchmarks/measure_track_drift.py [--preset 02] [--duration 10]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.depth_oracle_run import default_config, prepare_oracle  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.sim.sequence import SimulatedSequence  # noqa: E402
from pipeline.sim_source import simulate_cached  # noqa: E402

LAGS = (1, 2, 3, 5, 8, 12, 16, 20, 25, 29)


def track_errors(sim: SimulatedSequence, log, K: np.ndarray, flat_rel: float = 0.05) -> list[np.ndarray]:
    """(M, 2) pixel error series (rectified px, from the first observation) of every usable track."""
    truth = sim.truth
    Kinv = np.linalg.inv(K)
    T = {fr.index: truth["T_E_rectleft"][int(np.argmin(np.abs(truth["frame_stamp_ns"] / 1e9 - fr.stamp_s)))]
         for fr in log.frames}
    obs: dict[int, list[tuple[int, int]]] = {}
    for fi, fr in enumerate(log.frames):
        for j, tid in enumerate(fr.ids):
            obs.setdefault(int(tid), []).append((fi, j))
    out = []
    for lst in obs.values():
        if len(lst) < 6:
            continue
        fr0 = log.frames[lst[0][0]]
        d = sim.depth(fr0.index)
        u, v = fr0.rect_px[lst[0][1]]
        ui, vi = int(round(u)), int(round(v))
        if not (0 <= vi < d.shape[0] and 0 <= ui < d.shape[1]) or not np.isfinite(d[vi, ui]):
            continue
        win = d[max(vi - 2, 0):vi + 3, max(ui - 2, 0):ui + 3]
        if not np.all(np.isfinite(win)) or win.max() - win.min() > flat_rel * d[vi, ui]:
            continue
        T0 = T[fr0.index]
        p_w = T0[:3, :3] @ (Kinv @ np.array([u, v, 1.0]) * d[vi, ui]) + T0[:3, 3]
        errs = []
        for fi, j in lst:
            Tk = T[log.frames[fi].index]
            q = Tk[:3, :3].T @ (p_w - Tk[:3, 3])
            if q[2] <= 0.1:
                break
            errs.append(log.frames[fi].rect_px[j] - (K @ q)[:2] / q[2])
        out.append(np.array(errs))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="02")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    preset = args.preset if args.preset.startswith("rosario") else f"rosario-like-{args.preset}"
    src = simulate_cached(preset, duration_s=args.duration, progress=False)
    sim = SimulatedSequence(Path(src.sim_dir))
    prep = prepare_oracle(src.sim_dir, cache_dir(), [], default_config({}), [0], None)
    errs = track_errors(sim, prep["logs"][0], prep["rig"].K_rect)
    rows = []
    print(f"{preset}: {len(errs)} tracks on flat depth\n")
    print("| lag (frames) | n | per-axis variance (px²) | robust σ (px) |")
    print("|---|---|---|---|")
    for lag in LAGS:
        inc = np.array([e[lag] - e[0] for e in errs if len(e) > lag])
        if len(inc) < 10:
            continue
        var = float(np.var(inc, axis=0).mean())
        rob = float(1.4826 * np.median(np.abs(inc - np.median(inc, axis=0))))
        rows.append({"lag": lag, "n": len(inc), "variance_px2": var, "robust_sigma_px": rob})
        print(f"| {lag} | {len(inc)} | {var:.4f} | {rob:.3f} |")
    out = args.json or cache_dir() / "benchmarks" / "measure_track_drift.json"
    write_json_atomic(out, {"preset": preset, "duration_s": args.duration, "tracks": len(errs), "lags": rows})
    print(f"JSON: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
