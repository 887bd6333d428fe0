"""The container of a Rosario v1 ROS1 bag: opening and checking the file (plain, chunk-compressed or byte-split),
its topic index (names, types, counts, time span), raw message streams and its content identity.

Every problem with the file raises :class:`pipeline.errors.BagError` naming the bag (the path as given) and the
problem. Stamps are integer ns.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Reader, ReaderError

from pipeline import rosario_layout as L
from pipeline.bag_parts import SplitBagPath, bag_size, bag_source, resolve_bag_parts
from pipeline.bag_typestore import rosario_typestore
from pipeline.errors import BagError


@dataclass(frozen=True)
class TopicSummary:
    """A topic as stored in the bag: its exact name, rosbags message type and message count."""

    topic: str
    msgtype: str
    count: int



def _read_bag_header(source: Path | SplitBagPath) -> tuple[int, int]:
    """``(index_pos, chunk_count)`` from the bag header record; raises ``ValueError`` if not a ROS1 v2.0 bag."""
    with source.open("rb") as fh:
        magic = fh.readline(64)
        if magic != b"#ROSBAG V2.0\n":
            raise ValueError(f"not a ROS1 v2.0 bag (file starts with {magic[:16]!r})")
        raw = fh.read(4)
        if len(raw) < 4:
            raise ValueError("bag header record is cut off")
        (hlen,) = struct.unpack("<I", raw)
        buf = fh.read(hlen)
        if len(buf) < hlen:
            raise ValueError("bag header record is cut off")
    fields: dict[str, bytes] = {}
    i = 0
    while i + 4 <= len(buf):
        (flen,) = struct.unpack_from("<I", buf, i)
        name, _, value = buf[i + 4:i + 4 + flen].partition(b"=")
        fields[name.decode("ascii", "replace")] = value
        i += 4 + flen
    if fields.get("op") != b"\x03" or "index_pos" not in fields:
        raise ValueError("first record is not a bag header")
    (index_pos,) = struct.unpack("<Q", fields["index_pos"][:8])
    chunk_count = struct.unpack("<I", fields["chunk_count"][:4])[0] if "chunk_count" in fields else -1
    return index_pos, chunk_count


class _DiscardList:
    """Stands in for an index list of a connection nobody asked for: appends are dropped."""

    def append(self, _item: object) -> None:
        pass


class _FilteredIndexes:
    """Index mapping handed to ``Reader.read_index_data``: keeps entries of the wanted connection ids only."""

    def __init__(self, inner: Any, keep: set[int]) -> None:
        self.inner, self.keep, self.discard = inner, keep, _DiscardList()

    def __getitem__(self, conn_id: int) -> Any:
        return self.inner[conn_id] if conn_id in self.keep else self.discard


class _TopicReader(Reader):
    """rosbags ROS1 ``Reader`` that keeps the message index of the given topics only.

    ``Reader.open`` builds an in-memory index entry (~100 B) for every message of every topic. A stream needs
    only its own topics, so the others are dropped while the index is read (the IMU stream no longer pays for
    the image index and vice versa; the metadata pass keeps none). Relies on ``read_index_data(pos, indexes)``
    of rosbags 0.11 (covered by the round-trip tests).
    """

    def __init__(self, path: Any, topics: set[str] | None) -> None:
        super().__init__(path)
        self._keep_topics = topics
        self._filter: _FilteredIndexes | None = None

    def read_index_data(self, pos: int, indexes: Any) -> None:
        if self._keep_topics is None:
            return super().read_index_data(pos, indexes)
        if self._filter is None or self._filter.inner is not indexes:
            keep = {c.id for c in self.connections if L.normalize_topic(c.topic) in self._keep_topics}
            self._filter = _FilteredIndexes(indexes, keep)
        return super().read_index_data(pos, self._filter)


class BagContainer:
    """A bag file (or byte-split bag) opened and checked: header present, indexed, not empty, not truncated.

    Args:
        path: a bag file, the first part ``x.bag.00`` of a byte-split bag, or its stem ``x.bag``.

    Attributes:
        path: the path as given (named in every error); ``parts`` the files it consists of; ``source`` what
            rosbags reads (one file or the concatenated parts); ``size_bytes`` the total size, bytes.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.parts = resolve_bag_parts(path)
        except FileNotFoundError as exc:
            raise BagError(path, f"no such bag file ({exc})") from None
        self.source = bag_source(path)
        self.size_bytes = bag_size(self.source)
        self._check()

    def err(self, problem: str) -> BagError:
        """The error to raise for ``problem`` with this bag."""
        return BagError(self.path, problem)

    def _check(self) -> None:
        if self.size_bytes == 0:
            raise self.err("file is empty (0 bytes)")
        try:
            index_pos, chunk_count = _read_bag_header(self.source)
        except (OSError, ValueError) as exc:
            raise self.err(str(exc)) from None
        if index_pos == 0:
            raise self.err("bag is not indexed (recording was interrupted?); run `rosbag reindex` on it")
        if chunk_count == 0 and index_pos <= self.size_bytes:
            raise self.err("bag is empty (no messages)")
        if index_pos >= self.size_bytes:
            hint = "incomplete download, or a split part missing?" if len(self.parts) > 1 else "incomplete download?"
            raise self.err(f"file is truncated: its index should start at byte {index_pos} but the bag holds only "
                           f"{self.size_bytes} bytes ({hint})")

    def open_reader(self, topics: set[str] | None = None) -> Reader:
        """An open rosbags reader indexing only ``topics`` (normalised names; None = all)."""
        reader = _TopicReader(self.source, topics)
        try:
            reader.open()
        except (ReaderError, struct.error, AssertionError, ValueError, OSError, KeyError, IndexError) as exc:
            raise self.err(f"cannot read bag, truncated or corrupt ({type(exc).__name__}: {exc})") from None
        return reader

    def messages(self, topics: Iterable[str], start_ns: int | None = None, stop_ns: int | None = None,
                 limit: int | None = None) -> Iterator[tuple[str, Any]]:
        """Yield ``(normalised topic, deserialised message)`` in bag-time order for the given topics, bag time in
        ``[start_ns, stop_ns)`` (ns; None = unbounded), at most ``limit`` messages."""
        wanted = {L.normalize_topic(t) for t in topics}
        ts = rosario_typestore()
        reader = self.open_reader(wanted)
        n = 0
        try:
            conns = [c for c in reader.connections if L.normalize_topic(c.topic) in wanted]
            if not conns:
                return
            it = reader.messages(connections=conns, start=start_ns, stop=stop_ns)
            while limit is None or n < limit:
                try:
                    conn, _, raw = next(it)
                    msg = ts.deserialize_ros1(raw, conn.msgtype)
                except StopIteration:
                    return
                except (ReaderError, struct.error, AssertionError, ValueError, OSError, EOFError, KeyError,
                        IndexError) as exc:
                    raise self.err(f"cannot read message on {', '.join(sorted(wanted))} (truncated or corrupt "
                                   f"data: {type(exc).__name__}: {exc})") from None
                n += 1
                yield L.normalize_topic(conn.topic), msg
        finally:
            reader.close()

    def header_stamps_ns(self, topic: str) -> np.ndarray:
        """(N,) int64 header stamps (ns) of every message on ``topic``, in bag order, without deserialising them.

        Every Rosario message with a header starts with it (ROS1: ``uint32 seq, uint32 sec, uint32 nsec``), so the
        stamp is read from bytes 4..12 of the raw message; images are not decoded (cheap next to the depth stage).
        """
        wanted = {L.normalize_topic(topic)}
        reader = self.open_reader(wanted)
        out: list[int] = []
        try:
            conns = [c for c in reader.connections if L.normalize_topic(c.topic) in wanted]
            if conns:
                for _, _, raw in reader.messages(connections=conns):
                    sec, nsec = struct.unpack_from("<II", raw, 4)
                    out.append(sec * 1_000_000_000 + nsec)
        except (ReaderError, struct.error, AssertionError, ValueError, OSError, EOFError, KeyError,
                IndexError) as exc:
            raise self.err(f"cannot read message on {topic} (truncated or corrupt data: "
                           f"{type(exc).__name__}: {exc})") from None
        finally:
            reader.close()
        return np.asarray(out, dtype=np.int64)

    def identity(self) -> str:
        """A content key of the bag: name + BLAKE2 hash of its size, first MiB and last 64 KiB (index region)
        (see :meth:`pipeline.bag_reader.RosarioSequence.identity`)."""
        h = hashlib.blake2b(digest_size=10)
        h.update(str(self.size_bytes).encode())
        with self.source.open("rb") as fh:
            h.update(fh.read(1 << 20))
            fh.seek(max(self.size_bytes - (1 << 16), 0))
            h.update(fh.read(1 << 16))
        name = self.parts[0].name.split(".bag")[0] or "bag"
        return f"{name}-{h.hexdigest()}"


