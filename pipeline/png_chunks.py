"""The one on-disk layout of agrivio's chunked image stores: a ``.npz`` file per chunk of consecutive frames,
each frame a few encoded image layers (PNG, :mod:`pipeline.png_codec`; the depth cache's depth layer is an LZ4 map
stream, :mod:`pipeline.lz4_codec`: the layout holds any byte streams). Used by the depth-stage cache
(:mod:`pipeline.depth_cache`: layers ``depth`` and ``grey``, column ``hole_ratio``) and the simulator's
ground-truth chunks (:mod:`pipeline.sim.export`: ``depth``, ``label``, ``glare``, optionally ``rdepth``/``rlabel``).

Layout of one chunk (all arrays of ``np.savez``, in this order):

- ``index`` (n,) int64 frame indices, ``stamp_ns`` (n,) int64 stamps;
- per-frame numeric columns, e.g. ``hole_ratio`` (n,) float64;
- per layer ``NAME``: ``NAME`` (total,) uint8, the frames' byte streams concatenated, and ``NAME_off``
  (n + 1,) int64 offsets; frame ``k``'s stream is ``NAME[NAME_off[k]:NAME_off[k + 1]]`` (empty: the frame has no
  such image). A layer no frame has is left out.

Files are written atomically (temporary name, then rename).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_path

#: The stream of a frame that has no image in a layer.
EMPTY = np.zeros(0, dtype=np.uint8)


def write_chunk(path: Path | str, index: Sequence[int], stamp_ns: Sequence[int],
                layers: Mapping[str, Sequence[bytes | np.ndarray | None]],
                columns: Mapping[str, np.ndarray] | None = None) -> None:
    """Write one chunk of ``n = len(index)`` frames (see the module docstring).

    Args:
        index, stamp_ns: the frames' indices and stamps (ns).
        layers: name → n encoded byte streams (``bytes`` or uint8 arrays; None or empty: the frame has none).
        columns: name → (n,) per-frame numeric values.
    """
    arrays: dict[str, np.ndarray] = {"index": np.asarray(index, np.int64), "stamp_ns": np.asarray(stamp_ns, np.int64)}
    for name, values in (columns or {}).items():
        arrays[name] = np.asarray(values)
    for name, blobs in layers.items():
        streams = [EMPTY if b is None else np.frombuffer(b, np.uint8) if isinstance(b, bytes) else
                   np.asarray(b, np.uint8).reshape(-1) for b in blobs]
        if not any(len(b) for b in streams):
            continue
        arrays[name] = np.concatenate(streams)
        arrays[name + "_off"] = np.cumsum([0] + [len(b) for b in streams]).astype(np.int64)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


@dataclass(frozen=True)
class Chunk:
    """One chunk read back: ``index`` / ``stamp_ns`` (n,), ``columns`` and the layers' concatenated streams."""

    index: np.ndarray
    stamp_ns: np.ndarray
    columns: dict[str, np.ndarray]
    layers: dict[str, tuple[np.ndarray, np.ndarray]]

    def blob(self, layer: str, k: int) -> np.ndarray:
        """Frame ``k``'s (position in the chunk) stream of ``layer``; :data:`EMPTY` when it has none (also when
        no frame of the chunk has that layer)."""
        if layer not in self.layers:
            return EMPTY
        data, off = self.layers[layer]
        return data[off[k]:off[k + 1]] if off[k + 1] > off[k] else EMPTY

    def position(self, index: int) -> int | None:
        """Position of frame ``index`` in the chunk, or None."""
        pos = np.flatnonzero(self.index == index)
        return int(pos[0]) if pos.size else None


def read_chunk(path: Path | str) -> Chunk:
    """Read a chunk written by :func:`write_chunk`.

    Raises:
        FileNotFoundError; OSError, ValueError, KeyError, EOFError, ``zipfile.BadZipFile``, ``zlib.error``: a
        truncated or garbled file (the caller decides whether to recompute it).
    """
    with np.load(path) as z:
        return chunk_from_npz(z)


def chunk_from_npz(z: np.lib.npyio.NpzFile, layers: Sequence[str] | None = None) -> Chunk:
    """The :class:`Chunk` of an open ``.npz`` in this layout (for a reader that has already opened the file).

    ``layers``: read only these layers (the others are neither read nor checked; None: all)."""
    files = set(z.files)
    names = [name for name in files if name + "_off" in files]
    skip = {"index", "stamp_ns"} | set(names) | {name + "_off" for name in names}
    read = {name: (z[name], z[name + "_off"]) for name in names if layers is None or name in layers}
    columns = {name: z[name] for name in sorted(files - skip)}
    return Chunk(z["index"], z["stamp_ns"], columns, read)


__all__ = ["EMPTY", "Chunk", "chunk_from_npz", "read_chunk", "write_chunk"]
