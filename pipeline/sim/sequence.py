"""Simulate a whole Rosario-like sequence and read its outputs back.

Output folder (default ``<cache>/sim/<preset>-s<seed>-<duration>s/``)::

    <name>.bag                 Rosario v1 layout (stereo + camera_info 15 Hz, /imu 142 Hz, /gps/fix + /gps/vel
                               5 Hz, /odom + tf_static 10 Hz); optionally BZ2/LZ4 chunk-compressed
    camchain.yaml              Kalibr camchain of the rig the images were rendered with
    <name>_gt.txt              TUM ground truth like the real one: measured RTK antenna positions, ENU, origin at
                               the first fix, identity quaternions
    gt_antenna_true.tum        the true antenna positions at the same stamps (no RTK noise), same origin as
                               gt_body.tum
    gt_body.tum                full 6-DoF IMU-frame pose at every IMU stamp, ENU (origin: true antenna at the
                               first fix)
    truth.npz                  IMU-rate truth (pose, velocity, true gyro/accel, biases), per-frame camera poses,
                               frame transforms
    depth/chunk_NNNNN.npz      exact depth of every left frame in the rectified left camera (uint16 mm PNG), labels,
                               glare (see export.DepthChunkWriter)
    euroc/mav0/...             optional EuRoC/ASL export
    meta.json                  preset, seed, every parameter, versions, counts, timings (written last)

Determinism: the same config and seed give bit-identical streams (and bag bytes: the writer is deterministic).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import scipy
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from eval.trajectory import format_tum_rows
from msckf.camera import StereoRig
from pipeline.atomic import write_json_atomic, write_text_atomic
from pipeline.calibration import camchain_yaml, rig_from_camchain
from pipeline.errors import AgrivioError
from pipeline.paths import ROSARIO_CAMCHAIN, cache_dir
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.sim.config import SimConfig
from pipeline.sim.export import DepthChunkReader, DepthChunkWriter, EurocWriter
from pipeline.sim.imu import ImuSimulator
from pipeline.sim.mount import camera_poses, mount_transform
from pipeline.sim.presets import get_preset
from pipeline.sim.sensors import rotation_enu_field, simulate_gps, simulate_odometry
from pipeline.sim.terrain import Terrain
from pipeline.sim.trajectory import RobotTrajectory
from pipeline.sim.workers import FrameJob, RenderService

SIM_VERSION = 4
#: Frames between a frame and the first frame whose exposure reacts to it (auto-exposure latency). It is also how
#: many frames can be rendered at once, so it sets how well the render workers overlap (the images do not depend
#: on the number of workers).
AE_LATENCY_FRAMES = 3
#: Phases (seconds after the first IMU sample) of the other streams' first samples.
CAM_PHASE_S = 0.031
GPS_PHASE_S = 0.113
ODOM_PHASE_S = 0.057



def top_planned_speed(traj: RobotTrajectory, duration_s: float) -> float:
    """The highest planned speed of ``traj`` over ``[0, duration_s]`` (m/s, sampled every 0.1 s): the speed the
    EuRoC export's vibration-inclusive IMU noise figures are stated for."""
    return float(np.max(traj.planned_speed(np.arange(0.0, duration_s + 0.1, 0.1)), initial=0.0))

def _stamps(duration_s: float, rate_hz: float, phase_s: float) -> np.ndarray:
    n = int(np.floor((duration_s - phase_s) * rate_hz + 1e-9)) + 1
    return phase_s + np.arange(max(n, 0)) / rate_hz


