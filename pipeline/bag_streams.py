"""Sensor streams of a Rosario bag: stereo pairs, IMU (with the repeated-stamp policy), GPS, odometry, tf_static.

Each stream reads its own topics through :meth:`BagContainer.messages` (one rosbags reader per pass, one chunk
decompressed at a time), so streams can be iterated independently and interleaved. Stamps are ``header.stamp``
in integer ns; units rad/s, m/s², m, degrees (latitude/longitude); IMU samples in the Rosario IMU frame (x up,
y right, z forward); images raw (distorted, unrectified) BGR.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline import rosario_layout as L
from pipeline.bag_container import BagContainer
from pipeline.bag_messages import (
    GpsFix,
    GpsVelocity,
    ImuSample,
    ImuStampPolicy,
    OdomSample,
    ReaderStats,
    StaticTransform,
    StereoFrame,
    stamp_ns,
)

#: One IMU message as read: ``(stamp_ns, gyro (3,) rad/s, accel (3,) m/s²)``.
RawImu = tuple[int, np.ndarray, np.ndarray]


# ---- images ----------------------------------------------------------------------------------------------------
def decode_image(bag: BagContainer, msg: Any, topic: str, size_hw: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 writable BGR copy of a ``sensor_msgs/Image`` on ``topic``, checked against the encoding
    (``bgr8``) and ``size_hw`` (height, width) from camera_info; raises ``BagError`` otherwise."""
    h, w = int(msg.height), int(msg.width)
    if msg.encoding != L.IMAGE_ENCODING:
        raise bag.err(f"{topic} seq {msg.header.seq} has encoding {msg.encoding!r}; expected {L.IMAGE_ENCODING!r}")
    if (h, w) != size_hw:
        raise bag.err(f"{topic} image is {w}x{h} but camera_info says {size_hw[1]}x{size_hw[0]}")
    step = int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * 3 or data.size < h * step:
        raise bag.err(f"{topic} seq {msg.header.seq}: image data holds {data.size} bytes, expected {h}x{step}")
    return data[:h * step].reshape(h, step)[:, :w * 3].reshape(h, w, 3).copy()


def check_first_images(bag: BagContainer, sizes_hw: dict[str, tuple[int, int]]) -> None:
    """Decode the first image of each camera topic of ``sizes_hw`` ({topic: (height, width)}) as a check."""
    for topic in (L.TOPIC_LEFT_IMAGE, L.TOPIC_RIGHT_IMAGE):
        for _, msg in bag.messages([topic], limit=1):
            decode_image(bag, msg, topic, sizes_hw[topic])


def stereo_frames(bag: BagContainer, sizes_hw: dict[str, tuple[int, int]], pair_tolerance_ns: int,
                  stats: ReaderStats, start_index: int = 0, stop_index: int | None = None,
                  right: bool = True, left: bool = True) -> Iterator[StereoFrame]:
    """Stereo pairs in time order, matched by header stamp within ``pair_tolerance_ns`` (ns).

    A frame without a partner is skipped and counted in ``stats.unpaired_left/right``. Indices count pairs from
    the start of the bag; pairs before ``start_index`` are matched but not decoded. ``right=False``: the pairs
    are formed as always (same indices) but the right image is not decoded (``right_bgr`` None); ``left=False``
    likewise for the left image (``left_bgr`` None: a consumer that needs only the stamps and indices).
    """
    st = stats
    st.stereo_pairs = st.unpaired_left = st.unpaired_right = 0
    other = {L.TOPIC_LEFT_IMAGE: L.TOPIC_RIGHT_IMAGE, L.TOPIC_RIGHT_IMAGE: L.TOPIC_LEFT_IMAGE}
    pending: dict[str, tuple[int, Any]] = {}
    tol = pair_tolerance_ns

    def drop(topic: str) -> None:
        pending.pop(topic, None)
        if topic == L.TOPIC_LEFT_IMAGE:
            st.unpaired_left += 1
        else:
            st.unpaired_right += 1

    for topic, msg in bag.messages([L.TOPIC_LEFT_IMAGE, L.TOPIC_RIGHT_IMAGE]):
        t = stamp_ns(msg.header)
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
            yield StereoFrame(t_left, decode_image(bag, left_msg, L.TOPIC_LEFT_IMAGE, sizes_hw[L.TOPIC_LEFT_IMAGE])
                              if left else None,
                              decode_image(bag, right_msg, L.TOPIC_RIGHT_IMAGE, sizes_hw[L.TOPIC_RIGHT_IMAGE])
                              if right else None, index)
            continue
        if mate in pending and t - pending[mate][0] > tol:
            drop(mate)  # the other side's frame is too old to find a partner now
        if topic in pending:
            drop(topic)  # two frames of one side in a row: the older has no partner
        pending[topic] = (t, msg)
    for topic in list(pending):
        drop(topic)


