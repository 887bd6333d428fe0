"""On-disk cache of the depth stage, and the streaming entry point :func:`depth_stream`.

Layout (under ``cache_root``, by default ``pipeline.paths.cache_dir()``)::

    depth/<bag identity>/<params key>/
        meta.json              params, bag identity, chunk size, and ``n_frames`` once the sequence is complete
        chunk_000000.npz       frames [0, chunk_size): indices, stamps, hole ratios, encoded depth and grey images
                               (the chunk layout of :mod:`pipeline.png_chunks`; chunks of the earlier layout
                               are still read)

Depth is stored as whole millimetres (0 = hole) in an LZ4 stream of the uint16 map (:mod:`pipeline.lz4_codec`:
12× faster to decode than the 16-bit PNG written before, which every depth-variant run does once or twice per
frame; caches holding PNG depth are still read, the two decode to the same values) and the rectified left grey
image as 8-bit PNG (lossless, compact: PNG's row filters suit images far better than raw zlib). The grey image is
stored only where a frame carries one (the raw depth stage's frames; the inpainting stage stores none: its frames
are read for their depth only) and decoded only on request (``grey=True``). Chunk files are written atomically.
The key is the bag's content identity (:meth:`RosarioSequence.identity`) plus :meth:`DepthParams.key` (which
includes the stage and OpenCV versions), so a changed bag or parameter never reads stale depth.
"""

from __future__ import annotations

import json
import sys
import time
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from pipeline.atomic import write_json_atomic
from pipeline.depth import DepthFrame, DepthParams, compute_depth, decode_depth_mm, encode_depth_mm, quantize_mm
from pipeline.lz4_codec import decode_lz4_map, encode_lz4_map, is_lz4_map
from pipeline.png_chunks import EMPTY, chunk_from_npz, write_chunk
from pipeline.png_codec import PNG_COMPACT, decode_png, encode_png

DEFAULT_CHUNK_SIZE = 32
_WHERE = "depth cache"


def _png(img: np.ndarray) -> np.ndarray:
    return encode_png(img, PNG_COMPACT)


def _unpng(buf: np.ndarray) -> np.ndarray:
    return decode_png(buf, _WHERE)


def _depth_mm(buf: np.ndarray) -> np.ndarray:
    """The (H, W) uint16 millimetre map of a stored depth stream: LZ4 (written now) or PNG (older caches)."""
    return decode_lz4_map(buf, _WHERE) if is_lz4_map(buf) else _unpng(buf)


@dataclass(frozen=True)
class EncodedFrame:
    """One frame as stored: stamp, index, the depth stream (LZ4, or PNG in older caches) and the grey image's PNG
    (a few hundred kB instead of ~1.5 MB; :data:`EMPTY` when the frame has none or it was not read)."""

    stamp_ns: int
    index: int
    depth_stream: np.ndarray
    grey_png: np.ndarray
    hole_ratio: float = float("nan")  # NaN: a chunk written before hole ratios were stored

    @classmethod
    def of(cls, frame: DepthFrame, depth_mm: np.ndarray | None = None) -> EncodedFrame:
        """Encode ``frame``; ``depth_mm``: its uint16 millimetre map when the caller already has it (not rounded
        again)."""
        mm = encode_depth_mm(frame.depth_m) if depth_mm is None else depth_mm
        grey = EMPTY if frame.left_rect_grey is None else _png(np.ascontiguousarray(frame.left_rect_grey))
        return cls(int(frame.stamp_ns), int(frame.index), encode_lz4_map(mm), grey, frame.hole_ratio)

    def decode(self, grey: bool = True) -> DepthFrame:
        """The frame; its grey image only when ``grey`` and one was stored (else None)."""
        depth, valid = decode_depth_mm(_depth_mm(self.depth_stream))
        return DepthFrame(self.stamp_ns, self.index, depth, valid,
                          _unpng(self.grey_png) if grey and self.grey_png.size else None)


