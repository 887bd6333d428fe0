"""A sequence's depth preparation in one pass over its frames: SGBM depth and every inpainting method a matrix asks
for, each frame's whole chain on one worker of one process pool.

Before, the stages ran one after another over the whole sequence: the depth stage in this process (SGBM on
OpenCV's threads, then the grey PNG and the depth LZ4 encoded here, one frame at a time), then per inpainting
method a pool fed in batches of ``2 × workers`` frames (a batch waited for its slowest frame) whose results were
quantised and LZ4-encoded here. Now a worker takes a frame and computes its depth (or decodes it from the cache),
quantises and encodes it, inpaints it with each missing method and encodes those too; this process only reads
the bag, hands frames out (a bounded number ahead, so no batch waits for its slowest frame) and stores the
encoded results in frame order. What is stored is byte-for-byte what the staged path stored: the same functions
compute and encode every layer (``quantize_mm``, :meth:`pipeline.depth_cache.DepthCache.put`'s encoding), and
an inpainting method sees the raw frame exactly as a cache read gives it (depth in whole millimetres).

Frames already cached are not recomputed; the caches are marked complete as the staged path marks them (the
whole sequence seen). Results do not depend on the number of workers.
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pipeline.depth import DepthFrame, DepthParams, compute_depth, quantize_mm
from pipeline.depth_cache import DepthCache, EncodedFrame
from pipeline.inpaint_stage import InpaintParams, check_method, inpaint_frame, uses_guide
from pipeline.process_pool import spawn_pool
from pipeline.rosario_layout import TOPIC_LEFT_IMAGE

__all__ = ["prepare_depth_caches"]

_RIG: Any = None  # the worker's stereo rig (set once per worker by the pool initializer)


def _init_worker(rig: Any) -> None:
    global _RIG
    _RIG = rig


@dataclass(frozen=True)
class _Task:
    """One frame's work: its raw images (depth to compute) or its cached raw depth stream, and the methods to run."""

    index: int
    stamp_ns: int
    left_bgr: Any
    right_bgr: Any
    raw: EncodedFrame | None
    depth: DepthParams
    inpaint: tuple[InpaintParams, ...]


@dataclass(frozen=True)
class _Done:
    """One frame's results: the encoded raw frame (None when it was cached), the encoded inpainted frames in the
    task's method order, and the compute seconds of the depth and of each method."""

    index: int
    raw: EncodedFrame | None
    inpainted: tuple[EncodedFrame, ...]
    depth_s: float
    inpaint_s: tuple[float, ...]


def _prepare_frame(task: _Task) -> _Done:
    """A worker's chain for one frame (module level: the spawned pool pickles it by name)."""
    t0 = time.perf_counter()
    raw_enc = None
    if task.raw is None:
        frame, mm = quantize_mm(compute_depth(_RIG, task.left_bgr, task.right_bgr, task.depth, task.stamp_ns,
                                              task.index))
        raw_enc = EncodedFrame.of(frame, mm)
    else:
        frame = task.raw.decode(grey=any(uses_guide(p.method) for p in task.inpaint))
    depth_s = time.perf_counter() - t0
    encoded, seconds = [], []
    for params in task.inpaint:
        t1 = time.perf_counter()
        src = frame if uses_guide(params.method) else DepthFrame(frame.stamp_ns, frame.index, frame.depth_m,
                                                                  frame.valid, None)
        done = inpaint_frame(src, params)
        _, mm = quantize_mm(done)
        encoded.append(EncodedFrame.of(done, mm))  # stored as the staged path stores it (unrounded hole ratio)
        seconds.append(time.perf_counter() - t1)
    return _Done(task.index, raw_enc, tuple(encoded), depth_s, tuple(seconds))


def _tasks(seq: Any, raw: DepthCache, stores: Sequence[DepthCache], inpaint: Sequence[InpaintParams],
           depth: DepthParams, stop: int | None, stats: dict[str, Any]) -> Iterator[_Task]:
    """The frames that miss something, in order; frames with nothing missing are counted as cached."""
    need_images = not raw.has_frames(stop)
    guide = any(uses_guide(p.method) for p in inpaint)  # read the raw frames' grey images only for a guide
    frames = seq.stereo_frames(stop_index=stop, left=need_images, right=need_images)
    for sf in frames:
        stats["frames_seen"] = sf.index + 1
        todo = tuple(p for p, s in zip(inpaint, stores) if not s.has(sf.index))
        raw_enc = raw.encoded(sf.index, grey=guide)
        if raw_enc is not None and not todo:
            stats["cached"] += 1
            continue
        if raw_enc is None and sf.left_bgr is None:  # the raw cache lost a frame after all: decode this one
            sf = next(seq.stereo_frames(start_index=sf.index, stop_index=sf.index + 1))
        yield _Task(sf.index, sf.stamp_ns, sf.left_bgr if raw_enc is None else None,
                    sf.right_bgr if raw_enc is None else None, raw_enc, depth, todo)


