"""Rosario-like soybean-field simulator: world, renderer, trajectory, IMU/GPS/odometry, bag and ground truth.

Public API::

    from pipeline.sim import simulate_sequence, open_sequence, get_preset, SimConfig

    seq = simulate_sequence("rosario-like-01", out_dir, seed=0, duration_s=20, export_euroc=True)
    seq.bag_path, seq.gt_path, seq.body_gt_path, seq.camchain_path
    depth = seq.depth(12)                 # exact depth of left frame 12, rectified left camera, metres (NaN: none)
    body = seq.body_trajectory()          # 6-DoF IMU ground truth (eval.trajectory.Trajectory, ENU)

See ``pipeline/sim/sequence.py`` for the output layout and ``pipeline/sim/config.py`` for every parameter.
"""

from typing import Any

from pipeline.sim.config import SimConfig
from pipeline.sim.presets import get_preset, preset_names


def open_sequence(path) -> Any:
    """A previously simulated sequence folder (``SimulatedSequence``; raises ``AgrivioError`` if it is not
    finished)."""
    from pathlib import Path

    from pipeline.sim.sequence import SimulatedSequence

    seq = SimulatedSequence(Path(path))
    _ = seq.meta
    return seq


def __getattr__(name: str) -> Any:
    """Lazy exports of the sequence module: a render worker importing ``pipeline.sim.workers`` does not load the
    bag writer, the IMU simulator and their dependencies."""
    if name in ("SimulatedSequence", "simulate_sequence"):
        from pipeline.sim import sequence

        return getattr(sequence, name)
    raise AttributeError(f"module 'pipeline.sim' has no attribute {name!r}")


__all__ = ["SimConfig", "SimulatedSequence", "get_preset", "open_sequence", "preset_names", "simulate_sequence"]
