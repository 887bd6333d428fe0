"""The simulated world of one sequence: terrain, rig mount, trajectory and the sensor simulators."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msckf.camera import StereoRig
from pipeline.sim.config import SimConfig
from pipeline.sim.imu import ImuSimulator
from pipeline.sim.mount import mount_transform
from pipeline.sim.sensors import GpsSamples, OdomSamples, rotation_enu_field, simulate_gps, simulate_odometry
from pipeline.sim.terrain import Terrain
from pipeline.sim.timetable import StreamTimetable
from pipeline.sim.trajectory import RobotTrajectory

#: ``(parent, child, T_parent_child)`` entries of a ``tf_static`` message; T is (4, 4), metres.
StaticTransforms = tuple[tuple[str, str, np.ndarray], ...]


def static_transforms(T_BI: np.ndarray, rig: StereoRig, antenna_B: np.ndarray) -> StaticTransforms:
    """The ``tf_static`` content: base_link→imu (``T_BI``), imu→left/right camera, base_link→gps antenna."""
    T_base_gps = np.eye(4)
    T_base_gps[:3, 3] = antenna_B
    return (("base_link", "imu", T_BI), ("imu", "left", np.linalg.inv(rig.T_left_imu)),
            ("imu", "right", np.linalg.inv(rig.T_right_imu)), ("base_link", "gps", T_base_gps))


@dataclass
class SequenceWorld:
    """Everything the streams of a sequence are simulated from.

    Attributes:
        cfg: the resolved config; ``seed`` the noise/vibration seed, ``world_seed`` the terrain seed.
        rig: the stereo rig the images are rendered with.
        terrain: the field; ``T_BI`` (4, 4) IMU pose in base_link (m); ``traj`` the true motion.
        imu: the streaming IMU simulator (stateful: :meth:`ImuSimulator.next` advances it).
        R_EF: (3, 3) rotation field frame → ENU; ``antenna_B`` (3,) GPS antenna in base_link, m.
        gps: every GPS sample; ``p_F0`` (3,) field-frame origin of the ENU frame (true antenna at the first fix), m.
        odom: every wheel-odometry sample.
        statics: the ``tf_static`` transforms.
    """

    cfg: SimConfig
    seed: int
    world_seed: int
    rig: StereoRig
    terrain: Terrain
    T_BI: np.ndarray
    traj: RobotTrajectory
    imu: ImuSimulator
    R_EF: np.ndarray
    antenna_B: np.ndarray
    gps: GpsSamples
    p_F0: np.ndarray
    odom: OdomSamples
    statics: StaticTransforms

    @property
    def name(self) -> str:
        """The sequence name used in file names (the config name with ``-`` → ``_``)."""
        return self.cfg.name.replace("-", "_")

    @classmethod
    def build(cls, cfg: SimConfig, seed: int, rig: StereoRig, timetable: StreamTimetable) -> SequenceWorld:
        """Build the world of ``cfg`` (world seed ``cfg.field.world_seed``, else ``seed``) and simulate the GPS
        and odometry at the timetable's stamps."""
        world_seed = cfg.field.world_seed if cfg.field.world_seed is not None else seed
        centre = ((cfg.field.n_rows - 1) * cfg.field.row_spacing_m / 2, cfg.field.row_length_m / 2)
        terrain = Terrain(cfg.field, world_seed, centre)
        T_BI = mount_transform(rig, cfg.camera.tilt_deg, cfg.camera.imu_position_m)
        traj = RobotTrajectory(cfg, terrain, T_BI, seed)
        imu = ImuSimulator(cfg.imu, traj, seed)
        R_EF = rotation_enu_field(cfg.field.azimuth_deg)
        antenna_B = np.asarray(cfg.camera.gps_antenna_m, np.float64)
        gps, p_F0 = simulate_gps(cfg.gps, traj, antenna_B, R_EF, timetable.t_gps, seed)
        odom = simulate_odometry(cfg.odom, traj, timetable.t_odom, seed)
        return cls(cfg=cfg, seed=seed, world_seed=world_seed, rig=rig, terrain=terrain, T_BI=T_BI, traj=traj,
                   imu=imu, R_EF=R_EF, antenna_B=antenna_B, gps=gps, p_F0=p_F0, odom=odom,
                   statics=static_transforms(T_BI, rig, antenna_B))