def _submit(pool: Any, task: _Task) -> Future:
    """``task`` on the pool, or done here (serial: no pool) as an already finished future."""
    if pool is not None:
        return pool.submit(_prepare_frame, task)
    done: Future = Future()
    done.set_result(_prepare_frame(task))
    return done


def prepare_depth_caches(seq: Any, depth: DepthParams, inpaint: Sequence[InpaintParams], cache_root: Path | str,
                         stop_index: int | None = None, workers: int | None = None, progress: bool = True
                         ) -> dict[str, Any]:
    """Fill the raw depth cache of ``seq`` and the inpainted cache of each of ``inpaint`` (frames
    ``0 .. stop_index-1``, all without it), computing only what is missing, on one pool of ``workers`` processes
    (default: all cores; 1: in this process).

    Args:
        seq: a :class:`pipeline.bag_reader.RosarioSequence` (``identity()``, ``calibration``, ``stereo_frames()``,
            ``count()``).
        depth: the depth stage's parameters; every ``inpaint`` entry must inpaint this depth.
    Returns:
        Statistics: ``frames`` (computed, in a worker), ``cached`` (frames with nothing missing), ``depth_computed``,
        ``inpainted`` (method → frames computed), ``depth_s`` / ``inpaint_s`` (method → worker seconds), ``wall_s``.
    Raises:
        AgrivioError: an unknown inpainting method. ValueError: an ``inpaint`` entry for other depth parameters.
    """
    inpaint = list(dict.fromkeys(inpaint))
    for p in inpaint:
        check_method(p.method)
        if p.depth != depth:
            raise ValueError(f"inpainting parameters {p.key()} are for other depth parameters than {depth.key()}")
    t_start = time.perf_counter()
    key = seq.identity()
    raw = DepthCache(cache_root, key, depth)
    stores = [DepthCache(cache_root, key, p) for p in inpaint]
    stats: dict[str, Any] = {"frames": 0, "cached": 0, "depth_computed": 0, "frames_seen": 0,
                             "inpainted": {p.method: 0 for p in inpaint}, "depth_s": 0.0,
                             "inpaint_s": {p.method: 0.0 for p in inpaint}}
    total = seq.count(TOPIC_LEFT_IMAGE)
    stop = stop_index
    complete = raw.has_frames(stop, verify=True) and all(s.has_frames(stop, verify=True) for s in stores)
    if not complete:
        n_workers = max(1, workers or os.cpu_count() or 1)
        methods = ", ".join(p.method for p in inpaint)
        bar = tqdm(total=total if stop is None else min(total, stop), disable=not progress, unit="frame",
                   leave=False, desc="depth" + (f" + inpainting ({methods})" if methods else ""))
        store_of = dict(zip(inpaint, stores))  # frozen parameters compare by value (a task's are pickled copies)
        pool = spawn_pool(n_workers, _init_worker, (seq.calibration,)) if n_workers > 1 else None
        if pool is None:
            _init_worker(seq.calibration)
        try:
            ahead = 2 * n_workers + 2  # frames in flight: enough to keep every worker busy, a few MB each

            queue: deque[tuple[Future, tuple[InpaintParams, ...]]] = deque()

            def store_oldest() -> None:
                """Wait for the oldest frame in flight and store its results (frame order)."""
                fut, task_inpaint = queue.popleft()
                done: _Done = fut.result()
                if done.raw is not None:
                    raw.put_encoded(done.raw)
                    stats["depth_computed"] += 1
                    stats["depth_s"] += done.depth_s
                for p, enc, s in zip(task_inpaint, done.inpainted, done.inpaint_s):
                    store_of[p].put_encoded(enc)
                    stats["inpainted"][p.method] += 1
                    stats["inpaint_s"][p.method] += s
                stats["frames"] += 1

            seen_before = 0
            for task in _tasks(seq, raw, stores, inpaint, depth, stop, stats):
                queue.append((_submit(pool, task), task.inpaint))
                while len(queue) >= ahead:
                    store_oldest()
                bar.update(stats["frames_seen"] - seen_before)
                seen_before = stats["frames_seen"]
            while queue:
                store_oldest()
            bar.update(stats["frames_seen"] - seen_before)
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
            bar.close()
            raw.flush()
            for s in stores:
                s.flush()
        # every frame 0 .. n_seen-1 is stored now, and the sequence ended there (not at stop_index)
        n_seen = stats["frames_seen"]
        if stop is None or n_seen < stop:
            for s in [raw, *stores]:
                if s.n_frames is None:
                    s.mark_complete(n_seen)
    stats["wall_s"] = time.perf_counter() - t_start
    del stats["frames_seen"]
    return stats
