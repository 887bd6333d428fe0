"""The camera/IMU head on the robot: base_link → IMU mounting and the camera poses it implies.

``T_base_imu`` is built so that the left camera's optical axis points forward (base +x), pitched ``tilt_deg``
below the base's horizontal plane, with image x to the robot's right; the IMU then sits where the Kalibr
``cam0/T_cam_imu`` of the rig puts it relative to the camera (its axes x ≈ up, y ≈ right, z ≈ forward).
"""

from __future__ import annotations

import numpy as np

from msckf.camera import StereoRig


def base_to_camera_rotation(tilt_deg: float) -> np.ndarray:
    """R_base_cam (3, 3) of a camera looking along base +x, pitched ``tilt_deg`` down, image x to the right."""
    th = np.radians(tilt_deg)
    z_c = np.array([np.cos(th), 0.0, -np.sin(th)])
    x_c = np.array([0.0, -1.0, 0.0])
    y_c = np.cross(z_c, x_c)
    return np.stack([x_c, y_c, z_c], axis=1)


def mount_transform(rig: StereoRig, tilt_deg: float, imu_position_m: tuple[float, float, float]) -> np.ndarray:
    """T_base_imu (4, 4): maps IMU-frame points into base_link (metres)."""
    R_base_cam = base_to_camera_rotation(tilt_deg)
    T = np.eye(4)
    T[:3, :3] = R_base_cam @ rig.T_left_imu[:3, :3]
    T[:3, 3] = imu_position_m
    return T


def _rect(T_world_raw: np.ndarray, R_rect: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R_rect).T  # p_raw = R_rect^T p_rect
    return T_world_raw @ T


def camera_poses(T_world_imu: np.ndarray, rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """(T_world_rectleft, T_world_rectright): the rectified camera frames of both cameras in the world frame."""
    T_left = T_world_imu @ np.linalg.inv(rig.T_left_imu)
    T_right = T_world_imu @ np.linalg.inv(rig.T_right_imu)
    return _rect(T_left, rig.R_left), _rect(T_right, rig.R_right)
