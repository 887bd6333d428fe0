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
import sys
import time
from pathlib import Path

import numpy as np

from msckf.camera import StereoRig
from pipeline.atomic import remove_stale_temporaries, write_json_atomic, write_text_atomic
from pipeline.calibration import camchain_yaml, rig_from_camchain
from pipeline.errors import AgrivioError
from pipeline.paths import ROSARIO_CAMCHAIN, cache_dir
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.sim.config import SimConfig
from pipeline.sim.export import DepthChunkWriter, EurocWriter
from pipeline.sim.ground_truth import write_ground_truth
from pipeline.sim.meta import CAMCHAIN_FILE, DEPTH_FOLDER, EUROC_FOLDER, SIM_VERSION, build_meta, output_files
from pipeline.sim.presets import get_preset
from pipeline.sim.recording import AE_LATENCY_FRAMES, AutoExposure, record_sequence
from pipeline.sim.sequence_world import SequenceWorld
from pipeline.sim.simulated import SimulatedSequence
from pipeline.sim.streams import SlowStreams
from pipeline.sim.timetable import CAM_PHASE_S, GPS_PHASE_S, ODOM_PHASE_S, StreamTimetable, _stamps
from pipeline.sim.trajectory import RobotTrajectory

#: Former private name of :class:`pipeline.sim.recording.AutoExposure`.
_AutoExposure = AutoExposure

__all__ = ["AE_LATENCY_FRAMES", "CAM_PHASE_S", "GPS_PHASE_S", "ODOM_PHASE_S", "SIM_VERSION", "SimulatedSequence",
           "default_output_dir", "prepare_output_dir", "resolve_config", "simulate_sequence", "top_planned_speed",
           "_stamps"]


def top_planned_speed(traj: RobotTrajectory, duration_s: float) -> float:
    """The highest planned speed of ``traj`` over ``[0, duration_s]`` (m/s, sampled every 0.1 s): the speed the
    EuRoC export's vibration-inclusive IMU noise figures are stated for."""
    return float(np.max(traj.planned_speed(np.arange(0.0, duration_s + 0.1, 0.1)), initial=0.0))


def default_output_dir(config: SimConfig, seed: int) -> Path:
    """``<cache>/sim/<preset>-s<seed>-<duration>s``."""
    return cache_dir() / "sim" / f"{config.name}-s{seed}-{config.duration_s:g}s"


def resolve_config(preset_or_config: str | SimConfig, duration_s: float | None) -> SimConfig:
    """The config of a preset name or config, with ``duration_s`` (s) overriding its duration when given."""
    cfg = get_preset(preset_or_config) if isinstance(preset_or_config, str) else preset_or_config
    if duration_s is not None:
        cfg = dataclasses.replace(cfg, duration_s=float(duration_s))
    if cfg.duration_s <= 0:
        raise AgrivioError(f"simulate: duration must be positive, got {cfg.duration_s}")
    return cfg


def prepare_output_dir(root: Path, overwrite: bool) -> Path:
    """Create ``root`` and remove its ``meta.json`` (a sequence is finished only once it is rewritten).

    Raises:
        AgrivioError: ``root`` holds a finished sequence and ``overwrite`` is false.
    """
    root.mkdir(parents=True, exist_ok=True)
    meta_path = root / "meta.json"
    if meta_path.exists():
        if not overwrite:
            raise AgrivioError(f"{root}: already holds a simulated sequence (use overwrite)")
        meta_path.unlink()
    return meta_path


def _depth_writer(root: Path) -> DepthChunkWriter:
    """A depth chunk writer for ``root/depth`` with the chunks of an earlier run removed."""
    writer = DepthChunkWriter(root / DEPTH_FOLDER)
    for old in (root / DEPTH_FOLDER).glob("chunk_*.npz"):
        old.unlink()
    return writer


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
    t_wall = time.perf_counter()
    cfg = resolve_config(preset_or_config, duration_s)
    seed = int(seed)
    root = Path(out_dir) if out_dir is not None else default_output_dir(cfg, seed)
    meta_path = prepare_output_dir(root, overwrite)
    timetable = StreamTimetable.from_config(cfg, max_frames)
    world = SequenceWorld.build(cfg, seed, rig or rig_from_camchain(ROSARIO_CAMCHAIN), timetable)
    depth_writer = _depth_writer(root)
    euroc = EurocWriter(root / EUROC_FOLDER, world.rig, cfg.imu, RATE_CAMERA_HZ,
                        max_speed_m_s=top_planned_speed(world.traj, cfg.duration_s)) if export_euroc else None
    streams = SlowStreams(world.imu, timetable.imu_ns, world.gps, timetable.gps_ns, world.odom, timetable.odom_ns,
                          world.statics, cfg.gps.hdop, imu_sink=euroc)
    bag_path = root / f"{world.name}.bag"
    for stale, size in remove_stale_temporaries(bag_path):  # this folder is being (re)simulated: nobody else writes it
        print(f"removed an interrupted simulation's temporary bag {stale} ({size / 1e9:.1f} GB)", file=sys.stderr)
    frames = record_sequence(world, timetable, bag_path, streams, depth_writer, euroc, compression=compression,
                             overwrite=overwrite, right_depth=right_depth, workers=workers, ae_warmup=ae_warmup,
                             progress=progress)
    gt_name = write_ground_truth(root, world, timetable, streams.imu_rows(), frames, euroc)
    write_text_atomic(root / CAMCHAIN_FILE, camchain_yaml(world.rig))
    files = output_files(bag_path.name, gt_name, euroc is not None)
    write_json_atomic(meta_path, build_meta(world, timetable, frames, files, compression=compression,
                                            depth_chunk=depth_writer.chunk, right_depth=right_depth,
                                            wall_s=time.perf_counter() - t_wall))
    return SimulatedSequence(root)
