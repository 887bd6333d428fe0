"""Byte-split bags (``sequence01.bag.00``, ``.01``, …) read in place, without concatenating them on disk.

The Rosario server splits the BZ2-compressed bags with ``split --bytes=2GB`` (rosario.md §1). rosbags' ROS1
``Reader`` accepts any object that follows its ``RPath`` protocol (``exists``, ``open('rb')``, ``stat``, …), so
:class:`SplitBagPath` presents the parts as one seekable binary file (:class:`ChainedParts`), opening each part
lazily. Nothing is copied; reading costs one extra Python call per raw read.
"""

from __future__ import annotations

import bisect
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

_PART_RE = re.compile(r"^(?P<stem>.+)\.(?P<num>\d{2,3})$")


def split_parts(stem: Path) -> list[Path]:
    """The numbered parts ``<stem>.00``, ``<stem>.01``, … that exist, in order (empty if none).

    Parts must be numbered consecutively from 0 (two or three digits); a gap ends the list.
    """
    parts: list[Path] = []
    for width in (2, 3):
        i = 0
        while (p := stem.with_name(f"{stem.name}.{i:0{width}d}")).is_file():
            parts.append(p)
            i += 1
        if parts:
            return parts
    return parts


def resolve_bag_parts(path: Path | str) -> tuple[Path, ...]:
    """The file(s) that make up the bag named by ``path``.

    ``path`` may be a plain bag, the first part ``x.bag.00`` of a split bag, or the stem ``x.bag`` when only its
    parts exist. A plain file wins over parts of the same stem.

    Raises:
        FileNotFoundError: nothing matches.
    """
    path = Path(path)
    m = _PART_RE.match(path.name)
    if m and path.is_file():
        stem = path.with_name(m.group("stem"))
        parts = split_parts(stem)
        if parts and parts[0] == path:
            return tuple(parts)
        if parts and path in parts:
            raise FileNotFoundError(f"{path}: is a later part of a split bag; pass the first part {parts[0]}")
        return (path,)
    if path.is_file():
        return (path,)
    parts = split_parts(path)
    if parts:
        return tuple(parts)
    raise FileNotFoundError(f"{path}: no such bag (nor split parts {path.name}.00, .01, ...)")


class ChainedParts(io.RawIOBase):
    """A read-only, seekable raw stream over several files laid end to end.

    Only one part's handle is open at a time. Reads never cross a part boundary in one call (allowed for raw
    streams); wrap in :class:`io.BufferedReader` for ``read(n)`` that fills ``n`` bytes.
    """

    def __init__(self, parts: Sequence[Path]) -> None:
        super().__init__()
        self._parts = [Path(p) for p in parts]
        if not self._parts:
            raise ValueError("ChainedParts needs at least one part")
        sizes = [p.stat().st_size for p in self._parts]
        self._starts = [0]
        for s in sizes:
            self._starts.append(self._starts[-1] + s)
        self._size = self._starts[-1]
        self._pos = 0
        self._idx = -1
        self._fh: BinaryIO | None = None

    @property
    def size(self) -> int:
        """Total size in bytes."""
        return self._size

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if whence == os.SEEK_SET:
            pos = offset
        elif whence == os.SEEK_CUR:
            pos = self._pos + offset
        elif whence == os.SEEK_END:
            pos = self._size + offset
        else:
            raise ValueError(f"invalid whence {whence}")
        if pos < 0:
            raise OSError(f"negative seek position {pos}")
        self._pos = pos
        return pos

    def _part(self, idx: int) -> BinaryIO:
        if idx != self._idx:
            if self._fh is not None:
                self._fh.close()
            self._fh = self._parts[idx].open("rb", buffering=0)
            self._idx = idx
        assert self._fh is not None
        return self._fh

    def readinto(self, buffer: Any) -> int:
        if self.closed:
            raise ValueError("I/O operation on closed file")
        view = memoryview(buffer).cast("B")
        if self._pos >= self._size or len(view) == 0:
            return 0
        idx = bisect.bisect_right(self._starts, self._pos) - 1
        fh = self._part(idx)
        fh.seek(self._pos - self._starts[idx])
        n = min(len(view), self._starts[idx + 1] - self._pos)
        got = fh.readinto(view[:n]) or 0
        self._pos += got
        return got

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        super().close()


class SplitBagPath:
    """A path-like object for rosbags' ``Reader`` that reads byte-split parts as one bag.

    Implements the parts of rosbags' ``RPath`` protocol the ROS1 reader uses (``exists``, ``is_dir``,
    ``open('rb')``, ``stat``, ``name``/``stem``/``suffix``, ``str``).
    """

    def __init__(self, parts: Sequence[Path]) -> None:
        self.parts = tuple(Path(p) for p in parts)
        if not self.parts:
            raise ValueError("SplitBagPath needs at least one part")

    def __str__(self) -> str:
        first = self.parts[0]
        return f"{first.with_suffix('')}.{{{first.suffix[1:]}..{self.parts[-1].suffix[1:]}}}"

    def __repr__(self) -> str:
        return f"SplitBagPath({[str(p) for p in self.parts]!r})"

    @property
    def name(self) -> str:
        return self.parts[0].with_suffix("").name

    @property
    def stem(self) -> str:
        return Path(self.name).stem

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix

    def exists(self) -> bool:
        return all(p.is_file() for p in self.parts)

    def is_dir(self) -> bool:
        return False

    def stat(self, *, follow_symlinks: bool = True) -> os.stat_result:
        """Stat of the first part with ``st_size`` and ``st_mtime`` covering all parts."""
        stats = [p.stat() for p in self.parts]
        fields = list(stats[0])
        fields[6] = sum(s.st_size for s in stats)  # st_size
        fields[8] = max(int(s.st_mtime) for s in stats)  # st_mtime (int field of the tuple)
        return os.stat_result(fields)

    def open(self, mode: str = "rb", *args: Any, **kwargs: Any) -> BinaryIO:
        if mode not in ("rb", "br"):
            raise OSError(f"{self}: split bags are read-only (mode {mode!r})")
        return io.BufferedReader(ChainedParts(self.parts), buffer_size=1 << 16)  # type: ignore[return-value]

    def read_text(self, encoding: str | None = None) -> str:
        raise OSError(f"{self}: a bag is binary")


def bag_source(path: Path | str) -> Path | SplitBagPath:
    """A ``Path`` for a plain bag or a :class:`SplitBagPath` for split parts (see :func:`resolve_bag_parts`)."""
    parts = resolve_bag_parts(path)
    return parts[0] if len(parts) == 1 and not _PART_RE.match(parts[0].name) else SplitBagPath(parts)


def bag_size(source: Path | SplitBagPath) -> int:
    """Total size in bytes of a bag source."""
    return int(source.stat().st_size)
