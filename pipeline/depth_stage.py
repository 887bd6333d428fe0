"""The depth stage over a whole sequence as one call: stream it (computing or reading the cache) and summarise the
hole ratios and the time per computed frame; the summary is also written next to the cache (``summary.json``).
The ``agrivio depth`` command only checks the bag, calls :func:`run_depth` and prints."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthParams
from pipeline.depth_cache import depth_stream


def summarize(hole_ratios: list[float], stats: dict[str, Any], wall_s: float) -> dict[str, Any]:
    """Summary dict of a depth pass: frames, hole-ratio median/p10/p90, seconds per computed frame."""
    h = np.asarray(hole_ratios, dtype=np.float64)
    pct = (lambda q: float(np.percentile(h, q))) if h.size else (lambda q: float("nan"))
    computed = int(stats.get("computed", 0))
    return {
        "frames": int(h.size), "computed": computed, "cached": int(stats.get("cached", 0)),
        "hole_ratio_median": pct(50), "hole_ratio_p10": pct(10), "hole_ratio_p90": pct(90),
        "compute_s_per_frame": float(stats["compute_s"] / computed) if computed else None,
        "wall_s": float(wall_s), "cache_dir": stats.get("directory"),
    }


def run_depth(seq: RosarioSequence, params: DepthParams, *, cache: bool, cache_root: Path | None,
              max_frames: int | None, progress: bool) -> dict[str, Any]:
    """Stream the depth stage over ``seq`` and return :func:`summarize`'s dict (also written to the cache)."""
    stats: dict[str, Any] = {}
    holes: list[float] = []
    t0 = time.perf_counter()
    for frame in depth_stream(seq, params, cache=cache, progress=progress, cache_root=cache_root, stats=stats,
                              stop_index=max_frames):
        holes.append(frame.hole_ratio)
    summary = summarize(holes, stats, time.perf_counter() - t0)
    summary["unpaired_left"] = seq.stats.unpaired_left
    summary["unpaired_right"] = seq.stats.unpaired_right
    if summary["cache_dir"]:
        write_json_atomic(Path(summary["cache_dir"]) / "summary.json", summary)
    return summary


__all__ = ["run_depth", "summarize"]