# ---- IMU -------------------------------------------------------------------------------------------------------
def imu_raw(bag: BagContainer, start_ns: int | None, stop_ns: int | None) -> Iterator[RawImu]:
    """``/imu`` messages as recorded (stamps not fixed up), bag time in ``[start_ns, stop_ns)`` ns."""
    for _, m in bag.messages([L.TOPIC_IMU], start_ns, stop_ns):
        av, la = m.angular_velocity, m.linear_acceleration
        yield (stamp_ns(m.header), np.array([av.x, av.y, av.z], dtype=np.float64),
               np.array([la.x, la.y, la.z], dtype=np.float64))


def apply_imu_stamp_policy(raw: Iterable[RawImu], policy: ImuStampPolicy, stats: ReaderStats) -> Iterator[ImuSample]:
    """IMU samples of ``raw`` with repeated stamps handled per ``policy`` and backwards stamps dropped.

    ``"keep"``: as recorded; ``"drop"``: the first of each run of equal stamps; ``"spread"``: a run of k samples
    sharing a stamp is spread evenly (integer ns) up to the next distinct stamp, or by the last known period for
    a run at the very end. Counts go to ``stats.imu_samples / imu_repeated_stamps / imu_out_of_order`` (reset).
    """
    st = stats
    st.imu_samples = st.imu_repeated_stamps = st.imu_out_of_order = 0
    run: list[RawImu] = []
    last_period = 0.0

    def flush(next_t: int | None) -> Iterator[ImuSample]:
        k = len(run)
        t0 = run[0][0]
        if k == 1 or policy == "keep":
            stamps = [t0] * k
        elif policy == "drop":
            stamps, run[:] = [t0], run[:1]
        else:
            step = (next_t - t0) / k if next_t is not None else last_period
            stamps = [t0 + int(round(i * step)) for i in range(k)]
        for s, (_, g, a) in zip(stamps, run):
            st.imu_samples += 1
            yield ImuSample(s, g, a)

    for sample in raw:
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


def imu_sample_arrays(samples: Iterable[ImuSample], n_max: int) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_ns, data)``: (N,) int64 ns and (N, 6) float64 ``[gx, gy, gz, ax, ay, az]`` (rad/s, m/s²) of at
    most ``n_max`` samples."""
    stamps = np.empty(n_max, dtype=np.int64)
    data = np.empty((n_max, 6), dtype=np.float64)
    n = 0
    for s in samples:
        stamps[n] = s.stamp_ns
        data[n, 0:3] = s.gyro
        data[n, 3:6] = s.accel
        n += 1
    return stamps[:n].copy(), data[:n].copy()


# ---- GPS, odometry, tf_static ----------------------------------------------------------------------------------
def gps_fixes(bag: BagContainer, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[GpsFix]:
    """``/gps/fix`` messages in time order."""
    for _, m in bag.messages([L.TOPIC_GPS_FIX], start_ns, stop_ns):
        yield GpsFix(stamp_ns(m.header), float(m.latitude), float(m.longitude), float(m.altitude),
                     int(m.status.status), np.asarray(m.position_covariance, dtype=np.float64).reshape(3, 3))


def gps_velocities(bag: BagContainer, start_ns: int | None = None,
                   stop_ns: int | None = None) -> Iterator[GpsVelocity]:
    """``/gps/vel`` messages in time order (east, north, m/s)."""
    for _, m in bag.messages([L.TOPIC_GPS_VEL], start_ns, stop_ns):
        yield GpsVelocity(stamp_ns(m.header), float(m.twist.linear.x), float(m.twist.linear.y))


def odometry(bag: BagContainer, start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[OdomSample]:
    """``/odom`` messages in time order (planar wheel odometry: m, rad, m/s, rad/s)."""
    for _, m in bag.messages([L.TOPIC_ODOM], start_ns, stop_ns):
        p, q = m.pose.pose.position, m.pose.pose.orientation
        yaw = float(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("ZYX")[0]) if (q.x or q.y or q.z or q.w) \
            else 0.0
        yield OdomSample(stamp_ns(m.header), float(p.x), float(p.y), yaw, float(m.twist.twist.linear.x),
                         float(m.twist.twist.angular.z))


def tf_static(bag: BagContainer) -> Iterator[StaticTransform]:
    """Every transform of every ``tf_static`` (or ``/tf_static``) message, in time order (bag time)."""
    for _, m in bag.messages([L.TOPIC_TF_STATIC]):
        for tr in m.transforms:
            t, r = tr.transform.translation, tr.transform.rotation
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            T[:3, 3] = (t.x, t.y, t.z)
            yield StaticTransform(stamp_ns(tr.header), str(tr.header.frame_id), str(tr.child_frame_id), T)


def first_static_transforms(transforms: Iterable[StaticTransform]) -> dict[tuple[str, str], np.ndarray]:
    """``{(parent, child): T_parent_child}`` up to the first repeated (parent, child) pair."""
    out: dict[tuple[str, str], np.ndarray] = {}
    for tr in transforms:
        key = (tr.parent, tr.child)
        if key in out:
            break
        out[key] = tr.T_parent_child
    return out