@dataclass(frozen=True)
class BagIndex:
    """The topic index of a bag, from its chunk infos (no message is read).

    Attributes:
        topics: :class:`TopicSummary` keyed by normalised topic name (one leading slash, e.g. ``/tf_static``).
        start_ns, end_ns: bag time of the first and last message, ns.
    """

    topics: dict[str, TopicSummary]
    start_ns: int
    end_ns: int

    @classmethod
    def load(cls, bag: BagContainer, required: Iterable[str]) -> BagIndex:
        """Read the index of ``bag`` and check it: not empty, every ``required`` topic present with messages, and
        every known topic of the Rosario type (:data:`pipeline.rosario_layout.TOPIC_TYPES`)."""
        reader = bag.open_reader(set())  # metadata only: counts and times come from the chunk infos
        try:
            start_ns = int(reader.start_time)
            end_ns = int(reader.end_time)
            topics = {L.normalize_topic(name): TopicSummary(name, info.msgtype or "?", int(info.msgcount))
                      for name, info in reader.topics.items()}
        finally:
            reader.close()
        if sum(t.count for t in topics.values()) == 0:
            raise bag.err("bag is empty (no messages)")
        missing = [t for t in required if L.normalize_topic(t) not in topics or
                   topics[L.normalize_topic(t)].count == 0]
        if missing:
            have = ", ".join(sorted(t.topic for t in topics.values())) or "none"
            raise bag.err(f"missing required topic(s) {', '.join(missing)} (the bag has: {have})")
        for name, expected in L.TOPIC_TYPES.items():
            got = topics.get(L.normalize_topic(name))
            if got is not None and got.msgtype != expected:
                raise bag.err(f"topic {got.topic} has type {got.msgtype}, expected {expected}")
        return cls(topics, start_ns, end_ns)

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` (with or without leading slash) is in the bag."""
        return L.normalize_topic(topic) in self.topics

    def count(self, topic: str) -> int:
        """Number of messages on ``topic`` (with or without leading slash); 0 if absent."""
        t = self.topics.get(L.normalize_topic(topic))
        return t.count if t else 0

    @property
    def duration_s(self) -> float:
        """Time between the first and last message, seconds."""
        return max(self.end_ns - self.start_ns, 0) / 1e9
