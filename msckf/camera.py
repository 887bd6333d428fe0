"""Camera model and stereo rig shared by every stage of agrivio.

Conventions (used everywhere in the project):

* A camera frame is the OpenCV optical frame: x right, y down, z forward (along the optical axis), metres.
* ``T_a_b`` is a 4×4 homogeneous transform that maps points expressed in frame *b* into frame *a*:
  ``p_a = T_a_b @ p_b``. So ``T_cam_imu`` maps IMU-frame points into the camera frame (Kalibr's convention).
* Pixels are ``(u, v)`` with ``u`` the column and ``v`` the row; the centre of the top-left pixel is ``(0, 0)``
  (OpenCV convention).
* *Raw* pixels are those of the distorted images the sensor records. *Rectified* pixels are those of the
  undistorted, row-aligned stereo images produced by ``StereoRig.rectify``; depth maps live in the rectified
  left camera frame.
* Distortion is Kalibr ``radtan`` == ROS ``plumb_bob``: coefficients ``(k1, k2, p1, p2[, k3])``.

This module is the one camera type of the project (design.md): the simulator renders with it, the depth stage
rectifies with it, and the VIO projects with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


def _as_points(points: np.ndarray, dim: int) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.shape[-1] != dim:
        raise ValueError(f"expected points of shape (N, {dim}), got {arr.shape}")
    return arr


@dataclass(frozen=True)
class PinholeRadtan:
    """Pinhole camera with radial-tangential distortion.

    Attributes:
        width, height: image size in pixels.
        fx, fy, cx, cy: intrinsics in pixels (raw, distorted image).
        distortion: ``(k1, k2, p1, p2)`` or ``(k1, k2, p1, p2, k3)``; all zeros for an ideal pinhole.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.distortion) not in (4, 5):
            raise ValueError(f"radtan distortion needs 4 or 5 coefficients, got {len(self.distortion)}")
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError("camera size and focal lengths must be positive")

    @property
    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix (pixels)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        """Distortion coefficients as OpenCV expects them, shape (5,) ``(k1, k2, p1, p2, k3)``."""
        d = np.zeros(5)
        d[: len(self.distortion)] = self.distortion
        return d

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels, OpenCV's order."""
        return (self.width, self.height)

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply radtan distortion to normalised image coordinates.

        Args:
            xy: (N, 2) undistorted normalised coordinates ``(X/Z, Y/Z)``.
        Returns:
            (N, 2) distorted normalised coordinates.
        """
        xy = _as_points(xy, 2)
        k1, k2, p1, p2, k3 = self.D
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame 3-D points to raw (distorted) pixels.

        Args:
            points_cam: (N, 3) points in this camera's frame, metres; Z must be > 0.
        Returns:
            (N, 2) raw pixel coordinates ``(u, v)``. Points with Z <= 0 give NaN.
        """
        p = _as_points(points_cam, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        xyd = self.distort_normalized(xy)
        return np.stack([self.fx * xyd[:, 0] + self.cx, self.fy * xyd[:, 1] + self.cy], axis=1)

    def undistort_points(self, pixels: np.ndarray) -> np.ndarray:
        """Raw pixels to undistorted normalised coordinates (iterative inverse of the distortion).

        Args:
            pixels: (N, 2) raw pixel coordinates.
        Returns:
            (N, 2) normalised coordinates ``(X/Z, Y/Z)`` in this camera's frame.
        """
        px = _as_points(pixels, 2)
        if len(px) == 0:
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        out = cv2.undistortPoints(px.reshape(-1, 1, 2), self.K, self.D, None, None, None, criteria)
        return out.reshape(-1, 2).astype(np.float64)

    def unproject(self, pixels: np.ndarray, depth: np.ndarray | float | None = None) -> np.ndarray:
        """Raw pixels to camera-frame rays or points.

        Args:
            pixels: (N, 2) raw pixel coordinates.
            depth: Z in metres per pixel ((N,) or scalar). If None, returns rays with Z = 1.
        Returns:
            (N, 3) points (or Z=1 rays) in this camera's frame.
        """
        xy = self.undistort_points(pixels)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        if depth is None:
            return rays
        return rays * np.asarray(depth, dtype=np.float64).reshape(-1, 1)


def check_transform(T: np.ndarray, name: str) -> np.ndarray:
    """``T`` as a float64 4×4 rigid transform, or ``MsckfInputError`` (a ``ValueError``) naming ``name``."""
    from msckf.errors import MsckfInputError

    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise MsckfInputError(f"{name} must be a finite 4x4 transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or abs(np.linalg.det(R) - 1.0) > 1e-4:
        raise MsckfInputError(f"{name} does not hold a rotation matrix")
    return T


@dataclass(frozen=True)
class StereoRig:
    """A calibrated stereo pair (cam0 = left, cam1 = right) rigidly attached to an IMU.

    Attributes:
        left, right: raw camera models.
        T_right_left: (4, 4) maps left-camera (cam0) points into the right camera (cam1) frame
            (Kalibr ``cam1/T_cn_cnm1``).
        T_left_imu: (4, 4) maps IMU-frame points into the left camera frame (Kalibr ``cam0/T_cam_imu``).
        R_left, R_right: (3, 3) rectification rotations: ``p_rect = R @ p_raw_cam`` (ROS ``camera_info.R``).
        P_left, P_right: (3, 4) rectified projection matrices (ROS ``camera_info.P``); ``P_right[0, 3] =
            -fx_rect * baseline``.

    Build it with :meth:`from_extrinsics` (rectification computed by ``cv2.stereoRectify``) or pass R/P read
    from ``camera_info`` directly.
    """

    left: PinholeRadtan
    right: PinholeRadtan
    T_right_left: np.ndarray
    T_left_imu: np.ndarray
    R_left: np.ndarray
    R_right: np.ndarray
    P_left: np.ndarray
    P_right: np.ndarray
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("T_right_left", "T_left_imu"):
            object.__setattr__(self, name, check_transform(getattr(self, name), name))
        for name, shape in (("R_left", (3, 3)), ("R_right", (3, 3)), ("P_left", (3, 4)), ("P_right", (3, 4))):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != shape:
                raise ValueError(f"{name} must be {shape}, got {arr.shape}")
            object.__setattr__(self, name, arr)
        if self.P_right[0, 3] >= 0:
            raise ValueError("P_right[0, 3] must be -fx * baseline < 0 (right camera to the right of the left)")

    @classmethod
    def from_extrinsics(
        cls,
        left: PinholeRadtan,
        right: PinholeRadtan,
        T_right_left: np.ndarray,
        T_left_imu: np.ndarray,
        alpha: float = 0.0,
    ) -> StereoRig:
        """Compute the rectification with ``cv2.stereoRectify`` (``CALIB_ZERO_DISPARITY``), as the Rosario bags do.

        Args:
            alpha: OpenCV free-scaling parameter; Rosario bags since 2019-03 use 0 (only valid pixels kept).
        """
        T = check_transform(T_right_left, "T_right_left")
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            left.K, left.D, right.K, right.D, left.size,
            T[:3, :3].copy(), T[:3, 3].reshape(3, 1).copy(),  # OpenCV 5 rejects a 1-D T
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha,
        )
        return cls(left, right, T, T_left_imu, R1, R2, P1, P2)

    # ---- rectified geometry -------------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        """Rectified focal length in pixels (same for both rectified cameras)."""
        return float(self.P_left[0, 0])

    @property
    def cx(self) -> float:
        return float(self.P_left[0, 2])

    @property
    def cy(self) -> float:
        return float(self.P_left[1, 2])

    @property
    def baseline(self) -> float:
        """Rectified baseline in metres, ``-P_right[0, 3] / P_right[0, 0]``."""
        return float(-self.P_right[0, 3] / self.P_right[0, 0])

    @property
    def K_rect(self) -> np.ndarray:
        """3×3 intrinsics of the rectified left image."""
        return self.P_left[:, :3].copy()

    @property
    def T_rect_imu(self) -> np.ndarray:
        """(4, 4) maps IMU-frame points into the rectified left camera frame."""
        T = np.eye(4)
        T[:3, :3] = self.R_left
        return T @ self.T_left_imu

    @property
    def T_right_imu(self) -> np.ndarray:
        """(4, 4) maps IMU-frame points into the (raw) right camera frame."""
        return self.T_right_left @ self.T_left_imu

    def depth_from_disparity(self, disparity: np.ndarray) -> np.ndarray:
        """Rectified disparity (pixels, > 0) to depth Z in metres; non-positive disparity gives NaN."""
        d = np.asarray(disparity, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.fx * self.baseline / d
        return np.where(d > 0, z, np.nan)

    def disparity_from_depth(self, depth: np.ndarray) -> np.ndarray:
        """Depth Z (metres) to rectified disparity in pixels: ``u_left - u_right = fx * b / Z``."""
        return self.fx * self.baseline / np.asarray(depth, dtype=np.float64)

    # ---- pixel conversions ----------------------------------------------------------------------------------
    def rectify_left_pixels(self, raw_pixels: np.ndarray) -> np.ndarray:
        """Raw left pixels (N, 2) to rectified left pixels (N, 2): undistort, then :meth:`rectify_left_normalised`."""
        px = _as_points(raw_pixels, 2)
        if len(px) == 0:
            return np.zeros((0, 2))
        return self.rectify_left_normalised(self.left.undistort_points(px))

    def rectify_left_normalised(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted raw-left normalised coordinates ``(X/Z, Y/Z)`` (N, 2) to rectified left pixels (N, 2).

        The rays ``(x, y, 1)`` go through the one homography ``K_rect R_left``; the front end uses this directly
        on its tracks (already undistorted), :meth:`rectify_left_pixels` after undistorting raw pixels.
        """
        xy = _as_points(xy, 2)
        uvw = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ (self.K_rect @ self.R_left).T
        return uvw[:, :2] / uvw[:, 2:3]

    def rectified_left_to_raw(self, rect_pixels: np.ndarray) -> np.ndarray:
        """Rectified left pixels (N, 2) to raw (distorted) left pixels (N, 2)."""
        px = _as_points(rect_pixels, 2)
        rays_rect = np.concatenate(
            [(px[:, :1] - self.cx) / self.fx, (px[:, 1:2] - self.P_left[1, 2]) / self.P_left[1, 1],
             np.ones((len(px), 1))], axis=1)
        rays_raw = rays_rect @ self.R_left  # R^T applied to each row vector
        return self.left.project(rays_raw)

    def project_rectified(self, points_rect: np.ndarray) -> np.ndarray:
        """Points in the rectified left frame (N, 3) to rectified left pixels (N, 2)."""
        p = _as_points(points_rect, 3)
        uvw = p @ self.P_left[:, :3].T
        return uvw[:, :2] / uvw[:, 2:3]

    def unproject_rectified(self, rect_pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Rectified left pixels (N, 2) with depth Z (N,) metres to points in the rectified left frame (N, 3)."""
        px = _as_points(rect_pixels, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        x = (px[:, 0] - self.cx) / self.fx * z
        y = (px[:, 1] - self.cy) / self.P_left[1, 1] * z
        return np.stack([x, y, z], axis=1)

    # ---- images ---------------------------------------------------------------------------------------------
    def _maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if "maps" not in self._cache:
            size = self.left.size
            l1, l2 = cv2.initUndistortRectifyMap(self.left.K, self.left.D, self.R_left, self.P_left, size, cv2.CV_16SC2)
            r1, r2 = cv2.initUndistortRectifyMap(self.right.K, self.right.D, self.R_right, self.P_right, size,
                                                 cv2.CV_16SC2)
            self._cache["maps"] = (l1, l2, r1, r2)
        return self._cache["maps"]

    def rectify(self, left_image: np.ndarray, right_image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistort and rectify a raw stereo pair (grey or BGR, H×W[×3]) into row-aligned images."""
        expected = (self.left.height, self.left.width)
        for name, img in (("left", left_image), ("right", right_image)):
            if img.shape[:2] != expected:
                raise ValueError(f"{name} image is {img.shape[1]}x{img.shape[0]}, calibration expects "
                                 f"{expected[1]}x{expected[0]}")
        l1, l2, r1, r2 = self._maps()
        return (cv2.remap(left_image, l1, l2, cv2.INTER_LINEAR),
                cv2.remap(right_image, r1, r2, cv2.INTER_LINEAR))
