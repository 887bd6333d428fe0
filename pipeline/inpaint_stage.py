"""Inpainting stage: fill the holes of every cached depth frame of a sequence with one method, cached on disk.

Inpainted depth is deterministic, so it is computed once per (sequence, depth parameters, method) and reused by
all runs. It is stored with the depth stage's own cache format (whole millimetres, PNG-compressed chunks) in a
sibling folder keyed by the method as well; the hole mask of a frame is the raw depth frame's ``~valid``.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from inpaint import METHODS, inpaint
from pipeline.depth import DepthFrame, DepthParams, quantize_mm
from pipeline.depth_cache import DepthCache, depth_stream
from pipeline.errors import AgrivioError
from pipeline.process_pool import spawn_pool

#: Bump when the stage changes its outputs (invalidates inpainted caches). 2: ``paper`` is the coarse-to-fine
#: formulation (the greedy one is ``paper-greedy``). 3: issue 12 — compiled coarsest search (rounding), nearest-source
#: init, the network in its inference form and the fusion skip where candidates agree. 4: issue 12, second round —
#: the fusion network compiled (``inpaint.fusion_kernels``), a 4-channel decoder (new ``fusion_net_c2f`` weights),
#: one PatchMatch scan per pass, the anchored candidate shift in float64. 5: issue 12, generalisation — ``paper``'s
#: shifted candidates are clamped to the values of their source block and the target block (``shift_clamp``).
INPAINT_STAGE_VERSION = 5


@dataclass(frozen=True)
class InpaintParams:
    """Which depth is inpainted and how. ``options``: keyword options of the method, as a sorted tuple of pairs."""

    depth: DepthParams = field(default_factory=DepthParams)
    method: str = "paper"
    options: tuple[tuple[str, Any], ...] = ()

    def key(self) -> str:
        blob = json.dumps({"depth": self.depth.key(), "method": self.method, "options": list(self.options),
                           "version": INPAINT_STAGE_VERSION, "weights": _weights_fingerprint(self.method)},
                          sort_keys=True, default=str)
        return f"inpaint-{self.method}-" + hashlib.blake2b(blob.encode(), digest_size=8).hexdigest()


def _weights_fingerprint(method: str) -> str:
    """Hash of the shipped network weights (the paper's method): new weights invalidate its caches."""
    if method not in ("paper", "paper-greedy"):
        return ""
    weights = Path(__file__).resolve().parent.parent / "inpaint" / "weights"
    digest = hashlib.blake2b(digest_size=8)
    for path in sorted(weights.glob("*.pt")):
        digest.update(path.read_bytes())
    return digest.hexdigest()


#: Methods of :data:`inpaint.METHODS` that read the ``guide`` image (the rectified left grey). None does today:
#: every method works on depth only, so no guide is handed over. A method may also declare it itself with a
#: ``uses_guide = True`` attribute on its function.
GUIDED_METHODS: frozenset[str] = frozenset()


def check_method(method: str) -> None:
    """Raise :class:`AgrivioError` when ``method`` is not an inpainting method of :data:`inpaint.METHODS`."""
    if method not in METHODS:
        raise AgrivioError(f"unknown inpainting method {method!r}; available: {', '.join(sorted(METHODS))}")


def uses_guide(method: str) -> bool:
    """Whether ``method`` reads the guide image (:data:`GUIDED_METHODS` or the method's ``uses_guide``)."""
    return method in GUIDED_METHODS or bool(getattr(METHODS.get(method), "uses_guide", False))


def inpaint_frame(frame: DepthFrame, params: InpaintParams) -> DepthFrame:
    """The inpainted version of one raw depth frame (known pixels unchanged; the rectified left grey is the guide
    of a method that reads one, :func:`uses_guide`). The result carries no grey image: inpainted frames are read
    for their depth only (the raw depth cache keeps the grey)."""
    hole = ~frame.valid
    if not hole.any():
        filled = frame.depth_m.copy()
    elif not frame.valid.any():
        filled = frame.depth_m.copy()  # nothing to inpaint from: the frame stays all-hole
    else:
        guide = frame.left_rect_grey if uses_guide(params.method) else None
        filled = inpaint(np.nan_to_num(frame.depth_m, nan=0.0).astype(np.float32), hole, guide,
                         method=params.method, **dict(params.options))
    filled = np.asarray(filled, dtype=np.float32)
    valid = np.isfinite(filled) & (filled > 0)
    return DepthFrame(frame.stamp_ns, frame.index, np.where(valid, filled, np.nan).astype(np.float32), valid, None)


def inpainted_stream(sequence: Any, params: InpaintParams, cache_root: Path | str, progress: bool = True,
                     stats: dict[str, Any] | None = None, workers: int | None = None,
                     stop_index: int | None = None) -> Iterator[DepthFrame]:
    """Inpainted depth frames of ``sequence`` in order: from the cache, or computed from the raw depth and cached.

    Frames are independent, so missing ones are inpainted on a process pool of ``workers`` (default: all cores);
    the result does not depend on the number of workers. ``stop_index``: only frames ``0 .. stop_index-1`` (the
    runs' ``--max-frames``); the cache is marked complete only when the whole sequence was seen.
    """
    check_method(params.method)
    st = stats if stats is not None else {}
    st.update(computed=0, cached=0, compute_s=0.0)
    store = DepthCache(cache_root, sequence.identity(), params)
    st["directory"] = str(store.directory)
    stop = _complete_stop(store, stop_index)
    if stop is not None:
        for frame in store.iter(0, stop, grey=False):
            st["cached"] += 1
            yield frame
        return
    n_workers = max(1, workers or os.cpu_count() or 1)
    raw = depth_stream(sequence, params.depth, cache=True, progress=False, cache_root=cache_root,
                       stop_index=stop_index, grey=uses_guide(params.method))
    n = 0
    pool = spawn_pool(n_workers) if n_workers > 1 else None
    try:
        with tqdm(desc=f"inpaint ({params.method})", unit="frame", disable=not progress, leave=False) as bar:
            while True:
                batch = list(itertools.islice(raw, 2 * n_workers))
                if not batch:
                    break
                todo = [f for f in batch if not store.has(f.index)]
                t0 = time.perf_counter()
                mapper = pool.map if pool is not None else map
                fresh: dict[int, DepthFrame] = {}
                for done in mapper(inpaint_frame, todo, itertools.repeat(params)):
                    # the cached (millimetre) version, as later reads see it, without a PNG decode round trip
                    frame_mm, mm = quantize_mm(done)
                    store.put(done, mm)  # stored exactly as before (its hole ratio is the unrounded frame's)
                    fresh[frame_mm.index] = frame_mm
                st["compute_s"] += time.perf_counter() - t0
                st["computed"] += len(todo)
                st["cached"] += len(batch) - len(todo)
                for f in batch:
                    n += 1
                    bar.update(1)
                    yield fresh[f.index] if f.index in fresh else store.get(f.index, grey=False)
    finally:
        if pool is not None:
            pool.shutdown()
    store.flush()
    if stop_index is None or n < stop_index:  # the whole sequence was seen
        store.mark_complete(n)


def _complete_stop(store: DepthCache, stop_index: int | None) -> int | None:
    """The number of frames to serve from a cache that holds all of them intact (frames ``0 .. stop_index-1``, or
    the whole sequence), or None when something must be (re)computed; a corrupt chunk reads as missing."""
    n_total = store.n_frames
    if n_total is None:
        return None
    stop = n_total if stop_index is None else min(n_total, stop_index)
    return stop if store.has_frames(stop, verify=True) else None


def ensure_inpainted(sequence: Any, params: InpaintParams, cache_root: Path | str, progress: bool = True,
                     stats: dict[str, Any] | None = None, stop_index: int | None = None) -> None:
    """Make sure frames ``0 .. stop_index-1`` (all without it) are in the inpainted cache, computing what is
    missing; a complete, intact cache is checked without decoding any image (``stats['cached']`` counts it)."""
    st = stats if stats is not None else {}
    store = DepthCache(cache_root, sequence.identity(), params)
    stop = _complete_stop(store, stop_index)
    if stop is not None:
        st.update(computed=0, cached=stop, compute_s=0.0, directory=str(store.directory))
        return
    for _ in inpainted_stream(sequence, params, cache_root, progress=progress, stats=st, stop_index=stop_index):
        pass


def params_summary(params: InpaintParams) -> dict[str, Any]:
    return {"method": params.method, "options": dict(params.options), "depth": asdict(params.depth)}
