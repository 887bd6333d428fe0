"""Stream a Rosario v1 ROS1 bag: stereo frames, IMU, GPS, odometry, static transforms, calibration.

:class:`RosarioSequence` opens a bag (plain, BZ2/LZ4 chunk-compressed, or byte-split ``x.bag.00``, ``.01``, …),
checks it, and streams every sensor in timestamp order without loading the bag: each stream opens its own
rosbags ``Reader`` and decompresses one chunk at a time. Only rosbags' message index (a few ints per message)
stays in memory. Each stream may be iterated independently, also interleaved (e.g. IMU and frames for the VIO).

Stamps are ``header.stamp`` in integer nanoseconds (equal to bag time in Rosario bags). Units: rad/s, m/s²,
metres, degrees for latitude/longitude. Frames: IMU samples are in the Rosario IMU frame (x up, y right,
z forward); images are raw (distorted, unrectified) BGR 376×672.

Every problem with the input raises :class:`pipeline.errors.BagError` naming the file and the problem.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.rosbag1 import Reader, ReaderError
from scipy.spatial.transform import Rotation

from eval.trajectory import Trajectory, read_tum
from msckf.camera import StereoRig
from pipeline import rosario_layout as L
from pipeline.bag_parts import SplitBagPath, bag_size, bag_source, resolve_bag_parts
from pipeline.bag_typestore import rosario_typestore
from pipeline.calibration import CalibrationError, Camchain, CameraInfo, read_camchain, rig_from_camera_info
from pipeline.errors import BagError
from pipeline.paths import ROSARIO_CAMCHAIN

ImuStampPolicy = Literal["spread", "keep", "drop"]


# ---- sample types ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoFrame:
    """A stereo pair matched by stamp.

    Attributes:
        stamp_ns: left image header stamp, ns.
        left_bgr, right_bgr: (H, W, 3) uint8 raw BGR images (writable copies); ``right_bgr`` is None when the
            caller asked for the left images only (``stereo_frames(right=False)``).
        index: 0-based pair number from the start of the bag (stable across calls; used as the depth-cache key).
    """

    stamp_ns: int
    left_bgr: np.ndarray
    right_bgr: np.ndarray | None
    index: int


@dataclass(frozen=True)
class ImuSample:
    """One IMU reading: ``gyro`` (3,) rad/s and ``accel`` (3,) m/s² (gravity included), Rosario IMU axes."""

    stamp_ns: int
    gyro: np.ndarray
    accel: np.ndarray


@dataclass(frozen=True)
class GpsFix:
    """One ``/gps/fix``: lat/lon in degrees, ellipsoidal altitude in m, NavSatStatus ``status``, (3, 3) cov m²."""

    stamp_ns: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    status: int
    covariance: np.ndarray


@dataclass(frozen=True)
class GpsVelocity:
    """One ``/gps/vel``: ground velocity east and north, m/s."""

    stamp_ns: int
    v_east: float
    v_north: float


@dataclass(frozen=True)
class OdomSample:
    """One ``/odom`` sample: planar pose ``x, y`` (m), ``yaw`` (rad) of base_link in the odom frame,
    ``v`` = twist.linear.x (signed speed, m/s; bags before 2024-03 held v_x in the odom frame), ``yaw_rate`` rad/s."""

    stamp_ns: int
    x: float
    y: float
    yaw: float
    v: float
    yaw_rate: float


@dataclass(frozen=True)
class StaticTransform:
    """One transform of a ``tf_static`` message: ``T_parent_child`` (4, 4) maps child-frame points into parent."""

    stamp_ns: int
    parent: str
    child: str
    T_parent_child: np.ndarray


@dataclass(frozen=True)
class TopicSummary:
    """A topic as stored in the bag: its exact name, rosbags message type and message count."""

    topic: str
    msgtype: str
    count: int


@dataclass
class ReaderStats:
    """Counters of the last pass over each stream (reset when that stream restarts).

    Attributes:
        stereo_pairs: pairs yielded (inside the requested index range) plus skipped before it.
        unpaired_left, unpaired_right: images whose partner was missing (skipped, not fatal).
        imu_samples: IMU samples yielded.
        imu_repeated_stamps: samples whose stamp equalled the previous one (original bags).
        imu_out_of_order: samples dropped because their stamp went backwards.
    """

    stereo_pairs: int = 0
    unpaired_left: int = 0
    unpaired_right: int = 0
    imu_samples: int = 0
    imu_repeated_stamps: int = 0
    imu_out_of_order: int = 0


# ---- helpers ---------------------------------------------------------------------------------------------------
def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


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


def _camera_info(msg: Any) -> CameraInfo:
    return CameraInfo(width=int(msg.width), height=int(msg.height), distortion_model=str(msg.distortion_model),
                      K=np.asarray(msg.K, dtype=np.float64).reshape(3, 3), D=np.asarray(msg.D, dtype=np.float64),
                      R=np.asarray(msg.R, dtype=np.float64).reshape(3, 3),
                      P=np.asarray(msg.P, dtype=np.float64).reshape(3, 4))


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


# ---- the sequence ----------------------------------------------------------------------------------------------
class RosarioSequence:
    """A Rosario v1 bag opened for streaming.

    Args:
        path: a bag file, the first part ``x.bag.00`` of a byte-split bag, or its stem ``x.bag``.
        camchain: Kalibr camchain YAML (or a parsed :class:`Camchain`) giving the camera–IMU extrinsics;
            default the shipped Rosario one (``data/rosario_camchain.yaml``).
        pair_tolerance_ns: largest |left − right| stamp difference for a stereo pair (default 5 ms; frames are
            66.7 ms apart at 15 Hz).
        imu_stamps: how repeated IMU stamps (original bags) are handled: ``"spread"`` (default: a run of k
            samples sharing a stamp is spread evenly up to the next distinct stamp, as the authors' 2021 fix
            did over the whole log), ``"keep"`` (as recorded) or ``"drop"`` (keep the first of each run).
        required_topics: topics that must be present (default: images, camera_info, IMU).

    Raises:
        BagError: the bag is missing, empty, truncated, not indexed, lacks a required topic, holds a topic of the
            wrong type, non-``bgr8`` images, or images whose size differs from camera_info.
    """

    def __init__(self, path: Path | str, camchain: Path | str | Camchain | None = None, *,
                 pair_tolerance_ns: int = 5_000_000, imu_stamps: ImuStampPolicy = "spread",
                 required_topics: Iterable[str] = L.REQUIRED_TOPICS) -> None:
        self.path = Path(path)
        if imu_stamps not in ("spread", "keep", "drop"):
            raise ValueError(f"imu_stamps must be 'spread', 'keep' or 'drop', got {imu_stamps!r}")
        self.pair_tolerance_ns = int(pair_tolerance_ns)
        self.imu_stamps: ImuStampPolicy = imu_stamps
        self._camchain_arg = camchain
        self.stats = ReaderStats()
        try:
            self.parts = resolve_bag_parts(self.path)
        except FileNotFoundError as exc:
            raise BagError(self.path, f"no such bag file ({exc})") from None
        self._source = bag_source(self.path)
        self.size_bytes = bag_size(self._source)
        self._check_container()
        self._topics = self._load_topics(required_topics)
        self._check_first_images()

    # ---- opening and checks ------------------------------------------------------------------------------------
    def _err(self, problem: str) -> BagError:
        return BagError(self.path, problem)

    def _check_container(self) -> None:
        if self.size_bytes == 0:
            raise self._err("file is empty (0 bytes)")
        try:
            index_pos, chunk_count = _read_bag_header(self._source)
        except (OSError, ValueError) as exc:
            raise self._err(str(exc)) from None
        if index_pos == 0:
            raise self._err("bag is not indexed (recording was interrupted?); run `rosbag reindex` on it")
        if chunk_count == 0 and index_pos <= self.size_bytes:
            raise self._err("bag is empty (no messages)")
        if index_pos >= self.size_bytes:
            hint = "incomplete download, or a split part missing?" if len(self.parts) > 1 else "incomplete download?"
            raise self._err(f"file is truncated: its index should start at byte {index_pos} but the bag holds only "
                            f"{self.size_bytes} bytes ({hint})")

    def _open_reader(self, topics: set[str] | None = None) -> Reader:
        """An open rosbags reader indexing only ``topics`` (normalised names; None = all)."""
        reader = _TopicReader(self._source, topics)
        try:
            reader.open()
        except (ReaderError, struct.error, AssertionError, ValueError, OSError, KeyError, IndexError) as exc:
            raise self._err(f"cannot read bag, truncated or corrupt ({type(exc).__name__}: {exc})") from None
        return reader

    def _load_topics(self, required: Iterable[str]) -> dict[str, TopicSummary]:
        reader = self._open_reader(set())  # metadata only: counts and times come from the chunk infos
        try:
            self.start_ns = int(reader.start_time)
            self.end_ns = int(reader.end_time)
            topics = {L.normalize_topic(name): TopicSummary(name, info.msgtype or "?", int(info.msgcount))
                      for name, info in reader.topics.items()}
        finally:
            reader.close()
        if sum(t.count for t in topics.values()) == 0:
            raise self._err("bag is empty (no messages)")
        missing = [t for t in required if L.normalize_topic(t) not in topics or
                   topics[L.normalize_topic(t)].count == 0]
        if missing:
            have = ", ".join(sorted(t.topic for t in topics.values())) or "none"
            raise self._err(f"missing required topic(s) {', '.join(missing)} (the bag has: {have})")
        for name, expected in L.TOPIC_TYPES.items():
            got = topics.get(L.normalize_topic(name))
            if got is not None and got.msgtype != expected:
                raise self._err(f"topic {got.topic} has type {got.msgtype}, expected {expected}")
        return topics

    def _check_first_images(self) -> None:
        """Check the first image of each side against camera_info (size) and the encoding."""
        left_info, right_info = self.camera_info
        for topic, info in ((L.TOPIC_LEFT_IMAGE, left_info), (L.TOPIC_RIGHT_IMAGE, right_info)):
            for _, msg in self._messages([topic], limit=1):
                self._image(msg, topic, (info.height, info.width))

    # ---- metadata ----------------------------------------------------------------------------------------------
    @property
    def topics(self) -> dict[str, TopicSummary]:
        """Topics keyed by normalised name (one leading slash, e.g. ``/tf_static``)."""
        return dict(self._topics)

    def has_topic(self, topic: str) -> bool:
        return L.normalize_topic(topic) in self._topics

    def count(self, topic: str) -> int:
        """Number of messages on ``topic`` (with or without leading slash); 0 if absent."""
        t = self._topics.get(L.normalize_topic(topic))
        return t.count if t else 0

    @property
    def duration_s(self) -> float:
        """Time between the first and last message, seconds."""
        return max(self.end_ns - self.start_ns, 0) / 1e9

    def identity(self) -> str:
        """A content key of the bag: name + BLAKE2 hash of its size, first MiB and last 64 KiB (index region).

        Stable under copying, renaming parts and touching the file; cheap (reads ~1 MiB). It changes whenever
        the header, the first chunk(s), the message index (stamps, chunk positions) or the size change — not a
        full content hash: an edit of pixels in the middle that keeps every size and stamp is not seen.
        """
        h = hashlib.blake2b(digest_size=10)
        h.update(str(self.size_bytes).encode())
        with self._source.open("rb") as fh:
            h.update(fh.read(1 << 20))
            fh.seek(max(self.size_bytes - (1 << 16), 0))
            h.update(fh.read(1 << 16))
        name = self.parts[0].name.split(".bag")[0] or "bag"
        return f"{name}-{h.hexdigest()}"

    @cached_property
    def camera_info(self) -> tuple[CameraInfo, CameraInfo]:
        """(left, right) contents of the first camera_info message of each camera."""
        infos = []
        for topic in (L.TOPIC_LEFT_INFO, L.TOPIC_RIGHT_INFO):
            msgs = list(self._messages([topic], limit=1))
            if not msgs:
                raise self._err(f"missing required topic {topic}")
            infos.append(_camera_info(msgs[0][1]))
        return infos[0], infos[1]

    @cached_property
    def camchain(self) -> Camchain:
        arg = self._camchain_arg
        if isinstance(arg, Camchain):
            return arg
        return read_camchain(arg if arg is not None else ROSARIO_CAMCHAIN)

    @cached_property
    def calibration(self) -> StereoRig:
        """Stereo rig: K, D, R, P and size from the bag's camera_info, extrinsics from the camchain."""
        left, right = self.camera_info
        try:
            return rig_from_camera_info(left, right, self.camchain, source=self.path)
        except CalibrationError as exc:
            raise self._err(exc.problem) from None

    # ---- raw message stream ------------------------------------------------------------------------------------
    def _messages(self, topics: Iterable[str], start_ns: int | None = None, stop_ns: int | None = None,
                  limit: int | None = None) -> Iterator[tuple[str, Any]]:
        """Yield ``(normalised topic, deserialised message)`` in bag-time order for the given topics."""
        wanted = {L.normalize_topic(t) for t in topics}
        ts = rosario_typestore()
        reader = self._open_reader(wanted)
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
                    raise self._err(f"cannot read message on {', '.join(sorted(wanted))} (truncated or corrupt "
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
        reader = self._open_reader(wanted)
        out: list[int] = []
        try:
            conns = [c for c in reader.connections if L.normalize_topic(c.topic) in wanted]
            if conns:
                for _, _, raw in reader.messages(connections=conns):
                    sec, nsec = struct.unpack_from("<II", raw, 4)
                    out.append(sec * 1_000_000_000 + nsec)
        except (ReaderError, struct.error, AssertionError, ValueError, OSError, EOFError, KeyError,
                IndexError) as exc:
            raise self._err(f"cannot read message on {topic} (truncated or corrupt data: "
                            f"{type(exc).__name__}: {exc})") from None
        finally:
            reader.close()
        return np.asarray(out, dtype=np.int64)

    def _image(self, msg: Any, topic: str, size_hw: tuple[int, int]) -> np.ndarray:
        h, w = int(msg.height), int(msg.width)
        if msg.encoding != L.IMAGE_ENCODING:
            raise self._err(f"{topic} seq {msg.header.seq} has encoding {msg.encoding!r}; expected "
                            f"{L.IMAGE_ENCODING!r}")
        if (h, w) != size_hw:
            raise self._err(f"{topic} image is {w}x{h} but camera_info says {size_hw[1]}x{size_hw[0]}")
        step = int(msg.step)
        data = np.asarray(msg.data, dtype=np.uint8)
        if step < w * 3 or data.size < h * step:
            raise self._err(f"{topic} seq {msg.header.seq}: image data holds {data.size} bytes, expected "
                            f"{h}x{step}")
        return data[:h * step].reshape(h, step)[:, :w * 3].reshape(h, w, 3).copy()

    # ---- streams -----------------------------------------------------------------------------------------------
    def stereo_frames(self, start_index: int = 0, stop_index: int | None = None,
                      right: bool = True) -> Iterator[StereoFrame]:
        """Stereo pairs in time order, matched by header stamp within ``pair_tolerance_ns``.

        A frame without a partner is skipped and counted in ``stats.unpaired_left/right``. Indices count pairs
        from the start of the bag; pairs before ``start_index`` are matched but not decoded. ``right=False``: the
        pairs are formed as always (same indices) but the right image is not decoded (``right_bgr`` None).
        """
        st = self.stats
        st.stereo_pairs = st.unpaired_left = st.unpaired_right = 0
        left_info, right_info = self.camera_info
        sizes = {L.TOPIC_LEFT_IMAGE: (left_info.height, left_info.width),
                 L.TOPIC_RIGHT_IMAGE: (right_info.height, right_info.width)}
        other = {L.TOPIC_LEFT_IMAGE: L.TOPIC_RIGHT_IMAGE, L.TOPIC_RIGHT_IMAGE: L.TOPIC_LEFT_IMAGE}
        pending: dict[str, tuple[int, Any]] = {}
        tol = self.pair_tolerance_ns

        def drop(topic: str) -> None:
            pending.pop(topic, None)
            if topic == L.TOPIC_LEFT_IMAGE:
                st.unpaired_left += 1
            else:
                st.unpaired_right += 1

        for topic, msg in self._messages([L.TOPIC_LEFT_IMAGE, L.TOPIC_RIGHT_IMAGE]):
            t = _stamp_ns(msg.header)
            mate = other[topic]
            if mate in pending and abs(pending[mate][0] - t) <= tol:
                t_mate, msg_mate = pending.pop(mate)
                index = st.stereo_pairs
                st.stereo_pairs += 1
                if index < start_index:
                    continue
                if stop_index is not None and index >= stop_index:
                    return
                left_msg, right_msg = (msg, msg_mate) if topic == L.TOPIC_LEFT_IMAGE else (msg_mate, msg)
                t_left = t if topic == L.TOPIC_LEFT_IMAGE else t_mate
                yield StereoFrame(t_left, self._image(left_msg, L.TOPIC_LEFT_IMAGE, sizes[L.TOPIC_LEFT_IMAGE]),
                                  self._image(right_msg, L.TOPIC_RIGHT_IMAGE, sizes[L.TOPIC_RIGHT_IMAGE])
                                  if right else None, index)
                continue
            if mate in pending and t - pending[mate][0] > tol:
                drop(mate)  # the other side's frame is too old to find a partner now
            if topic in pending:
                drop(topic)  # two frames of one side in a row: the older has no partner
            pending[topic] = (t, msg)
        for topic in list(pending):
            drop(topic)

    def _imu_raw(self, start_ns: int | None, stop_ns: int | None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        for _, m in self._messages([L.TOPIC_IMU], start_ns, stop_ns):
            av, la = m.angular_velocity, m.linear_acceleration
            yield (_stamp_ns(m.header), np.array([av.x, av.y, av.z], dtype=np.float64),
                   np.array([la.x, la.y, la.z], dtype=np.float64))

    def imu(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[ImuSample]:
        """IMU samples in time order (rad/s, m/s², gravity included, Rosario IMU axes).

        Covariances are ignored (Rosario writes ``[-1, 0, …]`` in all three arrays, which does not mean "no
        data"). Repeated stamps are handled per ``imu_stamps``; samples whose stamp goes backwards are dropped.
        Stamps stay integer ns; with ``"spread"`` they are strictly increasing except for a repeated run at the
        very end when no earlier period is known.
        """
        st = self.stats
        st.imu_samples = st.imu_repeated_stamps = st.imu_out_of_order = 0
        run: list[tuple[int, np.ndarray, np.ndarray]] = []
        last_period = 0.0

        def flush(next_t: int | None) -> Iterator[ImuSample]:
            k = len(run)
            t0 = run[0][0]
            if k == 1 or self.imu_stamps == "keep":
                stamps = [t0] * k
            elif self.imu_stamps == "drop":
                stamps, run[:] = [t0], run[:1]
            else:
                step = (next_t - t0) / k if next_t is not None else last_period
                stamps = [t0 + int(round(i * step)) for i in range(k)]
            for s, (_, g, a) in zip(stamps, run):
                st.imu_samples += 1
                yield ImuSample(s, g, a)

        for sample in self._imu_raw(start_ns, stop_ns):
            t = sample[0]
            if run:
                if t == run[0][0]:
                    st.imu_repeated_stamps += 1
                    run.append(sample)
                    continue
                if t < run[0][0]:
                    st.imu_out_of_order += 1
                    continue
                yield from flush(t)
                last_period = (t - run[0][0]) / len(run)
            run = [sample]
        if run:
            yield from flush(None)

    def imu_samples(self, start_ns: int | None = None, stop_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """All IMU samples: ``(stamps_ns, data)``, (N,) int64 ns and (N, 6) float64 ``[gx, gy, gz, ax, ay, az]``
        (rad/s, m/s², IMU frame), after the repeated-stamp policy. Stamps stay integer ns, so callers can order
        IMU samples against image stamps exactly (a double holds a 2017 epoch stamp only to ≈ 238 ns)."""
        n_max = self.count(L.TOPIC_IMU)
        stamps = np.empty(n_max, dtype=np.int64)
        data = np.empty((n_max, 6), dtype=np.float64)
        n = 0
        for s in self.imu(start_ns, stop_ns):
            stamps[n] = s.stamp_ns
            data[n, 0:3] = s.gyro
            data[n, 3:6] = s.accel
            n += 1
        return stamps[:n].copy(), data[:n].copy()

    def imu_array(self, start_ns: int | None = None, stop_ns: int | None = None) -> np.ndarray:
        """All IMU samples as an (N, 7) float64 array ``[t_s, gx, gy, gz, ax, ay, az]`` (s, rad/s, m/s²); the
        seconds are ``stamp_ns / 1e9``, the conversion every image stamp goes through too."""
        stamps, data = self.imu_samples(start_ns, stop_ns)
        return np.column_stack([stamps / 1e9, data]) if len(stamps) else np.empty((0, 7), dtype=np.float64)

    def imu_stamps_ns(self) -> np.ndarray:
        """(N,) int64 IMU stamps in ns after the repeated-stamp policy (exact, unlike ``imu_array``'s seconds)."""
        return self.imu_samples()[0]

    def gps_fixes(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[GpsFix]:
        """``/gps/fix`` messages in time order."""
        for _, m in self._messages([L.TOPIC_GPS_FIX], start_ns, stop_ns):
            yield GpsFix(_stamp_ns(m.header), float(m.latitude), float(m.longitude), float(m.altitude),
                         int(m.status.status), np.asarray(m.position_covariance, dtype=np.float64).reshape(3, 3))

    def gps_fix_array(self) -> np.ndarray:
        """(N, 5) float64 ``[t_s, lat_deg, lon_deg, alt_m, status]``."""
        rows = [(f.stamp_ns / 1e9, f.lat_deg, f.lon_deg, f.alt_m, f.status) for f in self.gps_fixes()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 5)

    def gps_velocities(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[GpsVelocity]:
        """``/gps/vel`` messages in time order."""
        for _, m in self._messages([L.TOPIC_GPS_VEL], start_ns, stop_ns):
            yield GpsVelocity(_stamp_ns(m.header), float(m.twist.linear.x), float(m.twist.linear.y))

    def gps_velocity_array(self) -> np.ndarray:
        """(N, 3) float64 ``[t_s, v_east, v_north]`` (s, m/s)."""
        rows = [(v.stamp_ns / 1e9, v.v_east, v.v_north) for v in self.gps_velocities()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 3)

    def odometry(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[OdomSample]:
        """``/odom`` messages in time order (planar wheel odometry)."""
        for _, m in self._messages([L.TOPIC_ODOM], start_ns, stop_ns):
            p, q = m.pose.pose.position, m.pose.pose.orientation
            yaw = float(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("ZYX")[0]) if (q.x or q.y or q.z or q.w) \
                else 0.0
            yield OdomSample(_stamp_ns(m.header), float(p.x), float(p.y), yaw, float(m.twist.twist.linear.x),
                             float(m.twist.twist.angular.z))

    def odom_array(self) -> np.ndarray:
        """(N, 6) float64 ``[t_s, x, y, yaw, v, yaw_rate]`` (s, m, m, rad, m/s, rad/s)."""
        rows = [(o.stamp_ns / 1e9, o.x, o.y, o.yaw, o.v, o.yaw_rate) for o in self.odometry()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 6)

    def tf_static(self) -> Iterator[StaticTransform]:
        """Every transform of every ``tf_static`` (or ``/tf_static``) message, in time order (bag time)."""
        for _, m in self._messages([L.TOPIC_TF_STATIC]):
            for tr in m.transforms:
                t, r = tr.transform.translation, tr.transform.rotation
                T = np.eye(4)
                T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
                T[:3, 3] = (t.x, t.y, t.z)
                yield StaticTransform(_stamp_ns(tr.header), str(tr.header.frame_id), str(tr.child_frame_id), T)

    def static_transforms(self) -> dict[tuple[str, str], np.ndarray]:
        """``{(parent, child): T_parent_child}`` from the first ``tf_static`` message(s) (they repeat ~10 Hz)."""
        out: dict[tuple[str, str], np.ndarray] = {}
        for tr in self.tf_static():
            key = (tr.parent, tr.child)
            if key in out:
                break
            out[key] = tr.T_parent_child
        return out

    # ---- ground truth ------------------------------------------------------------------------------------------
    @staticmethod
    def ground_truth(path: Path | str) -> Trajectory:
        """Read a TUM ground-truth file (``t x y z qx qy qz qw``, LF or CRLF; Rosario v1: GPS antenna positions,
        identity quaternions) with ``eval.trajectory.read_tum``.

        Raises:
            EvalInputError: naming the file and the line of a malformed entry.
        """
        return read_tum(Path(path))

    # ---- misc --------------------------------------------------------------------------------------------------
    def __repr__(self) -> str:
        return f"RosarioSequence({str(self.path)!r}, {len(self.parts)} part(s), {self.size_bytes} bytes)"

    def __enter__(self) -> RosarioSequence:
        return self

    def __exit__(self, *exc: object) -> bool:
        return False


#: Alias named in design.md.
Sequence = RosarioSequence
