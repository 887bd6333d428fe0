"""MSCKF stereo visual-inertial odometry in the S-MSCKF mould (library: numpy arrays in, poses out).

Use :class:`msckf.vio.Msckf`; the camera model shared with the rest of agrivio is :mod:`msckf.camera`.
"""

from msckf.config import MsckfConfig, load_config
from msckf.vio import Msckf

__all__ = ["Msckf", "MsckfConfig", "load_config"]
