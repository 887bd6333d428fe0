"""Render the frames of a sequence and stream them, with every other sensor, into the bag in stamp order.

Auto exposure: both cameras share a ZED-like exposure that approaches the target level; the exposure of frame
``k + AE_LATENCY_FRAMES`` reacts to the level of frame ``k`` (the latency also bounds how many frames render at once).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from msckf.camera import StereoRig
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.sim.export import DepthChunkWriter, EurocWriter
from pipeline.sim.mount import camera_poses
from pipeline.sim.sequence_world import SequenceWorld
from pipeline.sim.streams import SlowStreams
from pipeline.sim.timetable import StreamTimetable
from pipeline.sim.trajectory import RobotTrajectory
from pipeline.sim.workers import FrameJob, RenderService

#: Frames between a frame and the first frame whose exposure reacts to it (auto-exposure latency). It is also how
#: many frames can be rendered at once, so it sets how well the render workers overlap (the images do not depend
#: on the number of workers).
AE_LATENCY_FRAMES = 3


class AutoExposure:
    """ZED-like auto exposure shared by both cameras: first-order approach of the target level.

    Args:
        target: target mean sensor level (0..1); ``tau_s`` time constant, s; ``dt`` frame period, s.
    """

    def __init__(self, target: float, tau_s: float, dt: float) -> None:
        self.target = target
        self.alpha = 1.0 - np.exp(-dt / max(tau_s, 1e-6))
        self.exposure = 0.5

    def update(self, level: float, full: bool = False) -> None:
        """Move the exposure towards the target after a frame of mean ``level`` (all the way if ``full``)."""
        level = max(level, 1e-3)
        step = 2.2 * np.log(self.target / level)  # sensor level ∝ exposure^(1/2.2) before clipping
        self.exposure = float(np.clip(self.exposure * np.exp(step * (1.0 if full else self.alpha)), 1e-3, 50.0))


@dataclass
class FrameRecord:
    """Per-frame results of the render loop.

    Attributes:
        cam_poses_E: (N, 4, 4) rectified-left camera poses in ENU (origin: true antenna at the first fix), m.
        mean_level: mean sensor level of each frame (0..1); ``exposure`` the exposure it was rendered with;
            ``sun`` its sun irradiance.
    """

    cam_poses_E: np.ndarray
    mean_level: list[float] = field(default_factory=list)
    exposure: list[float] = field(default_factory=list)
    sun: list[float] = field(default_factory=list)


def imu_poses_field(traj: RobotTrajectory, t_s: np.ndarray, block: int = 4096) -> np.ndarray:
    """(N, 4, 4) true IMU poses ``T_F_imu`` in the field frame (m) at times ``t_s`` (s), computed in blocks."""
    poses = np.tile(np.eye(4), (len(t_s), 1, 1))
    for lo in range(0, len(t_s), block):
        kc = traj.kinematics(t_s[lo:lo + block])
        poses[lo:lo + len(kc.t), :3, :3] = kc.R_FI
        poses[lo:lo + len(kc.t), :3, 3] = kc.p_I
    return poses


def camera_pose_enu(T_F_imu: np.ndarray, rig: StereoRig, R_EF: np.ndarray, p_F0: np.ndarray) -> np.ndarray:
    """(4, 4) rectified-left camera pose in ENU (origin at field point ``p_F0``, m) of the IMU pose ``T_F_imu``."""
    T_L, _ = camera_poses(T_F_imu, rig)
    T_E = np.eye(4)
    T_E[:3, :3] = R_EF @ T_L[:3, :3]
    T_E[:3, 3] = R_EF @ (T_L[:3, 3] - p_F0)
    return T_E


def record_sequence(world: SequenceWorld, timetable: StreamTimetable, bag_path: Path, streams: SlowStreams,
                    depth_writer: DepthChunkWriter, euroc: EurocWriter | None, *, compression: str | None,
                    overwrite: bool, right_depth: bool, workers: int, ae_warmup: int,
                    progress: bool) -> FrameRecord:
    """Render every frame of ``timetable`` and write the bag, the depth chunks and the EuRoC images/IMU.

    Frames are rendered ``AE_LATENCY_FRAMES`` ahead (in ``workers`` processes); before each frame is written,
    ``streams`` writes every IMU/GPS/odometry sample stamped up to it, and after the last frame the rest. On any
    error the EuRoC export is aborted; the render workers are always closed.
    """
    from pipeline.bag_writer import RosarioBagWriter

    cfg, rig, t_cam, cam_ns = world.cfg, world.rig, timetable.t_cam, timetable.cam_ns
    ae = AutoExposure(cfg.camera.ae_target, cfg.camera.ae_tau_s, 1.0 / RATE_CAMERA_HZ)
    record = FrameRecord(cam_poses_E=np.zeros((len(t_cam), 4, 4)))
    svc = RenderService(rig, cfg, world.world_seed, world.seed, workers=workers, right_depth=right_depth)
    poses = imu_poses_field(world.traj, t_cam)
    try:
        if len(t_cam):  # auto exposure converges on the first frame (the camera was running before recording)
            for _ in range(max(1, int(ae_warmup))):
                fr = svc.render_now(FrameJob(0, float(t_cam[0]), poses[0], ae.exposure))
                ae.update(fr.mean_level, full=True)
        lag = AE_LATENCY_FRAMES
        exposures = [ae.exposure] * min(lag, len(t_cam))
        for k in range(len(exposures)):
            svc.submit(FrameJob(k, float(t_cam[k]), poses[k], exposures[k]))
        with RosarioBagWriter(bag_path, compression=compression, overwrite=overwrite) as w:
            w.set_camera_info(rig)
            bar = tqdm(total=len(t_cam), desc=f"simulate {cfg.name}", unit="frame", disable=not progress)
            for k in range(len(t_cam)):
                idx, fr = svc.next_result()
                assert idx == k
                # the exposure of frame k + lag reacts to frame k (auto-exposure latency)
                if k + lag < len(t_cam):
                    ae.update(fr.mean_level)
                    exposures.append(ae.exposure)
                    svc.submit(FrameJob(k + lag, float(t_cam[k + lag]), poses[k + lag], ae.exposure))
                stamp = int(cam_ns[k])
                streams.flush_until(w, stamp)
                record.mean_level.append(fr.mean_level)
                record.exposure.append(exposures[k])
                record.sun.append(fr.sun)
                w.write_stereo(stamp, fr.left_bgr, fr.right_bgr)
                depth_writer.add_encoded(k, stamp, fr.depth_blobs)
                if euroc is not None:
                    euroc.add_stereo(stamp, fr.left_bgr, fr.right_bgr)
                record.cam_poses_E[k] = camera_pose_enu(poses[k], rig, world.R_EF, world.p_F0)
                bar.update()
            bar.close()
            streams.flush_until(w, timetable.last_stamp_ns)
        depth_writer.flush()
    except BaseException:
        if euroc is not None:
            euroc.abort()
        raise
    finally:
        svc.close()
    return record
