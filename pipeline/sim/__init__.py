"""Rosario-like soybean-field simulator: world, renderer, trajectory, IMU/GPS/odometry, bag and ground truth.

Public API::

    from pipeline.sim import simulate_sequence, open_sequence, get_preset, SimConfig

    seq = simulate_sequence("rosario-like-01", out_dir, seed=0, duration_s=20, export_euroc=True)
    seq.bag_path, seq.gt_path, seq.body_gt_path, seq.camchain_path
    depth = seq.depth(12)                 # exact depth of left frame 12, rectified left camera, metres (NaN: none)
    body = seq.body_trajectory()          # 6-DoF IMU ground truth (eval.trajectory.Trajectory, ENU)

See ``pipeline/sim/sequence.py`` for the output layout and ``pipeline/sim/config.py`` for every parameter.
"""

from pipeline.sim.config import SimConfig
from pipeline.sim.presets import get_preset, preset_names
from pipeline.sim.sequence import SimulatedSequence, simulate_sequence


def open_sequence(path) -> SimulatedSequence:
    """A previously simulated sequence folder (raises ``AgrivioError`` if it is not finished)."""
    from pathlib import Path

    seq = SimulatedSequence(Path(path))
    _ = seq.meta
    return seq


__all__ = ["SimConfig", "SimulatedSequence", "get_preset", "open_sequence", "preset_names", "simulate_sequence"]
