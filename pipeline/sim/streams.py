"""Interleave the IMU, GPS, odometry and tf_static streams into a bag writer in stamp order.

The frames drive the clock: before each frame is written, :meth:`SlowStreams.flush_until` writes every IMU,
GPS (fix + vel) and odometry (+ tf_static) sample stamped at or before the frame's stamp. Equal stamps go
GPS first, then odometry, then the IMU sample, then the frame.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from pipeline.sim.imu import ImuChunk
from pipeline.sim.sensors import GpsSamples, OdomSamples
from pipeline.sim.sequence_world import StaticTransforms

#: Columns of the recorded IMU rows: ``[t_s, gyro (3) rad/s, accel (3) m/s², bias_gyro (3), bias_accel (3)]``.
IMU_ROW_COLUMNS = 13


class StreamWriter(Protocol):
    """The part of :class:`pipeline.bag_writer.RosarioBagWriter` the slow streams write to (stamps in ns)."""

    def write_imu(self, stamp_ns: int, gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray) -> None: ...

    def write_gps_fix(self, stamp_ns: int, lat_deg: float, lon_deg: float, alt_m: float, status: int = 2,
                      hdop: float = 0.8) -> None: ...

    def write_gps_vel(self, stamp_ns: int, v_east: float, v_north: float) -> None: ...

    def write_odom(self, stamp_ns: int, x: float, y: float, yaw: float, v: float, yaw_rate: float) -> None: ...

    def write_tf_static(self, stamp_ns: int, transforms: StaticTransforms) -> None: ...


class ImuSource(Protocol):
    """Streams IMU samples in contiguous chunks (:class:`pipeline.sim.imu.ImuSimulator`)."""

    def next(self, count: int) -> ImuChunk: ...


class ImuSink(Protocol):
    """Also receives the IMU samples (the EuRoC export): stamps (N,) int64 ns, gyro/accel (N, 3)."""

    def add_imu(self, stamps_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None: ...


class SlowStreams:
    """The IMU, GPS and odometry streams of a sequence, written into a bag writer up to a stamp at a time.

    Args:
        imu: the IMU source; its samples are stamped ``imu_ns`` ((N,) int64 ns, increasing).
        imu_ns, gps_ns, odom_ns: (N,) int64 stamps of the IMU, GPS and odometry samples, ns.
        gps: GPS samples at ``gps_ns``; written as ``/gps/fix`` (status 2, ``hdop``) and ``/gps/vel``.
        odom: odometry samples at ``odom_ns``; each is followed by a ``tf_static`` message of ``statics``.
        statics: the ``tf_static`` transforms.
        hdop: horizontal dilution of precision stamped into every fix.
        imu_sink: also receives every IMU chunk (EuRoC export), or None.
    """

    def __init__(self, imu: ImuSource, imu_ns: np.ndarray, gps: GpsSamples, gps_ns: np.ndarray,
                 odom: OdomSamples, odom_ns: np.ndarray, statics: StaticTransforms, hdop: float,
                 imu_sink: ImuSink | None = None) -> None:
        self.imu, self.imu_ns, self.imu_sink = imu, imu_ns, imu_sink
        self.gps, self.gps_ns, self.hdop = gps, gps_ns, hdop
        self.odom, self.odom_ns, self.statics = odom, odom_ns, statics
        self.i_imu = self.i_gps = self.i_odom = 0
        self._imu_rows: list[np.ndarray] = []

    def flush_until(self, w: StreamWriter, stamp_ns: int) -> None:
        """Write every not yet written sample stamped ≤ ``stamp_ns`` (ns) into ``w``, in stamp order."""
        n_new = int(np.searchsorted(self.imu_ns, stamp_ns, side="right")) - self.i_imu
        if n_new > 0:
            chunk = self.imu.next(n_new)
            self._imu_rows.append(np.column_stack([chunk.t, chunk.gyro, chunk.accel, chunk.bias_gyro,
                                                   chunk.bias_accel]))
            if self.imu_sink is not None:
                self.imu_sink.add_imu(self.imu_ns[self.i_imu:self.i_imu + n_new], chunk.gyro, chunk.accel)
            for j in range(n_new):  # interleave with GPS and odometry in stamp order
                s = int(self.imu_ns[self.i_imu + j])
                self._flush_gps_odom(w, s)
                w.write_imu(s, chunk.gyro[j], chunk.accel[j])
            self.i_imu += n_new
        self._flush_gps_odom(w, stamp_ns)

    def _flush_gps_odom(self, w: StreamWriter, stamp_ns: int) -> None:
        """Write the GPS and odometry samples stamped ≤ ``stamp_ns`` (ns), GPS first."""
        gps, odom = self.gps, self.odom
        while self.i_gps < len(self.gps_ns) and self.gps_ns[self.i_gps] <= stamp_ns:
            i, s = self.i_gps, int(self.gps_ns[self.i_gps])
            w.write_gps_fix(s, float(gps.lat[i]), float(gps.lon[i]), float(gps.alt[i]), status=2, hdop=self.hdop)
            w.write_gps_vel(s, float(gps.vel_en[i, 0]), float(gps.vel_en[i, 1]))
            self.i_gps += 1
        while self.i_odom < len(self.odom_ns) and self.odom_ns[self.i_odom] <= stamp_ns:
            i, s = self.i_odom, int(self.odom_ns[self.i_odom])
            w.write_odom(s, float(odom.x[i]), float(odom.y[i]), float(odom.yaw[i]), float(odom.v[i]),
                         float(odom.yaw_rate[i]))
            w.write_tf_static(s, self.statics)
            self.i_odom += 1

    def imu_rows(self) -> np.ndarray:
        """(N, 13) float64 rows of the IMU samples written so far (see :data:`IMU_ROW_COLUMNS`)."""
        return np.concatenate(self._imu_rows) if self._imu_rows else np.zeros((0, IMU_ROW_COLUMNS))
