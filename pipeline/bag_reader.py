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

from collections.abc import Iterable, Iterator
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from eval.trajectory import Trajectory, read_tum
from msckf.camera import StereoRig
from pipeline import bag_streams as S
from pipeline import rosario_layout as L
from pipeline.bag_calibration import SequenceCalibration
from pipeline.bag_calibration import camera_info_from_msg as _camera_info
from pipeline.bag_container import BagContainer, BagIndex, TopicSummary, _read_bag_header, _TopicReader
from pipeline.bag_messages import (
    GpsFix,
    GpsVelocity,
    ImuSample,
    ImuStampPolicy,
    OdomSample,
    ReaderStats,
    StaticTransform,
    StereoFrame,
)
from pipeline.bag_messages import stamp_ns as _stamp_ns
from pipeline.calibration import Camchain, CameraInfo

__all__ = ["GpsFix", "GpsVelocity", "ImuSample", "ImuStampPolicy", "OdomSample", "ReaderStats", "RosarioSequence",
           "Sequence", "StaticTransform", "StereoFrame", "TopicSummary", "_TopicReader", "_camera_info",
           "_read_bag_header", "_stamp_ns"]


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
        self.stats = ReaderStats()
        self._bag = BagContainer(self.path)
        self.parts = self._bag.parts
        self.size_bytes = self._bag.size_bytes
        self._index = BagIndex.load(self._bag, required_topics)
        self.start_ns, self.end_ns = self._index.start_ns, self._index.end_ns
        self._calib = SequenceCalibration(self._bag, camchain)
        S.check_first_images(self._bag, self._calib.image_sizes_hw())

    # ---- container and index (pipeline.bag_container) ----------------------------------------------------------
    @property
    def topics(self) -> dict[str, TopicSummary]:
        """Topics keyed by normalised name (one leading slash, e.g. ``/tf_static``)."""
        return dict(self._index.topics)

    def has_topic(self, topic: str) -> bool:
        return self._index.has_topic(topic)

    def count(self, topic: str) -> int:
        """Number of messages on ``topic`` (with or without leading slash); 0 if absent."""
        return self._index.count(topic)

    @property
    def duration_s(self) -> float:
        """Time between the first and last message, seconds."""
        return self._index.duration_s

    def identity(self) -> str:
        """A content key of the bag: name + BLAKE2 hash of its size, first MiB and last 64 KiB (index region).

        Stable under copying, renaming parts and touching the file; cheap (reads ~1 MiB). It changes whenever
        the header, the first chunk(s), the message index (stamps, chunk positions) or the size change — not a
        full content hash: an edit of pixels in the middle that keeps every size and stamp is not seen.
        """
        return self._bag.identity()

    def _messages(self, topics: Iterable[str], start_ns: int | None = None, stop_ns: int | None = None,
                  limit: int | None = None) -> Iterator[tuple[str, Any]]:
        """Yield ``(normalised topic, deserialised message)`` in bag-time order for the given topics."""
        return self._bag.messages(topics, start_ns, stop_ns, limit)

    def header_stamps_ns(self, topic: str) -> np.ndarray:
        """(N,) int64 header stamps (ns) of every message on ``topic``, in bag order, without deserialising them.

        Every Rosario message with a header starts with it (ROS1: ``uint32 seq, uint32 sec, uint32 nsec``), so the
        stamp is read from bytes 4..12 of the raw message; images are not decoded (cheap next to the depth stage).
        """
        return self._bag.header_stamps_ns(topic)

    # ---- calibration (pipeline.bag_calibration) ----------------------------------------------------------------
    @cached_property
    def camera_info(self) -> tuple[CameraInfo, CameraInfo]:
        """(left, right) contents of the first camera_info message of each camera."""
        return self._calib.camera_info

    @cached_property
    def camchain(self) -> Camchain:
        return self._calib.camchain

    @cached_property
    def calibration(self) -> StereoRig:
        """Stereo rig: K, D, R, P and size from the bag's camera_info, extrinsics from the camchain."""
        return self._calib.rig

    # ---- streams (pipeline.bag_streams) ------------------------------------------------------------------------
    def stereo_frames(self, start_index: int = 0, stop_index: int | None = None,
                      right: bool = True, left: bool = True) -> Iterator[StereoFrame]:
        """Stereo pairs in time order, matched by header stamp within ``pair_tolerance_ns``.

        A frame without a partner is skipped and counted in ``stats.unpaired_left/right``. Indices count pairs
        from the start of the bag; pairs before ``start_index`` are matched but not decoded. ``right=False``: the
        pairs are formed as always (same indices) but the right image is not decoded (``right_bgr`` None);
        ``left=False`` likewise for the left image.
        """
        yield from S.stereo_frames(self._bag, self._calib.image_sizes_hw(), self.pair_tolerance_ns, self.stats,
                                   start_index, stop_index, right, left)

    def _imu_raw(self, start_ns: int | None, stop_ns: int | None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        return S.imu_raw(self._bag, start_ns, stop_ns)

    def imu(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[ImuSample]:
        """IMU samples in time order (rad/s, m/s², gravity included, Rosario IMU axes).

        Covariances are ignored (Rosario writes ``[-1, 0, …]`` in all three arrays, which does not mean "no
        data"). Repeated stamps are handled per ``imu_stamps``; samples whose stamp goes backwards are dropped.
        Stamps stay integer ns; with ``"spread"`` they are strictly increasing except for a repeated run at the
        very end when no earlier period is known.
        """
        yield from S.apply_imu_stamp_policy(self._imu_raw(start_ns, stop_ns), self.imu_stamps, self.stats)

    def imu_samples(self, start_ns: int | None = None, stop_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """All IMU samples: ``(stamps_ns, data)``, (N,) int64 ns and (N, 6) float64 ``[gx, gy, gz, ax, ay, az]``
        (rad/s, m/s², IMU frame), after the repeated-stamp policy. Stamps stay integer ns, so callers can order
        IMU samples against image stamps exactly (a double holds a 2017 epoch stamp only to ≈ 238 ns)."""
        return S.imu_sample_arrays(self.imu(start_ns, stop_ns), self.count(L.TOPIC_IMU))

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
        return S.gps_fixes(self._bag, start_ns, stop_ns)

    def gps_fix_array(self) -> np.ndarray:
        """(N, 5) float64 ``[t_s, lat_deg, lon_deg, alt_m, status]``."""
        rows = [(f.stamp_ns / 1e9, f.lat_deg, f.lon_deg, f.alt_m, f.status) for f in self.gps_fixes()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 5)

    def gps_velocities(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[GpsVelocity]:
        """``/gps/vel`` messages in time order."""
        return S.gps_velocities(self._bag, start_ns, stop_ns)

    def gps_velocity_array(self) -> np.ndarray:
        """(N, 3) float64 ``[t_s, v_east, v_north]`` (s, m/s)."""
        rows = [(v.stamp_ns / 1e9, v.v_east, v.v_north) for v in self.gps_velocities()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 3)

    def odometry(self, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[OdomSample]:
        """``/odom`` messages in time order (planar wheel odometry)."""
        return S.odometry(self._bag, start_ns, stop_ns)

    def odom_array(self) -> np.ndarray:
        """(N, 6) float64 ``[t_s, x, y, yaw, v, yaw_rate]`` (s, m, m, rad, m/s, rad/s)."""
        rows = [(o.stamp_ns / 1e9, o.x, o.y, o.yaw, o.v, o.yaw_rate) for o in self.odometry()]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 6)

    def tf_static(self) -> Iterator[StaticTransform]:
        """Every transform of every ``tf_static`` (or ``/tf_static``) message, in time order (bag time)."""
        return S.tf_static(self._bag)

    def static_transforms(self) -> dict[tuple[str, str], np.ndarray]:
        """``{(parent, child): T_parent_child}`` from the first ``tf_static`` message(s) (they repeat ~10 Hz)."""
        return S.first_static_transforms(self.tf_static())

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