def _read_frames(path: Path, grey: bool = True) -> dict[int, EncodedFrame]:
    """The frames of one chunk file: the shared layout (:mod:`pipeline.png_chunks`), or the layout this cache
    wrote before it (``stamps_ns``, ``indices``, optional ``hole_ratios``, ``depth_K`` / ``grey_K`` per frame).
    ``grey=False``: the grey images are not read (their streams are :data:`EMPTY`): a depth-only reader skips
    ≈ 2/3 of a raw chunk's bytes."""
    with np.load(path) as z:
        if "indices" not in z.files:
            c = chunk_from_npz(z, None if grey else ("depth",))
            holes = c.columns.get("hole_ratio")
            return {int(index): EncodedFrame(int(stamp), int(index), c.blob("depth", k), c.blob("grey", k),
                                             float(holes[k]) if holes is not None else float("nan"))
                    for k, (stamp, index) in enumerate(zip(c.stamp_ns.tolist(), c.index.tolist()))}
        holes_old = z["hole_ratios"].tolist() if "hole_ratios" in z.files else None
        return {int(index): EncodedFrame(int(stamp), int(index), z[f"depth_{k}"], z[f"grey_{k}"] if grey else EMPTY,
                                         float(holes_old[k]) if holes_old is not None else float("nan"))
                for k, (stamp, index) in enumerate(zip(z["stamps_ns"].tolist(), z["indices"].tolist()))}


class KeyedParams(Protocol):
    """Parameters that select a cache folder by their :meth:`key` (:class:`DepthParams`,
    :class:`pipeline.inpaint_stage.InpaintParams`, :class:`CacheKey`)."""

    def key(self) -> str: ...


@dataclass(frozen=True)
class CacheKey:
    """A cache's parameter key as a run recorded it (``input_key_parts``: :meth:`DepthParams.key` or
    :meth:`InpaintParams.key`), for reading that cache without rebuilding its parameters (e.g. the replay)."""

    value: str

    def key(self) -> str:
        return self.value


