"""The simulator's stream seams: the timetable's stamps and the stamp-order interleaving of the slow streams."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.sim.imu import ImuChunk
from pipeline.sim.presets import get_preset
from pipeline.sim.sensors import GpsSamples, OdomSamples
from pipeline.sim.streams import SlowStreams
from pipeline.sim.timetable import CAM_PHASE_S, GPS_PHASE_S, StreamTimetable


class _FakeImu:
    """Stands in for the IMU simulator: sample k has gyro (k, 0, 0) and accel (0, 0, k)."""

    def __init__(self) -> None:
        self.k = 0
        self.calls: list[int] = []

    def next(self, count: int) -> ImuChunk:
        self.calls.append(count)
        k = np.arange(self.k, self.k + count, dtype=np.float64)
        self.k += count
        z = np.zeros(count)
        return ImuChunk(t=k / 100.0, gyro=np.column_stack([k, z, z]), accel=np.column_stack([z, z, k]),
                        bias_gyro=np.zeros((count, 3)), bias_accel=np.zeros((count, 3)))


class _Recorder:
    """A bag writer that records ``(kind, stamp_ns)`` of every message."""

    def __init__(self) -> None:
        self.log: list[tuple[str, int]] = []

    def write_imu(self, stamp_ns, gyro_rad_s, accel_m_s2) -> None:
        assert gyro_rad_s[0] == accel_m_s2[2]
        self.log.append(("imu", stamp_ns))

    def write_gps_fix(self, stamp_ns, lat_deg, lon_deg, alt_m, status=2, hdop=0.8) -> None:
        assert status == 2 and hdop == 0.7
        self.log.append(("fix", stamp_ns))

    def write_gps_vel(self, stamp_ns, v_east, v_north) -> None:
        self.log.append(("vel", stamp_ns))

    def write_odom(self, stamp_ns, x, y, yaw, v, yaw_rate) -> None:
        self.log.append(("odom", stamp_ns))

    def write_tf_static(self, stamp_ns, transforms) -> None:
        assert transforms == ()
        self.log.append(("tf", stamp_ns))


class _Sink:
    def __init__(self) -> None:
        self.stamps: list[int] = []

    def add_imu(self, stamps_ns, gyro, accel) -> None:
        self.stamps.extend(int(s) for s in stamps_ns)


def _streams(sink: _Sink | None = None) -> tuple[SlowStreams, _FakeImu]:
    imu = _FakeImu()
    imu_ns = np.arange(0, 100, 10, dtype=np.int64)  # 0, 10, …, 90
    gps_ns = np.array([10, 35, 95], dtype=np.int64)  # 10 ties an IMU stamp; 95 is after the last IMU sample
    odom_ns = np.array([10, 50], dtype=np.int64)
    n = len(gps_ns)
    gps = GpsSamples(t=gps_ns / 1e9, true_enu=np.zeros((n, 3)), meas_enu=np.zeros((n, 3)), lat=np.zeros(n),
                     lon=np.zeros(n), alt=np.zeros(n), vel_en=np.zeros((n, 2)))
    m = len(odom_ns)
    odom = OdomSamples(t=odom_ns / 1e9, x=np.zeros(m), y=np.zeros(m), yaw=np.zeros(m), v=np.zeros(m),
                       yaw_rate=np.zeros(m))
    return SlowStreams(imu, imu_ns, gps, gps_ns, odom, odom_ns, (), 0.7, imu_sink=sink), imu


def test_slow_streams_write_in_stamp_order_gps_then_odom_then_imu_on_ties():
    sink = _Sink()
    streams, imu = _streams(sink)
    w = _Recorder()
    streams.flush_until(w, 12)  # a frame at 12 ns
    assert w.log == [("imu", 0), ("fix", 10), ("vel", 10), ("odom", 10), ("tf", 10), ("imu", 10)]
    streams.flush_until(w, 12)  # nothing new
    assert len(w.log) == 6 and imu.calls == [2]
    streams.flush_until(w, 95)  # the final flush: the rest, the GPS fix after the last IMU sample included
    kinds = [k for k, _ in w.log]
    stamps = [s for _, s in w.log]
    assert stamps == sorted(stamps)
    assert kinds.count("imu") == 10 and kinds.count("fix") == 3 and kinds.count("odom") == 2
    assert w.log[-2:] == [("fix", 95), ("vel", 95)]
    assert imu.calls == [2, 8]
    assert sink.stamps == list(range(0, 100, 10))
    rows = streams.imu_rows()
    assert rows.shape == (10, 13)
    np.testing.assert_array_equal(rows[:, 1], np.arange(10))  # gyro x of sample k is k, in order


def test_slow_streams_without_imu_samples_give_empty_rows():
    streams, _ = _streams()
    assert streams.imu_rows().shape == (0, 13)


def test_timetable_stamps_and_phases():
    cfg = dataclasses.replace(get_preset("tiny"), duration_s=1.0)
    tt = StreamTimetable.from_config(cfg, max_frames=4)
    t0 = int(cfg.start_stamp_ns)
    assert len(tt.t_imu) == int(np.floor(cfg.imu.rate_hz)) + 1 and tt.imu_ns[0] == t0
    assert len(tt.t_cam) == 4 and tt.t_cam[0] == CAM_PHASE_S
    assert tt.cam_ns[0] == t0 + round((CAM_PHASE_S + cfg.camera.time_offset_s) * 1e9)
    assert tt.gps_ns[0] == t0 + round(GPS_PHASE_S * 1e9)
    for t, ns in ((tt.t_imu, tt.imu_ns), (tt.t_gps, tt.gps_ns), (tt.t_odom, tt.odom_ns)):
        assert ns.dtype == np.int64 and np.all(np.diff(ns) > 0) and t[-1] <= cfg.duration_s
        np.testing.assert_array_equal(ns, t0 + np.round(t * 1e9).astype(np.int64))
    assert tt.last_stamp_ns == max(tt.imu_ns[-1], tt.gps_ns[-1], tt.odom_ns[-1])