@dataclass
class SimulatedSequence:
    """A simulated sequence on disk (see the module docstring for the layout)."""

    root: Path

    @cached_property
    def meta(self) -> dict[str, Any]:
        path = self.root / "meta.json"
        if not path.is_file():
            raise AgrivioError(f"{self.root}: not a finished simulated sequence (no meta.json)")
        return json.loads(path.read_text())

    @property
    def name(self) -> str:
        return str(self.meta["files"]["bag"]).removesuffix(".bag")

    @property
    def bag_path(self) -> Path:
        return self.root / self.meta["files"]["bag"]

    @property
    def camchain_path(self) -> Path:
        return self.root / self.meta["files"]["camchain"]

    @property
    def gt_path(self) -> Path:
        """TUM antenna ground truth, like the real ``sequence0X_gt.txt``."""
        return self.root / self.meta["files"]["gt"]

    @property
    def gt_antenna_true_path(self) -> Path:
        return self.root / self.meta["files"]["gt_antenna_true"]

    @property
    def body_gt_path(self) -> Path:
        return self.root / self.meta["files"]["gt_body"]

    @property
    def euroc_path(self) -> Path | None:
        p = self.meta["files"].get("euroc")
        return None if p is None else self.root / p

    @property
    def n_frames(self) -> int:
        return int(self.meta["counts"]["frames"])

    @property
    def config(self) -> SimConfig:
        return SimConfig.from_dict(self.meta["config"])

    def rig(self) -> StereoRig:
        """The stereo rig the images were rendered with (from the written camchain)."""
        return rig_from_camchain(self.camchain_path)

    @cached_property
    def _depth(self) -> DepthChunkReader:
        return DepthChunkReader(self.root / "depth")

    def depth(self, index: int) -> np.ndarray:
        """Exact depth of left frame ``index``: (376, 672) float32 Z in the rectified left camera, metres; NaN where
        there is none (sky, or farther than 65.5 m)."""
        return self._depth.get(index, "depth")

    def labels(self, index: int) -> np.ndarray:
        """(376, 672) uint8 surface labels of the rectified left frame (``render.LABEL_*``)."""
        return self._depth.get(index, "label")

    def glare(self, index: int) -> np.ndarray:
        """(376, 672) float32 sun-glare sensor level of the rectified left frame (0 = none, 1 = full scale)."""
        return self._depth.get(index, "glare").astype(np.float32) / 255.0

    def right_depth(self, index: int) -> np.ndarray:
        """Rectified right depth (only if simulated with ``right_depth=True``)."""
        return self._depth.get(index, "rdepth")

    def iter_depth(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, int, np.ndarray]]:
        """``(index, stamp_ns, depth)`` for frames ``start .. stop``."""
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for i in range(start, stop):
            yield i, self._depth.stamp_ns(i), self.depth(i)

    @cached_property
    def truth(self) -> dict[str, np.ndarray]:
        """Arrays of ``truth.npz`` (see :func:`simulate_sequence`)."""
        with np.load(self.root / self.meta["files"]["truth"]) as z:
            return {k: z[k] for k in z.files}

    def body_trajectory(self):
        """6-DoF IMU-frame ground truth (``eval.trajectory.Trajectory``, ENU, stamps in seconds)."""
        from eval.trajectory import read_tum

        return read_tum(self.body_gt_path)

    def antenna_ground_truth(self):
        """The Rosario-style antenna ground truth (``eval.trajectory.Trajectory``, identity orientations)."""
        from eval.trajectory import read_tum

        return read_tum(self.gt_path)


def default_output_dir(config: SimConfig, seed: int) -> Path:
    return cache_dir() / "sim" / f"{config.name}-s{seed}-{config.duration_s:g}s"


def resolve_config(preset_or_config: str | SimConfig, duration_s: float | None) -> SimConfig:
    cfg = get_preset(preset_or_config) if isinstance(preset_or_config, str) else preset_or_config
    if duration_s is not None:
        cfg = dataclasses.replace(cfg, duration_s=float(duration_s))
    if cfg.duration_s <= 0:
        raise AgrivioError(f"simulate: duration must be positive, got {cfg.duration_s}")
    return cfg


class _AutoExposure:
    """ZED-like auto exposure shared by both cameras: first-order approach of the target level."""

    def __init__(self, target: float, tau_s: float, dt: float) -> None:
        self.target = target
        self.alpha = 1.0 - np.exp(-dt / max(tau_s, 1e-6))
        self.exposure = 0.5

    def update(self, level: float, full: bool = False) -> None:
        level = max(level, 1e-3)
        step = 2.2 * np.log(self.target / level)  # sensor level ∝ exposure^(1/2.2) before clipping
        self.exposure = float(np.clip(self.exposure * np.exp(step * (1.0 if full else self.alpha)), 1e-3, 50.0))