class DepthCache:
    """Depth frames of one bag and one parameter set, stored in chunks of ``chunk_size`` frames.

    Frames are held encoded (LZ4 / PNG) in memory too, so a chunk in flight costs ~10 MB, not ~50 MB.

    Args:
        cache_root: root folder (``depth/`` is created below it).
        bag_key: the bag identity (e.g. ``RosarioSequence.identity()``).
        params: the parameters (:class:`DepthParams`, an inpainting stage's :class:`InpaintParams`, or a recorded
            :class:`CacheKey`); their key selects the sub-folder.
        chunk_size: frames per chunk file (an existing cache keeps the size it was written with).
    """

    def __init__(self, cache_root: Path | str, bag_key: str, params: KeyedParams,
                 chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
        self.params = params
        self.bag_key = bag_key
        self.directory = Path(cache_root) / "depth" / bag_key / params.key()
        meta = self._read_meta()
        self.chunk_size = int(meta.get("chunk_size", chunk_size)) if meta else int(chunk_size)
        self._pending: dict[int, dict[int, EncodedFrame]] = {}
        # the last chunk read: (chunk, frames, whether its grey images were read)
        self._loaded: tuple[int, dict[int, EncodedFrame], bool] | None = None

    # ---- metadata ----------------------------------------------------------------------------------------------
    @property
    def meta_path(self) -> Path:
        return self.directory / "meta.json"

    def _read_meta(self) -> dict[str, Any]:
        try:
            return json.loads(self.meta_path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return {}

    def _write_meta(self, **extra: Any) -> None:
        meta = {"bag": self.bag_key, "params": asdict(self.params), "params_key": self.params.key(),
                "chunk_size": self.chunk_size, **extra}
        write_json_atomic(self.meta_path, meta)

    @property
    def n_frames(self) -> int | None:
        """Number of frames of the sequence if the cache is complete, else None."""
        n = self._read_meta().get("n_frames")
        return int(n) if n is not None else None

    def has_frames(self, stop: int | None, verify: bool = False) -> bool:
        """True when frames ``0 .. stop-1`` are all stored (``stop`` None: the whole sequence).

        A cache marked complete (``n_frames``) is trusted unless ``verify``; otherwise the chunk files are read
        (their zip CRC-32 checked, images not decoded) and a damaged chunk counts as missing frames.
        """
        n = self.n_frames
        if stop is None:
            if n is None:
                return False
            stop = n
        elif n is not None:
            stop = min(stop, n)  # the sequence has only n frames
        if n is not None and not verify:
            return True
        for chunk in range((stop + self.chunk_size - 1) // self.chunk_size):
            frames = self._pending.get(chunk) or self._load_chunk(chunk)
            if any(i not in frames for i in range(chunk * self.chunk_size, min((chunk + 1) * self.chunk_size, stop))):
                return False
        return True

    def mark_complete(self, n_frames: int) -> None:
        """Record that frames ``0 .. n_frames-1`` are all stored."""
        self._write_meta(n_frames=int(n_frames))

    # ---- chunks ------------------------------------------------------------------------------------------------
    def _chunk_path(self, chunk: int) -> Path:
        return self.directory / f"chunk_{chunk:06d}.npz"

    def _load_chunk(self, chunk: int, grey: bool = True) -> dict[int, EncodedFrame]:
        """The stored frames of ``chunk`` (``grey=False``: without their grey images; never merged into a chunk
        that is written again, :meth:`put_encoded` reads the whole chunk)."""
        if self._loaded is not None and self._loaded[0] == chunk and (self._loaded[2] or not grey):
            return self._loaded[1]
        path = self._chunk_path(chunk)
        frames: dict[int, EncodedFrame] = {}
        if path.is_file():
            try:
                frames = _read_frames(path, grey)
            except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                # a truncated or garbled chunk (zip CRC-32 / structure check) is said once and recomputed
                print(f"warning: {path}: corrupt depth-cache chunk ({type(exc).__name__}: {exc}); it is "
                      f"recomputed", file=sys.stderr)
                frames = {}
        self._loaded = (chunk, frames, grey)
        return frames

    def _write_chunk(self, chunk: int, frames: dict[int, EncodedFrame]) -> None:
        ordered = [frames[i] for i in sorted(frames)]
        self.directory.mkdir(parents=True, exist_ok=True)
        if not self.meta_path.exists():
            self._write_meta()
        write_chunk(self._chunk_path(chunk), [f.index for f in ordered], [f.stamp_ns for f in ordered],
                    {"depth": [f.depth_stream for f in ordered], "grey": [f.grey_png for f in ordered]},
                    {"hole_ratio": np.array([f.hole_ratio for f in ordered], dtype=np.float64)})
        self._loaded = (chunk, dict(frames), True)

    # ---- public API --------------------------------------------------------------------------------------------
    def encoded(self, index: int, grey: bool = True) -> EncodedFrame | None:
        """Frame ``index`` as stored (nothing decoded), or None; ``grey=False``: its grey image is not read (its
        ``grey_png`` may be :data:`EMPTY`)."""
        chunk = index // self.chunk_size
        return self._pending.get(chunk, {}).get(index) or self._load_chunk(chunk, grey).get(index)

    def has(self, index: int) -> bool:
        """Whether frame ``index`` is stored (nothing is decoded)."""
        return self.encoded(index, grey=False) is not None

    def get(self, index: int, grey: bool = True) -> DepthFrame | None:
        """The cached frame ``index`` (depth in whole millimetres) or None. ``grey=False`` skips decoding the
        rectified grey image (``left_rect_grey`` is then None): the VIO reads only the depth."""
        enc = self.encoded(index, grey)
        return enc.decode(grey) if enc is not None else None

    def put(self, frame: DepthFrame, depth_mm: np.ndarray | None = None) -> None:
        """Store a frame (depth rounded to millimetres). A chunk is written once all its frames are present.

        ``depth_mm``: the frame's depth as (H, W) uint16 millimetres (``pipeline.depth.quantize_mm``) when the
        caller has rounded it already; then it is stored as is.
        """
        self.put_encoded(EncodedFrame.of(frame, depth_mm))

    def put_encoded(self, enc: EncodedFrame) -> None:
        """Store a frame encoded already (:meth:`EncodedFrame.of`, e.g. by a worker process); as :meth:`put`."""
        chunk = enc.index // self.chunk_size
        if chunk not in self._pending:
            self._pending[chunk] = dict(self._load_chunk(chunk))
        pending = self._pending[chunk]
        pending[enc.index] = enc
        if len(pending) == self.chunk_size:
            self._write_chunk(chunk, self._pending.pop(chunk))

    def flush(self) -> None:
        """Write partially filled chunks (at the end of a sequence or when interrupted)."""
        for chunk in sorted(self._pending):
            self._write_chunk(chunk, self._pending[chunk])
        self._pending.clear()

    def hole_ratios(self, stop: int) -> np.ndarray | None:
        """(stop,) hole ratio of frames ``0 .. stop-1`` without decoding their images (chunks from before the
        ratios were stored decode the depth), or None when a frame is missing."""
        out = np.empty(stop, dtype=np.float64)
        for index in range(stop):
            enc = self.encoded(index, grey=False)
            if enc is None:
                return None
            h = enc.hole_ratio
            out[index] = h if np.isfinite(h) else float(1.0 - decode_depth_mm(_depth_mm(enc.depth_stream))[1].mean())
        return out

    def iter(self, start: int = 0, stop: int | None = None, grey: bool = True) -> Iterator[DepthFrame]:
        """Cached frames ``start, start+1, …`` in order, ending at ``stop`` or at the first missing frame
        (``grey=False``: their grey images are not decoded)."""
        index = start
        while stop is None or index < stop:
            frame = self.get(index, grey)
            if frame is None:
                return
            yield frame
            index += 1

    def __iter__(self) -> Iterator[DepthFrame]:
        return self.iter()


def depth_stream(sequence: Any, params: DepthParams = DepthParams(), cache: bool = True, progress: bool = True,
                 cache_root: Path | str | None = None, stats: dict[str, Any] | None = None,
                 start_index: int = 0, stop_index: int | None = None, grey: bool = True) -> Iterator[DepthFrame]:
    """Depth frames of a sequence in order, read from the cache or computed (and cached) when missing.

    Args:
        sequence: a :class:`pipeline.bag_reader.RosarioSequence` (``identity()``, ``calibration``,
            ``stereo_frames()``, ``count()``).
        cache: read and write the on-disk cache; False computes every frame and stores nothing.
        progress: show a tqdm bar on stderr.
        cache_root: cache root (default ``pipeline.paths.cache_dir()``).
        stats: optional dict filled with ``computed``, ``cached``, ``compute_s`` (seconds spent computing),
            ``directory`` (cache folder or None).
        start_index, stop_index: frame index range.
        grey: decode the rectified grey image of cached frames (computed frames always carry it).
    Yields:
        :class:`DepthFrame`, depth rounded to whole millimetres in both paths (so results never depend on
        whether the cache was warm).
    """
    from tqdm import tqdm

    from pipeline.paths import cache_dir
    from pipeline.rosario_layout import TOPIC_LEFT_IMAGE

    st = stats if stats is not None else {}
    st.update(computed=0, cached=0, compute_s=0.0, directory=None)
    store = DepthCache(cache_root or cache_dir(), sequence.identity(), params) if cache else None
    if store is not None:
        st["directory"] = str(store.directory)
    total = sequence.count(TOPIC_LEFT_IMAGE)
    bar = tqdm(total=total if stop_index is None else min(total, stop_index), initial=start_index,
               disable=not progress, unit="frame", desc="depth", leave=False)
    try:
        index = start_index
        if store is not None:
            for frame in store.iter(start_index, stop_index, grey):
                st["cached"] += 1
                bar.update(1)
                index = frame.index + 1
                yield frame
            n = store.n_frames
            if n is not None and index >= n:
                return
        if stop_index is not None and index >= stop_index:
            return
        rig = sequence.calibration
        n_seen = index  # frames of the sequence seen so far (for the completeness marker)
        for sf in sequence.stereo_frames(start_index=index, stop_index=stop_index):
            n_seen = sf.index + 1
            frame = store.get(sf.index) if store is not None else None
            if frame is not None:
                st["cached"] += 1
            else:
                t0 = time.perf_counter()
                frame, mm = quantize_mm(compute_depth(rig, sf.left_bgr, sf.right_bgr, params, sf.stamp_ns, sf.index))
                st["compute_s"] += time.perf_counter() - t0
                st["computed"] += 1
                if store is not None:
                    store.put(frame, mm)  # rounded to millimetres once
            bar.update(1)
            yield frame
        if store is not None:
            store.flush()
            # every frame 0 .. n_seen-1 is now stored, and the sequence ended there (not at stop_index)
            if start_index == 0 and (stop_index is None or n_seen < stop_index):
                store.mark_complete(n_seen)
    finally:
        if store is not None:
            store.flush()
        bar.close()
