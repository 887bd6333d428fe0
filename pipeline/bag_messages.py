"""Message types of a Rosario v1 bag as :class:`pipeline.bag_reader.RosarioSequence` yields them.

Stamps are ``header.stamp`` in integer nanoseconds. Units: rad/s, m/s², metres, degrees for latitude/longitude.
Frames: IMU samples are in the Rosario IMU frame (x up, y right, z forward); images are raw BGR.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

#: How repeated IMU stamps are handled (see :class:`pipeline.bag_reader.RosarioSequence`).
ImuStampPolicy = Literal["spread", "keep", "drop"]


def stamp_ns(header: Any) -> int:
    """A ROS ``std_msgs/Header``'s stamp in integer ns."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


@dataclass(frozen=True)
class StereoFrame:
    """A stereo pair matched by stamp.

    Attributes:
        stamp_ns: left image header stamp, ns.
        left_bgr, right_bgr: (H, W, 3) uint8 raw BGR images (writable copies); ``right_bgr`` is None when the
            caller asked for the left images only (``stereo_frames(right=False)``), ``left_bgr`` None when it asked
            for no left image (``left=False``).
        index: 0-based pair number from the start of the bag (stable across calls; used as the depth-cache key).
    """

    stamp_ns: int
    left_bgr: np.ndarray | None
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
