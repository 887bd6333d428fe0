"""``meta.json`` of a simulated sequence: preset, seed, every parameter, file names, counts, versions, timing."""

from __future__ import annotations

import platform
from typing import Any

import cv2
import numpy as np
import scipy

from pipeline.sim.ground_truth import ANTENNA_TRUE_GT_FILE, BODY_GT_FILE, TRUTH_FILE
from pipeline.sim.recording import FrameRecord
from pipeline.sim.sequence_world import SequenceWorld
from pipeline.sim.timetable import StreamTimetable

SIM_VERSION = 4
CAMCHAIN_FILE = "camchain.yaml"
DEPTH_FOLDER = "depth"
EUROC_FOLDER = "euroc"


def output_files(bag_name: str, gt_name: str, euroc: bool) -> dict[str, str]:
    """The ``files`` entry of ``meta.json``: role → name relative to the output folder."""
    files = {"bag": bag_name, "camchain": CAMCHAIN_FILE, "gt": gt_name, "gt_antenna_true": ANTENNA_TRUE_GT_FILE,
             "gt_body": BODY_GT_FILE, "truth": TRUTH_FILE, "depth": DEPTH_FOLDER}
    if euroc:
        files["euroc"] = EUROC_FOLDER
    return files


def build_meta(world: SequenceWorld, timetable: StreamTimetable, frames: FrameRecord, files: dict[str, str], *,
               compression: str | None, depth_chunk: int, right_depth: bool, wall_s: float) -> dict[str, Any]:
    """The content of ``meta.json`` (``wall_s``: the simulation's wall time, s)."""
    from pipeline.version import code_version

    cfg = world.cfg
    return {
        "simulator_version": SIM_VERSION, "preset": cfg.name, "seed": world.seed, "world_seed": world.world_seed,
        "config": cfg.to_dict(), "files": files,
        "counts": {"frames": int(len(timetable.t_cam)), "imu": int(len(timetable.t_imu)),
                   "gps": int(len(timetable.t_gps)), "odom": int(len(timetable.t_odom))},
        "start_stamp_ns": timetable.start_stamp_ns, "duration_s": cfg.duration_s, "compression": compression,
        "depth": {"frame": "rectified left camera (OpenCV optical), Z in metres", "encoding":
                  "uint16 millimetres PNG, 0 = none (sky / beyond 65.535 m)", "chunk": depth_chunk,
                  "stored": ["depth", "label", "glare"] + (["rdepth", "rlabel"] if right_depth else [])},
        "frames": {"field": "x across rows, y along rows, z up", "enu": "R_E_F (field→ENU), origin = true "
                   "antenna at the first GPS fix", "imu": "Rosario IMU axes (x up, y right, z forward)"},
        "versions": {"code": code_version(), "numpy": np.__version__, "scipy": scipy.__version__,
                     "opencv": cv2.__version__, "python": platform.python_version()},
        "wall_s": wall_s,
        "exposure": {"min": float(np.min(frames.exposure)) if frames.exposure else None,
                     "max": float(np.max(frames.exposure)) if frames.exposure else None},
    }
