"""The calibration of a Rosario bag: camera_info from the bag, camera–IMU extrinsics from a Kalibr camchain."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from msckf.camera import StereoRig
from pipeline import rosario_layout as L
from pipeline.bag_container import BagContainer
from pipeline.calibration import CalibrationError, Camchain, CameraInfo, read_camchain, rig_from_camera_info
from pipeline.paths import ROSARIO_CAMCHAIN


def camera_info_from_msg(msg: Any) -> CameraInfo:
    """A ``sensor_msgs/CameraInfo`` message as :class:`CameraInfo` (K (3, 3), D, R (3, 3), P (3, 4), pixels)."""
    return CameraInfo(width=int(msg.width), height=int(msg.height), distortion_model=str(msg.distortion_model),
                      K=np.asarray(msg.K, dtype=np.float64).reshape(3, 3), D=np.asarray(msg.D, dtype=np.float64),
                      R=np.asarray(msg.R, dtype=np.float64).reshape(3, 3),
                      P=np.asarray(msg.P, dtype=np.float64).reshape(3, 4))


class SequenceCalibration:
    """Calibration of one bag, read on first use and kept.

    Args:
        bag: the opened bag (camera_info source).
        camchain: Kalibr camchain YAML path or parsed :class:`Camchain` (extrinsics); None: the shipped Rosario one.
    """

    def __init__(self, bag: BagContainer, camchain: Path | str | Camchain | None) -> None:
        self.bag = bag
        self._camchain_arg = camchain

    @cached_property
    def camera_info(self) -> tuple[CameraInfo, CameraInfo]:
        """(left, right) contents of the first camera_info message of each camera."""
        infos = []
        for topic in (L.TOPIC_LEFT_INFO, L.TOPIC_RIGHT_INFO):
            msgs = list(self.bag.messages([topic], limit=1))
            if not msgs:
                raise self.bag.err(f"missing required topic {topic}")
            infos.append(camera_info_from_msg(msgs[0][1]))
        return infos[0], infos[1]

    @cached_property
    def camchain(self) -> Camchain:
        """The parsed camchain (camera–IMU extrinsics T_cam_imu, m)."""
        arg = self._camchain_arg
        if isinstance(arg, Camchain):
            return arg
        return read_camchain(arg if arg is not None else ROSARIO_CAMCHAIN)

    @cached_property
    def rig(self) -> StereoRig:
        """Stereo rig: K, D, R, P and size from the bag's camera_info, extrinsics from the camchain."""
        left, right = self.camera_info
        try:
            return rig_from_camera_info(left, right, self.camchain, source=self.bag.path)
        except CalibrationError as exc:
            raise self.bag.err(exc.problem) from None

    def image_sizes_hw(self) -> dict[str, tuple[int, int]]:
        """``{image topic: (height, width)}`` of both cameras, pixels, from camera_info."""
        left, right = self.camera_info
        return {L.TOPIC_LEFT_IMAGE: (left.height, left.width), L.TOPIC_RIGHT_IMAGE: (right.height, right.width)}
