"""Data quality of a bag's streams, measured once per bag (cached by its content identity) before any compute.

What is counted (all stamps are header stamps in integer nanoseconds):

* stereo pairing: left/right images, how many left images have a right image within the reader's pairing
  tolerance, and the right − left stamp offset to the nearest right image (median, 10th/90th percentile, ms);
* camera frames: median period and dropped frames (a gap of k periods counts k − 1 dropped frames);
* IMU: samples, repeated stamps, stamps that go backwards, gaps longer than :data:`IMU_GAP_FACTOR` median
  periods (count, longest, total seconds missing). A NaN or infinite IMU sample is an error naming bag, topic
  and stamp.

:func:`check_stereo_pairing` turns a pairing below :data:`MIN_PAIR_FRACTION` into an error naming the offset seen.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.errors import AgrivioError, BagError
from pipeline.rosario_layout import TOPIC_IMU, TOPIC_LEFT_IMAGE, TOPIC_RIGHT_IMAGE

QUALITY_VERSION = 1
#: Fewest left images (fraction) that must find a right partner for the depth stage to go on.
MIN_PAIR_FRACTION = 0.5
#: An IMU stamp step longer than this many median periods is a gap.
IMU_GAP_FACTOR = 5.0
#: A camera stamp step longer than this many median periods has dropped frames.
FRAME_GAP_FACTOR = 1.5


def stereo_pairing(left_ns: np.ndarray, right_ns: np.ndarray, tolerance_ns: int) -> dict[str, Any]:
    """Pairing statistics of left/right header stamps (ns); offsets are right − left to the nearest right, ms."""
    left = np.sort(np.asarray(left_ns, dtype=np.int64))
    right = np.sort(np.asarray(right_ns, dtype=np.int64))
    out: dict[str, Any] = {"left": int(left.size), "right": int(right.size), "tolerance_ms": tolerance_ns / 1e6}
    if left.size == 0 or right.size == 0:
        return {**out, "paired": 0, "offset_ms_median": None, "offset_ms_p10": None, "offset_ms_p90": None}
    k = np.clip(np.searchsorted(right, left), 1, right.size - 1) if right.size > 1 else np.zeros(left.size, int)
    before, after = right[np.maximum(k - 1, 0)] - left, right[k] - left
    offset = np.where(np.abs(before) <= np.abs(after), before, after)
    return {**out, "paired": int(np.count_nonzero(np.abs(offset) <= tolerance_ns)),
            "offset_ms_median": float(np.median(offset)) / 1e6, "offset_ms_p10": float(np.percentile(offset, 10)) / 1e6,
            "offset_ms_p90": float(np.percentile(offset, 90)) / 1e6}


def frame_gaps(stamps_ns: np.ndarray, factor: float = FRAME_GAP_FACTOR) -> dict[str, Any]:
    """Median period (ms), dropped frames and the longest gap (ms) of a camera stream's stamps (ns)."""
    t = np.sort(np.asarray(stamps_ns, dtype=np.int64))
    if t.size < 3:
        return {"period_ms": None, "dropped": 0, "max_gap_ms": None}
    dt = np.diff(t).astype(np.float64)
    period = float(np.median(dt))
    big = dt[dt > factor * period]
    dropped = int(np.sum(np.round(big / period) - 1)) if period > 0 else 0
    return {"period_ms": period / 1e6, "dropped": max(dropped, 0), "max_gap_ms": float(dt.max()) / 1e6}


