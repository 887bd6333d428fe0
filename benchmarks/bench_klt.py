"""How much of the stereo VIO's frame time is pyramidal KLT, and what would cutting it cost? (one core)

Issue 16 asks for the whole stereo VIO at ≥ 60 frames/s (≤ 16.7 ms per frame) on one core. This benchmark runs the
``stereo`` VIO (default config: S-MSCKF's KLT, 15 × 15 window, ``maxLevel`` 3, 30 iterations / 0.01 px) over a
simulated preset and times, per frame and as the calling thread's CPU time (``time.thread_time``, one OpenCV
thread), the whole front end, its KLT step (``StereoFrontend._klt``: the ``cv2.calcOpticalFlowPyrLK`` call with its
point conversions, for temporal tracking and stereo matching of the tracks and of new candidates) and the back end,
all in the same pass. It then reports the floor those figures set: KLT + back end alone, i.e. the frame rate
reachable if everything else in the front end cost nothing.

Every KLT call of the pass is recorded (images, points, initial guesses) and replayed with other settings
(window, ``maxLevel``, iterations, ε): their median cost per frame and how far their results move from the
default's (median / 99th percentile of the point displacement over the points both track, share of points whose
success flag flips) — what a faster KLT would change in the tracks.

Usage: .venv/bin/python benchmarks/bench_klt.py [--preset rosario-like-02] [--duration 10] [--max-frames 150]
       [--repeats 3] [--out PATH]
Prints two tables and writes JSON (default: <cache>/benchmarks/bench_klt.json).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, as the pipeline's runs
    os.environ.setdefault(_var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

#: (name, window px, maxLevel change, max iterations, ε px) of the replayed settings; the first is the default's
SETTINGS = (("S-MSCKF (default)", 15, 0, 30, 0.01), ("ε 0.03", 15, 0, 30, 0.03), ("ε 0.05", 15, 0, 30, 0.05),
            ("10 iterations", 15, 0, 10, 0.01), ("maxLevel − 1", 15, -1, 30, 0.01), ("window 13", 13, 0, 30, 0.01),
            ("window 11", 11, 0, 30, 0.01))


@dataclass
class KltCall:
    """One recorded ``calcOpticalFlowPyrLK`` call: images, (N, 2) points and guesses (px), its levels and output."""

    frame: int
    img0: np.ndarray
    img1: np.ndarray
    px: np.ndarray
    guess: np.ndarray
    levels: int
    out: np.ndarray
    ok: np.ndarray


def record_pass(preset: str, duration_s: float, max_frames: int | None
                ) -> tuple[list[KltCall], dict[str, np.ndarray], np.ndarray]:
    """Run the stereo VIO once; returns every KLT call, the per-frame CPU ms of front end, KLT and back end (and KLT
    points) over the frames after initialisation, and which frames those are ((n_frames,) bool)."""
    from msckf.vio import Msckf
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import to_grey
    from pipeline.paths import cache_dir
    from pipeline.run_job import feed_imu_until
    from pipeline.sources import resolve_source

    src = resolve_source(preset, duration_s=duration_s, cache_root=cache_dir(), progress=False)
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    imu = seq.imu_array()
    frames = [(fr.stamp_ns / 1e9, to_grey(fr.left_bgr), to_grey(fr.right_bgr))
              for fr in seq.stereo_frames(stop_index=max_frames)]
    vio = Msckf(None, seq.calibration, variant="stereo", seed=0)
    fe = vio.frontend
    klt = fe._klt  # the front end's one entry to calcOpticalFlowPyrLK, wrapped to record and time it
    calls: list[KltCall] = []
    klt_ms = np.zeros(len(frames))
    current = {"frame": 0}

    def recording_klt(img0: np.ndarray, img1: np.ndarray, px: np.ndarray, guess: np.ndarray,
                      levels: int) -> tuple[np.ndarray, np.ndarray]:
        t0 = time.thread_time()
        out, ok = klt(img0, img1, px, guess, levels)
        klt_ms[current["frame"]] += (time.thread_time() - t0) * 1e3
        if len(px):
            calls.append(KltCall(current["frame"], img0, img1, px.copy(), guess.copy(), levels, out.copy(), ok.copy()))
        return out, ok

    fe._klt = recording_klt
    front_ms, back_ms = np.zeros(len(frames)), np.zeros(len(frames))
    initialised = np.zeros(len(frames), dtype=bool)
    k = 0
    for i, (t, left, right) in enumerate(frames):
        current["frame"] = i
        k = feed_imu_until(vio, imu, k, t)
        t0 = time.thread_time()
        obs = fe.process(t, left, right)
        t1 = time.thread_time()
        vio.add_features(obs)
        t2 = time.thread_time()
        front_ms[i], back_ms[i] = (t1 - t0) * 1e3, (t2 - t1) * 1e3
        initialised[i] = vio.initialized
    keep = initialised
    return calls, {"front_ms": front_ms[keep], "klt_ms": klt_ms[keep], "back_ms": back_ms[keep],
                   "points": np.bincount([c.frame for c in calls], weights=[len(c.px) for c in calls],
                                         minlength=len(frames))[keep]}, keep


def replay(calls: list[KltCall], n_frames: int, window: int, level_change: int, iterations: int, eps: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replay every call with other settings: (per-frame CPU ms (n_frames,), displacements px, success-flag flips)."""
    ms = np.zeros(n_frames)
    moved: list[np.ndarray] = []
    flips: list[np.ndarray] = []
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, eps)
    for c in calls:
        p = np.ascontiguousarray(c.px, dtype=np.float32).reshape(-1, 1, 2)
        g = np.ascontiguousarray(c.guess, dtype=np.float32).reshape(-1, 1, 2)
        t0 = time.thread_time()
        out, status, _ = cv2.calcOpticalFlowPyrLK(c.img0, c.img1, p, g, winSize=(window, window),
                                                  maxLevel=max(c.levels + level_change, 0), criteria=criteria,
                                                  flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        ms[c.frame] += (time.thread_time() - t0) * 1e3
        out = out.reshape(-1, 2).astype(np.float64)
        h, w = c.img1.shape[:2]
        st = (status.reshape(-1).astype(bool) & np.all(np.isfinite(out), axis=1) & (out[:, 0] >= 0)
              & (out[:, 0] <= w - 1) & (out[:, 1] >= 0) & (out[:, 1] <= h - 1))   # as the front end's _klt
        both = st & c.ok
        moved.append(np.linalg.norm(out[both] - c.out[both], axis=1))
        flips.append(st != c.ok)
    return ms, np.concatenate(moved), np.concatenate(flips)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=3, help="passes (the recording pass with the lowest VIO median "
                                                             "is shown) and replays per setting (interleaved; "
                                                             "median)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)

    passes = [record_pass(args.preset, args.duration, args.max_frames) for _ in range(max(args.repeats, 1))]
    calls, t, timed = min(passes, key=lambda p: float(np.median(p[1]["front_ms"] + p[1]["back_ms"])))
    n_frames = len(timed)   # replays are summarised over the same frames as the pass (after initialisation)
    med = {k: float(np.median(v)) for k, v in t.items()}
    vio = med["front_ms"] + med["back_ms"]
    floor = float(np.median(t["klt_ms"] + t["back_ms"]))
    other = float(np.median(t["front_ms"] - t["klt_ms"]))
    print(f"stereo VIO on {args.preset} ({args.duration:g} s, {len(t['front_ms'])} frames after initialisation), CPU "
          f"ms per frame, median of the best of {len(passes)} passes:")
    print(f"  front end {med['front_ms']:.2f} (KLT {med['klt_ms']:.2f} for {med['points']:.0f} points, the rest "
          f"{other:.2f}) + back end {med['back_ms']:.2f} = {vio:.2f} ms → {1e3 / vio:.1f} frames/s")
    print(f"  floor with the rest of the front end free: KLT + back end = {floor:.2f} ms → {1e3 / floor:.1f} frames/s "
          f"(60 frames/s needs ≤ 16.67 ms)")
    print(f"\n{'KLT setting':20} {'ms/frame':>8} {'vs default':>10} {'moved median px':>15} {'p99 px':>8} "
          f"{'flags flip':>10}")
    rows = []
    # settings interleaved within each repeat (the order reversed every other repeat): all see the same load
    reps: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {s[0]: [] for s in SETTINGS}
    for r in range(max(args.repeats, 1)):
        for name, win, dlev, iters, eps in (SETTINGS if r % 2 == 0 else SETTINGS[::-1]):
            reps[name].append(replay(calls, n_frames, win, dlev, iters, eps))
    base_ms = float(np.median([np.median(x[0][timed]) for x in reps[SETTINGS[0][0]]]))
    for name, win, dlev, iters, eps in SETTINGS:
        per_frame = float(np.median([np.median(x[0][timed]) for x in reps[name]]))
        moved, flips = reps[name][0][1], reps[name][0][2]
        row = {"setting": name, "window": win, "max_level_change": dlev, "iterations": iters, "eps_px": eps,
               "ms_per_frame": per_frame, "speedup_vs_default": base_ms / per_frame,
               "moved_median_px": float(np.median(moved)) if moved.size else 0.0,
               "moved_p99_px": float(np.percentile(moved, 99)) if moved.size else 0.0,
               "flag_flips": float(np.mean(flips)) if flips.size else 0.0}
        rows.append(row)
        print(f"{name:20} {per_frame:8.2f} {row['speedup_vs_default']:9.2f}x {row['moved_median_px']:15.4f} "
              f"{row['moved_p99_px']:8.3f} {100 * row['flag_flips']:9.2f}%", flush=True)

    from pipeline.atomic import write_json_atomic
    from pipeline.paths import cache_dir

    out = args.out or cache_dir() / "benchmarks" / "bench_klt.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, {
        "benchmark": "stereo VIO: KLT share of the frame time and the cost of faster KLT settings, one thread",
        "preset": args.preset, "duration_s": args.duration, "repeats": args.repeats,
        "median_ms": med, "floor_klt_plus_backend_ms": floor, "rest_of_frontend_ms": other,
        "passes_median_ms": [{k: float(np.median(v)) for k, v in p[1].items()} for p in passes],
        "replays": rows, "opencv": cv2.__version__, "numpy": np.__version__, "python": platform.python_version(),
        "machine": platform.processor() or platform.machine(),
    })
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
