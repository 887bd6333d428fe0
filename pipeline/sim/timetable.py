"""The stream timetable of a simulated sequence: when each sensor samples, in seconds and in bag ns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.sim.config import SimConfig

#: Phases (seconds after the first IMU sample) of the other streams' first samples.
CAM_PHASE_S = 0.031
GPS_PHASE_S = 0.113
ODOM_PHASE_S = 0.057


def _stamps(duration_s: float, rate_hz: float, phase_s: float) -> np.ndarray:
    """(N,) float64 sample times ``phase_s + k / rate_hz`` (s since the first IMU sample) within ``duration_s``."""
    n = int(np.floor((duration_s - phase_s) * rate_hz + 1e-9)) + 1
    return phase_s + np.arange(max(n, 0)) / rate_hz


def to_bag_ns(start_stamp_ns: int, t_s: np.ndarray) -> np.ndarray:
    """(N,) int64 bag stamps, ns: ``start_stamp_ns`` plus ``t_s`` (s since the first IMU sample) rounded to ns."""
    return start_stamp_ns + np.round(np.asarray(t_s) * 1e9).astype(np.int64)


@dataclass(frozen=True)
class StreamTimetable:
    """Sample times of every stream of a sequence.

    Attributes:
        t_imu, t_cam, t_gps, t_odom: (N,) float64 sample times, s since the first IMU sample (the camera's
            without its clock offset ``camera.time_offset_s``).
        imu_ns, cam_ns, gps_ns, odom_ns: (N,) int64 bag/header stamps, ns (``start_stamp_ns`` + the time; the
            camera's includes ``camera.time_offset_s``).
        start_stamp_ns: stamp of the first IMU sample, ns.
    """

    t_imu: np.ndarray
    t_cam: np.ndarray
    t_gps: np.ndarray
    t_odom: np.ndarray
    imu_ns: np.ndarray
    cam_ns: np.ndarray
    gps_ns: np.ndarray
    odom_ns: np.ndarray
    start_stamp_ns: int

    @classmethod
    def from_config(cls, cfg: SimConfig, max_frames: int | None = None) -> StreamTimetable:
        """The timetable of ``cfg`` over ``[0, cfg.duration_s]``; at most ``max_frames`` camera frames."""
        dur = cfg.duration_s
        t0 = int(cfg.start_stamp_ns)
        t_imu = np.arange(int(np.floor(dur * cfg.imu.rate_hz + 1e-9)) + 1) / cfg.imu.rate_hz
        t_cam = _stamps(dur, RATE_CAMERA_HZ, CAM_PHASE_S)
        if max_frames is not None:
            t_cam = t_cam[:max_frames]
        t_gps = _stamps(dur, cfg.gps.rate_hz, GPS_PHASE_S)
        t_odom = _stamps(dur, cfg.odom.rate_hz, ODOM_PHASE_S)
        return cls(t_imu=t_imu, t_cam=t_cam, t_gps=t_gps, t_odom=t_odom, imu_ns=to_bag_ns(t0, t_imu),
                   cam_ns=to_bag_ns(t0, t_cam + cfg.camera.time_offset_s), gps_ns=to_bag_ns(t0, t_gps),
                   odom_ns=to_bag_ns(t0, t_odom), start_stamp_ns=t0)

    @property
    def last_stamp_ns(self) -> int:
        """The latest IMU, GPS or odometry stamp, ns: the slow streams are flushed up to it after the last frame."""
        return int(max(self.imu_ns[-1], self.gps_ns[-1] if len(self.gps_ns) else 0,
                       self.odom_ns[-1] if len(self.odom_ns) else 0))