def simulate_sequence(preset_or_config: str | SimConfig, out_dir: Path | str | None = None, seed: int = 0,
                      duration_s: float | None = None, compression: str | None = None, export_euroc: bool = False,
                      progress: bool = True, overwrite: bool = True, right_depth: bool = False,
                      rig: StereoRig | None = None, max_frames: int | None = None,
                      workers: int = 1, ae_warmup: int = 3) -> SimulatedSequence:
    """Simulate a sequence and write every output (see the module docstring).

    Args:
        preset_or_config: a preset name (``pipeline.sim.presets``) or a :class:`SimConfig`.
        out_dir: output folder (default under the cache dir).
        seed: noise, vibration and (unless ``field.world_seed`` is set) world seed.
        duration_s: override the config's duration, seconds.
        compression: bag chunk compression, ``None``, ``"lz4"`` or ``"bz2"`` (like the served bags; slow).
        export_euroc: also write the EuRoC/ASL folder.
        progress: tqdm progress bar.
        overwrite: replace an existing output folder's files.
        right_depth: also store the rectified right camera's depth and labels (for occlusion analysis).
        rig: the stereo calibration to render with (default: the shipped Rosario camchain).
        max_frames: stop rendering after this many stereo frames (other streams still cover the duration).
        workers: render frames in this many processes (results do not depend on it).
        ae_warmup: renders of the first frame to settle the auto exposure before recording (≥ 1).
    Returns:
        The written sequence.
    """
    from pipeline.bag_writer import RosarioBagWriter

    t_wall = time.perf_counter()
    cfg = resolve_config(preset_or_config, duration_s)
    seed = int(seed)
    world_seed = cfg.field.world_seed if cfg.field.world_seed is not None else seed
    root = Path(out_dir) if out_dir is not None else default_output_dir(cfg, seed)
    root.mkdir(parents=True, exist_ok=True)
    meta_path = root / "meta.json"
    if meta_path.exists():
        if not overwrite:
            raise AgrivioError(f"{root}: already holds a simulated sequence (use overwrite)")
        meta_path.unlink()
    rig = rig or rig_from_camchain(ROSARIO_CAMCHAIN)
    name = cfg.name.replace("-", "_")
    centre = ((cfg.field.n_rows - 1) * cfg.field.row_spacing_m / 2, cfg.field.row_length_m / 2)
    terrain = Terrain(cfg.field, world_seed, centre)
    T_BI = mount_transform(rig, cfg.camera.tilt_deg, cfg.camera.imu_position_m)
    traj = RobotTrajectory(cfg, terrain, T_BI, seed)
    imu = ImuSimulator(cfg.imu, traj, seed)
    R_EF = rotation_enu_field(cfg.field.azimuth_deg)
    antenna_B = np.asarray(cfg.camera.gps_antenna_m, np.float64)
    t0 = int(cfg.start_stamp_ns)

    def ns(t: np.ndarray) -> np.ndarray:
        return t0 + np.round(np.asarray(t) * 1e9).astype(np.int64)

    dur = cfg.duration_s
    t_imu = np.arange(int(np.floor(dur * cfg.imu.rate_hz + 1e-9)) + 1) / cfg.imu.rate_hz
    t_cam = _stamps(dur, RATE_CAMERA_HZ, CAM_PHASE_S)
    if max_frames is not None:
        t_cam = t_cam[:max_frames]
    t_gps = _stamps(dur, cfg.gps.rate_hz, GPS_PHASE_S)
    t_odom = _stamps(dur, cfg.odom.rate_hz, ODOM_PHASE_S)
    gps, p_F0 = simulate_gps(cfg.gps, traj, antenna_B, R_EF, t_gps, seed)
    odom = simulate_odometry(cfg.odom, traj, t_odom, seed)
    T_base_gps = np.eye(4)
    T_base_gps[:3, 3] = antenna_B
    statics = (("base_link", "imu", T_BI), ("imu", "left", np.linalg.inv(rig.T_left_imu)),
               ("imu", "right", np.linalg.inv(rig.T_right_imu)), ("base_link", "gps", T_base_gps))
    cam_ns = ns(t_cam + cfg.camera.time_offset_s)
    imu_ns, gps_ns, odom_ns = ns(t_imu), ns(t_gps), ns(t_odom)

    ae = _AutoExposure(cfg.camera.ae_target, cfg.camera.ae_tau_s, 1.0 / RATE_CAMERA_HZ)
    depth_writer = DepthChunkWriter(root / "depth")
    for old in (root / "depth").glob("chunk_*.npz"):
        old.unlink()
    top_speed = top_planned_speed(traj, cfg.duration_s)
    euroc = EurocWriter(root / "euroc", rig, cfg.imu, RATE_CAMERA_HZ, max_speed_m_s=top_speed) if export_euroc else None
    imu_rows: list[np.ndarray] = []
    cam_poses_E = np.zeros((len(t_cam), 4, 4))
    bag_path = root / f"{name}.bag"
    frame_stats = {"mean_level": [], "exposure": [], "sun": []}
    i_imu = i_gps = i_odom = 0

    def flush_until(w: RosarioBagWriter, stamp: int) -> None:
        nonlocal i_imu
        n_new = int(np.searchsorted(imu_ns, stamp, side="right")) - i_imu
        if n_new > 0:
            chunk = imu.next(n_new)
            rows = np.column_stack([chunk.t, chunk.gyro, chunk.accel, chunk.bias_gyro, chunk.bias_accel])
            imu_rows.append(rows)
            if euroc is not None:
                euroc.add_imu(imu_ns[i_imu:i_imu + n_new], chunk.gyro, chunk.accel)
            # interleave with GPS and odometry in stamp order
            for j in range(n_new):
                s = int(imu_ns[i_imu + j])
                _flush_slow(w, s)
                w.write_imu(s, chunk.gyro[j], chunk.accel[j])
            i_imu += n_new
        _flush_slow(w, stamp)

    def _flush_slow(w: RosarioBagWriter, stamp: int) -> None:
        nonlocal i_gps, i_odom
        while i_gps < len(gps_ns) and gps_ns[i_gps] <= stamp:
            s = int(gps_ns[i_gps])
            w.write_gps_fix(s, float(gps.lat[i_gps]), float(gps.lon[i_gps]), float(gps.alt[i_gps]),
                            status=2, hdop=cfg.gps.hdop)
            w.write_gps_vel(s, float(gps.vel_en[i_gps, 0]), float(gps.vel_en[i_gps, 1]))
            i_gps += 1
        while i_odom < len(odom_ns) and odom_ns[i_odom] <= stamp:
            s = int(odom_ns[i_odom])
            w.write_odom(s, float(odom.x[i_odom]), float(odom.y[i_odom]), float(odom.yaw[i_odom]),
                         float(odom.v[i_odom]), float(odom.yaw_rate[i_odom]))
            w.write_tf_static(s, statics)
            i_odom += 1

    # ---- render (possibly in worker processes) and stream everything into the bag in stamp order ----------------
    svc = RenderService(rig, cfg, world_seed, seed, workers=workers, right_depth=right_depth)
    poses = np.tile(np.eye(4), (len(t_cam), 1, 1))
    for lo in range(0, len(t_cam), 4096):
        kc = traj.kinematics(t_cam[lo:lo + 4096])
        poses[lo:lo + len(kc.t), :3, :3] = kc.R_FI
        poses[lo:lo + len(kc.t), :3, 3] = kc.p_I
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
                flush_until(w, stamp)
                frame_stats["mean_level"].append(fr.mean_level)
                frame_stats["exposure"].append(exposures[k])
                frame_stats["sun"].append(fr.sun)
                w.write_stereo(stamp, fr.left_bgr, fr.right_bgr)
                depth_writer.add_encoded(k, stamp, fr.depth_blobs)
                if euroc is not None:
                    euroc.add_stereo(stamp, fr.left_bgr, fr.right_bgr)
                T_L, _ = camera_poses(poses[k], rig)
                T_E = np.eye(4)
                T_E[:3, :3] = R_EF @ T_L[:3, :3]
                T_E[:3, 3] = R_EF @ (T_L[:3, 3] - p_F0)
                cam_poses_E[k] = T_E
                bar.update()
            bar.close()
            flush_until(w, int(max(imu_ns[-1], gps_ns[-1] if len(gps_ns) else 0,
                                   odom_ns[-1] if len(odom_ns) else 0)))
        depth_writer.flush()
    except BaseException:
        if euroc is not None:
            euroc.abort()
        raise
    finally:
        svc.close()

    # ---- ground truth -----------------------------------------------------------------------------------------------
    imu_all = np.concatenate(imu_rows) if imu_rows else np.zeros((0, 13))
    p_E = np.zeros((len(t_imu), 3))
    q_E = np.zeros((len(t_imu), 4))
    v_E = np.zeros((len(t_imu), 3))
    gyro_true = np.zeros((len(t_imu), 3))
    accel_true = np.zeros((len(t_imu), 3))
    for lo in range(0, len(t_imu), 8192):  # in chunks: memory does not grow with the duration
        kin = traj.kinematics(t_imu[lo:lo + 8192])
        sl = slice(lo, lo + len(kin.t))
        p_E[sl] = (kin.p_I - p_F0) @ R_EF.T
        q_E[sl] = Rotation.from_matrix(R_EF[None] @ kin.R_FI).as_quat()
        v_E[sl] = kin.v_I @ R_EF.T
        gyro_true[sl] = kin.gyro
        accel_true[sl] = kin.specific_force
    header = (f"agrivio simulator {cfg.name} seed {seed}: IMU-frame pose (x up, y right, z forward) in ENU, origin "
              "at the true GPS antenna position of the first fix\ntimestamp[s] x y z qx qy qz qw")
    write_text_atomic(root / "gt_body.tum", format_tum_rows(imu_ns / 1e9, p_E, q_E, header))
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (len(t_gps), 1))
    meas0 = gps.meas_enu[0] if len(t_gps) else np.zeros(3)
    gt_name = f"{name}_gt.txt"
    write_text_atomic(root / gt_name, format_tum_rows(gps_ns / 1e9, gps.meas_enu - meas0, ident,
                                               "GPS-RTK antenna positions (measured), ENU, origin at the first fix\n"
                                               "timestamp[s] x y z qx qy qz qw"))
    write_text_atomic(root / "gt_antenna_true.tum", format_tum_rows(gps_ns / 1e9, gps.true_enu, ident,
                                                            "true GPS antenna positions, ENU, same origin as "
                                                            "gt_body.tum\ntimestamp[s] x y z qx qy qz qw"))
    truth = {"imu_stamp_ns": imu_ns, "p_E": p_E, "q_E_xyzw": q_E, "v_E": v_E, "gyro_true": gyro_true,
             "accel_true": accel_true, "gyro_meas": imu_all[:, 1:4], "accel_meas": imu_all[:, 4:7],
             "bias_gyro": imu_all[:, 7:10], "bias_accel": imu_all[:, 10:13], "frame_stamp_ns": cam_ns,
             "T_E_rectleft": cam_poses_E, "R_E_F": R_EF, "p_F_origin": p_F0, "T_base_imu": T_BI,
             "antenna_base": antenna_B, "gps_stamp_ns": gps_ns, "gps_true_enu": gps.true_enu,
             "gps_meas_enu": gps.meas_enu, "odom_stamp_ns": odom_ns,
             "exposure": np.array(frame_stats["exposure"]), "sun_irradiance": np.array(frame_stats["sun"]),
             "mean_level": np.array(frame_stats["mean_level"])}
    from pipeline.atomic import atomic_path

    with atomic_path(root / "truth.npz", suffix=".npz") as tmp:
        np.savez_compressed(tmp, **truth)
    if euroc is not None:
        euroc.add_ground_truth(imu_ns, p_E, q_E, v_E, imu_all[:, 7:10], imu_all[:, 10:13])
        euroc.close()
    write_text_atomic(root / "camchain.yaml", camchain_yaml(rig))
    from pipeline.version import code_version

    files = {"bag": bag_path.name, "camchain": "camchain.yaml", "gt": gt_name, "gt_antenna_true":
             "gt_antenna_true.tum", "gt_body": "gt_body.tum", "truth": "truth.npz", "depth": "depth"}
    if euroc is not None:
        files["euroc"] = "euroc"
    meta = {
        "simulator_version": SIM_VERSION, "preset": cfg.name, "seed": seed, "world_seed": world_seed,
        "config": cfg.to_dict(), "files": files,
        "counts": {"frames": int(len(t_cam)), "imu": int(len(t_imu)), "gps": int(len(t_gps)),
                   "odom": int(len(t_odom))},
        "start_stamp_ns": t0, "duration_s": dur, "compression": compression,
        "depth": {"frame": "rectified left camera (OpenCV optical), Z in metres", "encoding":
                  "uint16 millimetres PNG, 0 = none (sky / beyond 65.535 m)", "chunk": depth_writer.chunk,
                  "stored": ["depth", "label", "glare"] + (["rdepth", "rlabel"] if right_depth else [])},
        "frames": {"field": "x across rows, y along rows, z up", "enu": "R_E_F (field→ENU), origin = true "
                   "antenna at the first GPS fix", "imu": "Rosario IMU axes (x up, y right, z forward)"},
        "versions": {"code": code_version(), "numpy": np.__version__, "scipy": scipy.__version__,
                     "opencv": cv2.__version__, "python": platform.python_version()},
        "wall_s": time.perf_counter() - t_wall,
        "exposure": {"min": float(np.min(frame_stats["exposure"])) if frame_stats["exposure"] else None,
                     "max": float(np.max(frame_stats["exposure"])) if frame_stats["exposure"] else None},
    }
    write_json_atomic(meta_path, meta)
    return SimulatedSequence(root)
