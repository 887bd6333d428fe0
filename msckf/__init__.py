"""MSCKF stereo visual-inertial odometry in the S-MSCKF mould (library: numpy arrays in, poses out).

Use :class:`msckf.vio.Msckf`; the camera model shared with the rest of agrivio is :mod:`msckf.camera`.
"""

from typing import Any

__all__ = ["Msckf", "MsckfConfig", "load_config"]


def __getattr__(name: str) -> Any:
    """Lazy exports: ``import msckf.camera`` (the simulator's render workers) does not load the filter and its
    scipy.stats dependency (0.65 s)."""
    if name == "Msckf":
        from msckf.vio import Msckf

        return Msckf
    if name in ("MsckfConfig", "load_config"):
        from msckf import config

        return getattr(config, name)
    raise AttributeError(f"module 'msckf' has no attribute {name!r}")
