"""How the depth cache stores a depth map: 16-bit PNG (before issue 16) against the LZ4 map stream (now).

Takes the raw SGBM depth of a simulated preset through the pipeline's depth stage (cached: computed once), encodes
each frame's uint16 millimetre map both ways and times encode and decode (CPU time of this thread, one core, the
two codecs alternating frame by frame so both see the same machine load). Also times what a VIO run pays per
frame to read its depth from the cache (``DepthCache.get`` + the decode to metres), with each codec: every
depth-variant run reads one map per frame, a depth-inpainted run two (the inpainted and the raw one). Checks that
both codecs give back the same millimetres on every frame.

    .venv/bin/python benchmarks/bench_depth_codec.py [--preset rosario-like-02] [--duration 10] [--frames 150]
        [--repeats 5] [--json PATH]

Prints a table of medians and writes JSON (default ``<cache>/benchmarks/bench_depth_codec.json``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.atomic import write_json_atomic  # noqa: E402
from pipeline.depth import DepthParams, decode_depth_mm, encode_depth_mm  # noqa: E402
from pipeline.lz4_codec import decode_lz4_map, encode_lz4_map  # noqa: E402
from pipeline.paths import cache_dir  # noqa: E402
from pipeline.png_codec import PNG_COMPACT, decode_png, encode_png  # noqa: E402

CODECS = {
    "png (before)": (lambda mm: encode_png(mm, PNG_COMPACT), decode_png),
    "lz4 (now)": (encode_lz4_map, decode_lz4_map),
}


def _cpu_ms(fn, *args):
    t0 = time.thread_time()
    out = fn(*args)
    return out, 1e3 * (time.thread_time() - t0)


def _depth_maps(preset: str, duration_s: float, frames: int) -> list[np.ndarray]:
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth_cache import DepthCache, depth_stream
    from pipeline.sources import resolve_source

    root = cache_dir()
    src = resolve_source(preset, duration_s=duration_s, cache_root=root, progress=True)
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    for _ in depth_stream(seq, DepthParams(), cache=True, progress=True, cache_root=root, stop_index=frames):
        pass
    store = DepthCache(root, seq.identity(), DepthParams())
    return [encode_depth_mm(store.get(i, grey=False).depth_m) for i in range(frames)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rosario-like-02")
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    ap.add_argument("--frames", type=int, default=150, help="frames (from the start of the sequence)")
    ap.add_argument("--repeats", type=int, default=5, help="passes over the frames (decode timings)")
    ap.add_argument("--json", type=Path, default=cache_dir() / "benchmarks" / "bench_depth_codec.json")
    args = ap.parse_args()
    cv2.setNumThreads(1)

    maps = _depth_maps(args.preset, args.duration, args.frames)
    names = list(CODECS)
    size = {n: [] for n in names}
    enc_ms = {n: [] for n in names}
    dec_ms = {n: [] for n in names}
    read_ms = {n: [] for n in names}
    streams = {n: [] for n in names}
    for i, mm in enumerate(maps):
        for n in (names if i % 2 == 0 else names[::-1]):
            buf, ms = _cpu_ms(CODECS[n][0], mm)
            streams[n].append(buf)
            size[n].append(buf.size)
            enc_ms[n].append(ms)
    identical = all(np.array_equal(CODECS[n][1](streams[n][i]), mm) for n in names for i, mm in enumerate(maps))
    for r in range(args.repeats):
        for i in range(len(maps)):
            for n in (names if (i + r) % 2 == 0 else names[::-1]):
                _, ms = _cpu_ms(CODECS[n][1], streams[n][i])
                dec_ms[n].append(ms)
                _, ms = _cpu_ms(lambda b, n=n: decode_depth_mm(CODECS[n][1](b)), streams[n][i])
                read_ms[n].append(ms)

    rows = []
    for n in names:
        rows.append({"codec": n, "kb_median": float(np.median(size[n])) / 1024,
                     "encode_ms_median": float(np.median(enc_ms[n])), "decode_ms_median": float(np.median(dec_ms[n])),
                     "read_ms_median": float(np.median(read_ms[n]))})
    base = rows[0]
    print(f"{args.preset}, {len(maps)} frames of {maps[0].shape[1]}×{maps[0].shape[0]} raw SGBM depth; CPU ms per frame"
          f" (medians), ratio against the PNG the cache wrote before, measured in the same run")
    print(f"{'codec':14s} {'kB':>7s} {'encode':>8s} {'decode':>8s} {'read (decode + to metres)':>26s}")
    for r in rows:
        print(f"{r['codec']:14s} {r['kb_median']:7.1f} {r['encode_ms_median']:8.2f} {r['decode_ms_median']:8.2f} "
              f"{r['read_ms_median']:26.2f}   (×{base['decode_ms_median'] / r['decode_ms_median']:.1f} decode, "
              f"×{base['encode_ms_median'] / r['encode_ms_median']:.1f} encode, "
              f"{100 * (r['kb_median'] / base['kb_median'] - 1):+.0f} % size)")
    print(f"identical millimetres on every frame: {'yes' if identical else 'NO'}")
    result = {"benchmark": "bench_depth_codec", "preset": args.preset, "duration_s": args.duration,
              "frames": len(maps), "repeats": args.repeats, "rows": rows, "identical": identical,
              "machine": platform.platform(), "opencv": cv2.__version__, "numpy": np.__version__}
    write_json_atomic(args.json, result)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
