"""Ground truth of a simulated sequence: IMU-rate truth and its files (TUM trajectories, ``truth.npz``, EuRoC).

Frames: ENU with origin at the true GPS antenna position of the first fix; IMU axes as Rosario's (x up, y right,
z forward). Stamps: int64 ns in the arrays, seconds in the TUM files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from eval.trajectory import format_tum_rows
from pipeline.atomic import atomic_path, write_text_atomic
from pipeline.sim.export import EurocWriter
from pipeline.sim.recording import FrameRecord
from pipeline.sim.sequence_world import SequenceWorld
from pipeline.sim.timetable import StreamTimetable
from pipeline.sim.trajectory import RobotTrajectory

BODY_GT_FILE = "gt_body.tum"
ANTENNA_TRUE_GT_FILE = "gt_antenna_true.tum"
TRUTH_FILE = "truth.npz"


@dataclass(frozen=True)
class ImuTruth:
    """True IMU-frame state at every IMU stamp (N rows).

    Attributes:
        p_E: (N, 3) IMU position, ENU, m; ``q_E`` (N, 4) its orientation (IMU → ENU) as x, y, z, w;
            ``v_E`` (N, 3) velocity, ENU, m/s.
        gyro_true: (N, 3) true angular rate, rad/s; ``accel_true`` (N, 3) true specific force, m/s² (IMU frame).
    """

    p_E: np.ndarray
    q_E: np.ndarray
    v_E: np.ndarray
    gyro_true: np.ndarray
    accel_true: np.ndarray


def imu_truth(traj: RobotTrajectory, t_imu: np.ndarray, R_EF: np.ndarray, p_F0: np.ndarray,
              block: int = 8192) -> ImuTruth:
    """The truth of ``traj`` at times ``t_imu`` (s) in ENU (rotation ``R_EF`` field → ENU, origin at field
    point ``p_F0``, m); computed in blocks so memory does not grow with the duration."""
    n = len(t_imu)
    p_E, q_E, v_E = np.zeros((n, 3)), np.zeros((n, 4)), np.zeros((n, 3))
    gyro_true, accel_true = np.zeros((n, 3)), np.zeros((n, 3))
    for lo in range(0, n, block):
        kin = traj.kinematics(t_imu[lo:lo + block])
        sl = slice(lo, lo + len(kin.t))
        p_E[sl] = (kin.p_I - p_F0) @ R_EF.T
        q_E[sl] = Rotation.from_matrix(R_EF[None] @ kin.R_FI).as_quat()
        v_E[sl] = kin.v_I @ R_EF.T
        gyro_true[sl] = kin.gyro
        accel_true[sl] = kin.specific_force
    return ImuTruth(p_E=p_E, q_E=q_E, v_E=v_E, gyro_true=gyro_true, accel_true=accel_true)


def write_ground_truth(root: Path, world: SequenceWorld, timetable: StreamTimetable, imu_rows: np.ndarray,
                       frames: FrameRecord, euroc: EurocWriter | None) -> str:
    """Write ``gt_body.tum``, ``<name>_gt.txt``, ``gt_antenna_true.tum`` and ``truth.npz`` into ``root``, and the
    EuRoC ground truth (closing the EuRoC export) when ``euroc`` is given.

    Args:
        imu_rows: (N, 13) recorded IMU rows (:meth:`pipeline.sim.streams.SlowStreams.imu_rows`).
        frames: the render loop's per-frame results.
    Returns:
        The file name of the measured antenna ground truth (``<name>_gt.txt``).
    """
    cfg, gps, imu_ns, gps_ns = world.cfg, world.gps, timetable.imu_ns, timetable.gps_ns
    tr = imu_truth(world.traj, timetable.t_imu, world.R_EF, world.p_F0)
    header = (f"agrivio simulator {cfg.name} seed {world.seed}: IMU-frame pose (x up, y right, z forward) in ENU, "
              "origin at the true GPS antenna position of the first fix\ntimestamp[s] x y z qx qy qz qw")
    write_text_atomic(root / BODY_GT_FILE, format_tum_rows(imu_ns / 1e9, tr.p_E, tr.q_E, header))
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (len(timetable.t_gps), 1))
    meas0 = gps.meas_enu[0] if len(timetable.t_gps) else np.zeros(3)
    gt_name = f"{world.name}_gt.txt"
    write_text_atomic(root / gt_name, format_tum_rows(gps_ns / 1e9, gps.meas_enu - meas0, ident,
                                                      "GPS-RTK antenna positions (measured), ENU, origin at the "
                                                      "first fix\ntimestamp[s] x y z qx qy qz qw"))
    write_text_atomic(root / ANTENNA_TRUE_GT_FILE, format_tum_rows(gps_ns / 1e9, gps.true_enu, ident,
                                                                   "true GPS antenna positions, ENU, same origin "
                                                                   "as gt_body.tum\ntimestamp[s] x y z qx qy qz qw"))
    truth: dict[str, Any] = {
             "imu_stamp_ns": imu_ns, "p_E": tr.p_E, "q_E_xyzw": tr.q_E, "v_E": tr.v_E, "gyro_true": tr.gyro_true,
             "accel_true": tr.accel_true, "gyro_meas": imu_rows[:, 1:4], "accel_meas": imu_rows[:, 4:7],
             "bias_gyro": imu_rows[:, 7:10], "bias_accel": imu_rows[:, 10:13], "frame_stamp_ns": timetable.cam_ns,
             "T_E_rectleft": frames.cam_poses_E, "R_E_F": world.R_EF, "p_F_origin": world.p_F0,
             "T_base_imu": world.T_BI, "antenna_base": world.antenna_B, "gps_stamp_ns": gps_ns,
             "gps_true_enu": gps.true_enu, "gps_meas_enu": gps.meas_enu, "odom_stamp_ns": timetable.odom_ns,
             "exposure": np.array(frames.exposure), "sun_irradiance": np.array(frames.sun),
             "mean_level": np.array(frames.mean_level)}
    with atomic_path(root / TRUTH_FILE, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **truth)
    if euroc is not None:
        euroc.add_ground_truth(imu_ns, tr.p_E, tr.q_E, tr.v_E, imu_rows[:, 7:10], imu_rows[:, 10:13])
        euroc.close()
    return gt_name