def imu_quality(seq: Any) -> dict[str, Any]:
    """IMU counts of ``seq`` (a :class:`RosarioSequence`), raw stamps as recorded.

    Raises:
        BagError: a sample holds NaN or infinity (names the bag, the topic and the stamp).
    """
    stamps: list[int] = []
    for t, gyro, accel in seq._imu_raw(None, None):
        if not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel))):
            raise BagError(seq.path, f"{TOPIC_IMU} sample at stamp {t} ns ({t / 1e9:.6f} s) holds NaN or infinity")
        stamps.append(t)
    t = np.asarray(stamps, dtype=np.int64)
    out: dict[str, Any] = {"samples": int(t.size), "repeated_stamps": 0, "backwards_stamps": 0, "gaps": 0,
                           "max_gap_s": None, "missing_s": 0.0, "period_ms": None}
    if t.size < 3:
        return out
    dt = np.diff(t)
    out["repeated_stamps"] = int(np.count_nonzero(dt == 0))
    out["backwards_stamps"] = int(np.count_nonzero(dt < 0))
    forward = dt[dt > 0].astype(np.float64)
    if forward.size:
        period = float(np.median(forward))
        gaps = forward[forward > IMU_GAP_FACTOR * period]
        out.update(period_ms=period / 1e6, gaps=int(gaps.size), max_gap_s=float(forward.max()) / 1e9,
                   missing_s=float(np.sum(gaps - period)) / 1e9)
    return out


def measure(seq: Any) -> dict[str, Any]:
    """Every statistic of the module docstring for ``seq`` (reads the bag once, images undecoded)."""
    left = seq.header_stamps_ns(TOPIC_LEFT_IMAGE)
    right = seq.header_stamps_ns(TOPIC_RIGHT_IMAGE)
    return {"version": QUALITY_VERSION, "stereo": stereo_pairing(left, right, seq.pair_tolerance_ns),
            "camera": frame_gaps(left), "imu": imu_quality(seq)}


def sequence_quality(seq: Any, cache_root: Path | str | None) -> dict[str, Any]:
    """:func:`measure`, cached under ``cache_root/quality/<bag identity>.json`` (None: not cached)."""
    path = Path(cache_root) / "quality" / f"{seq.identity()}-t{seq.pair_tolerance_ns}.json" if cache_root else None
    if path is not None:
        try:
            cached = json.loads(path.read_text())
            if cached.get("version") == QUALITY_VERSION:
                return cached
        except (OSError, ValueError):
            pass
    quality = measure(seq)
    if path is not None:
        write_json_atomic(path, quality)
    return quality


def check_stereo_pairing(bag: Path | str, quality: dict[str, Any]) -> None:
    """Raise when fewer than :data:`MIN_PAIR_FRACTION` of the images form stereo pairs (naming the offset seen)."""
    st = quality["stereo"]
    n = min(st["left"], st["right"])
    if n and st["paired"] >= MIN_PAIR_FRACTION * n:
        return
    offset = st.get("offset_ms_median")
    seen = f"median right − left stamp offset {offset:+.1f} ms" if offset is not None else "no right images"
    raise AgrivioError(f"{bag}: only {st['paired']} of {st['left']} left images have a right image within "
                       f"±{st['tolerance_ms']:g} ms ({seen}); the stereo stamps do not match")


def summary_lines(quality: dict[str, Any]) -> list[str]:
    """Human-readable lines (for ``agrivio info``, the depth stage and the report)."""
    st, cam, imu = quality["stereo"], quality["camera"], quality["imu"]
    off = st.get("offset_ms_median")
    lines = [f"stereo pairs: {st['paired']} of {st['left']} left / {st['right']} right images within "
             f"±{st['tolerance_ms']:g} ms" + (f" (right − left offset median {off:+.2f} ms, p10 "
                                              f"{st['offset_ms_p10']:+.2f}, p90 {st['offset_ms_p90']:+.2f})"
                                              if off is not None else "")]
    if cam.get("period_ms") is not None:
        lines.append(f"camera: period {cam['period_ms']:.1f} ms, {cam['dropped']} dropped frame(s), longest gap "
                     f"{cam['max_gap_ms']:.1f} ms")
    imu_line = (f"IMU: {imu['samples']} samples, {imu['repeated_stamps']} repeated and {imu['backwards_stamps']} "
                f"backwards stamp(s), {imu['gaps']} gap(s) > {IMU_GAP_FACTOR:g} periods")
    if imu["gaps"]:
        imu_line += f" (longest {imu['max_gap_s']:.3f} s, {imu['missing_s']:.3f} s missing)"
    lines.append(imu_line)
    return lines


__all__ = ["MIN_PAIR_FRACTION", "check_stereo_pairing", "frame_gaps", "imu_quality", "measure",
           "sequence_quality", "stereo_pairing", "summary_lines"]
