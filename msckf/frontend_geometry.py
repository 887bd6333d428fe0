"""Geometry of the front end: gyro-predicted inter-frame rotation, epipolar checks and 2-point RANSAC.

All point arrays are ``(N, 2)`` float64 undistorted normalised coordinates ``(X/Z, Y/Z)`` of one camera unless
stated. Rotations are 3×3 matrices; ``R_c_p`` maps vectors expressed in the *previous* camera frame into the
*current* camera frame (S-MSCKF's ``R_p_c``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from msckf.rotation import skew


class GyroBuffer:
    """Buffered IMU gyro samples and the rotation they integrate to between two image times.

    Samples are IMU-frame angular rates (rad/s) with stamps in seconds; they must arrive in time order. The
    integration between ``t0`` and ``t1`` uses the mid-point rate of each pair of consecutive samples over the
    part of their interval inside ``[t0, t1]``; before the first / after the last sample the nearest sample's
    rate is held. With no sample at all the rotation is the identity. (S-MSCKF uses the plain mean of the rates
    between the two images; this is the same for a constant rate and more accurate otherwise.)
    """

    def __init__(self) -> None:
        self._t: list[float] = []
        self._w: list[np.ndarray] = []

    def add(self, t_s: float, gyro_rad_s: np.ndarray) -> None:
        w = np.asarray(gyro_rad_s, dtype=np.float64).reshape(3)
        t = float(t_s)
        if self._t and t < self._t[-1]:
            raise ValueError(f"IMU stamp {t:.6f} s is earlier than the previous one ({self._t[-1]:.6f} s)")
        self._t.append(t)
        self._w.append(w)

    def __len__(self) -> int:
        return len(self._t)

    def rotation_imu(self, t0: float, t1: float) -> np.ndarray:
        """``R_i0_i1``: orientation of the IMU frame at ``t1`` relative to the IMU frame at ``t0`` (3×3).

        ``R_i0_i1`` maps vectors in the IMU frame at ``t1`` into the IMU frame at ``t0``.
        """
        if not self._t or t1 <= t0:
            return np.eye(3)
        t = np.asarray(self._t)
        w = np.asarray(self._w)
        # Extend with held end values, then clip the piecewise-linear rate to [t0, t1].
        t = np.concatenate([[min(t0, t[0])], t, [max(t1, t[-1])]])
        w = np.concatenate([w[:1], w, w[-1:]])
        lo = np.clip(t[:-1], t0, t1)
        hi = np.clip(t[1:], t0, t1)
        dt = hi - lo
        keep = dt > 0
        if not np.any(keep):
            return np.eye(3)
        # Rate at the mid-point of each clipped sub-interval (linear interpolation of the samples).
        span = t[1:] - t[:-1]
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(span > 0, ((lo + hi) / 2 - t[:-1]) / span, 0.5)
        w_mid = w[:-1] + a[:, None] * (w[1:] - w[:-1])
        rotvecs = (w_mid * dt[:, None])[keep]
        R = np.eye(3)
        for Rk in Rotation.from_rotvec(rotvecs).as_matrix():
            R = R @ Rk
        return R

    def drop_before(self, t_s: float) -> None:
        """Forget samples older than the last one at or before ``t_s`` (that one is kept for interpolation)."""
        t = np.asarray(self._t)
        k = int(np.searchsorted(t, t_s, side="right")) - 1
        if k > 0:
            del self._t[:k]
            del self._w[:k]


def camera_rotation(R_i0_i1: np.ndarray, R_cam_imu: np.ndarray) -> np.ndarray:
    """Inter-frame rotation in a camera rigidly attached to the IMU.

    Args:
        R_i0_i1: (3, 3) IMU orientation at the current frame relative to the previous one (see
            :meth:`GyroBuffer.rotation_imu`).
        R_cam_imu: (3, 3) rotation part of ``T_cam_imu``.
    Returns:
        (3, 3) ``R_c_p`` mapping previous-camera-frame vectors into the current camera frame.
    """
    R_cp_cc = R_cam_imu @ R_i0_i1 @ R_cam_imu.T
    return R_cp_cc.T


def rotate_normalised(xy: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Apply the infinite homography: rotate the rays ``(x, y, 1)`` by ``R`` and renormalise to Z = 1.

    Rays that end up behind the camera give NaN.
    """
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        out = rays[:, :2] / rays[:, 2:3]
    out[rays[:, 2] <= 1e-9] = np.nan
    return out


def epipolar_distance(xy0: np.ndarray, xy1: np.ndarray, R_1_0: np.ndarray, t_1_0: np.ndarray) -> np.ndarray:
    """Distance of each camera-1 point to the epipolar line of its camera-0 point (normalised units).

    With ``p1 = R_1_0 p0 + t_1_0`` the essential matrix is ``E = [t]× R`` and the line is ``l = E x0``; the
    distance is ``|x1ᵀ l| / sqrt(l_x² + l_y²)`` (the true dot product, not uoip's element-wise slip).

    Args:
        xy0, xy1: (N, 2) normalised coordinates in camera 0 and camera 1.
        R_1_0, t_1_0: rotation (3, 3) and translation (3,) mapping camera-0 points into camera 1.
    Returns:
        (N,) distances in normalised image units of camera 1 (multiply by the focal length for pixels).
    """
    E = skew(np.asarray(t_1_0, dtype=np.float64)) @ R_1_0
    x0 = np.concatenate([xy0, np.ones((len(xy0), 1))], axis=1)
    lines = x0 @ E.T
    num = np.abs(np.sum(lines[:, :2] * xy1, axis=1) + lines[:, 2])
    return num / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)


def triangulated_depths(xy0: np.ndarray, xy1: np.ndarray, R_1_0: np.ndarray,
                        t_1_0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depths of a two-view correspondence by least squares on ``z1 x1 = z0 R x0 + t``.

    Returns:
        ``(z0, z1)``: (N,) depths (metres if ``t`` is in metres) along the rays in camera 0 and camera 1.
        A near-parallel pair gives a large or non-finite depth.
    """
    n = len(xy0)
    x0 = np.concatenate([xy0, np.ones((n, 1))], axis=1)
    x1 = np.concatenate([xy1, np.ones((n, 1))], axis=1)
    a = x0 @ R_1_0.T          # z0 * a - z1 * x1 = -t
    b = -x1
    # Normal equations of the 3×2 system [a b] [z0 z1]ᵀ = -t, solved in closed form for every point.
    aa = np.sum(a * a, axis=1)
    bb = np.sum(b * b, axis=1)
    ab = np.sum(a * b, axis=1)
    at = -(a @ t_1_0)
    bt = -(b @ t_1_0)
    det = aa * bb - ab * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        z0 = (bb * at - ab * bt) / det
        z1 = (aa * bt - ab * at) / det
    return z0, z1


def ransac_iterations(success_probability: float, inlier_ratio: float) -> int:
    """Hypotheses a 2-point RANSAC needs: ``ceil(log(1 - p) / log(1 - r²))``."""
    return max(1, int(np.ceil(np.log(1.0 - success_probability) / np.log(1.0 - inlier_ratio ** 2))))


def two_point_ransac(
    xy_prev: np.ndarray,
    xy_curr: np.ndarray,
    R_c_p: np.ndarray,
    focal_px: float,
    threshold_px: float,
    rng: np.random.Generator,
    *,
    iterations: int,
    max_motion_px: float,
    min_inlier_fraction: float,
    degenerate_motion_px: float,
) -> np.ndarray:
    """2-point RANSAC on consecutive frames of one camera, with the rotation known from the gyro.

    After compensating the rotation (``x'_p = R_c_p x_p``) the epipolar constraint reduces to ``t · (x'_p × x_c)
    = 0`` for the unknown translation direction ``t``, so two correspondences fix ``t = c_a × c_b`` with
    ``c = x'_p × x_c``. Following S-MSCKF: motions above ``max_motion_px`` are outliers up front; fewer than 3
    remaining → every point is an outlier; a mean motion below ``degenerate_motion_px`` means no translation and
    the inliers are the points that moved less than ``threshold_px``; otherwise ``iterations`` hypotheses are
    drawn (pairs of distinct points), a hypothesis needs ``min_inlier_fraction`` of all points, the one with most
    inliers wins and is refitted on its inliers (least squares, smallest singular vector), and the final inliers
    are those of the refitted model. Unlike S-MSCKF's algebraic residual, the error is the point-to-epipolar-line
    distance in the current image (pixels = normalised × ``focal_px``).

    Args:
        xy_prev, xy_curr: (N, 2) normalised coordinates of the same features in the previous and current frame.
        R_c_p: (3, 3) rotation previous → current camera frame (from the gyro).
        focal_px: focal length used to turn pixel thresholds into normalised units.
        threshold_px: inlier threshold, pixels.
        rng: the caller's seeded generator (the only randomness).
    Returns:
        (N,) bool inlier mask.
    """
    n = len(xy_prev)
    inliers = np.zeros(n, dtype=bool)
    if n == 0:
        return inliers
    unit = 1.0 / focal_px
    p = rotate_normalised(xy_prev, R_c_p)
    motion = np.hypot(*(p - xy_curr).T)
    candidate = np.isfinite(motion) & (motion <= max_motion_px * unit)
    idx = np.flatnonzero(candidate)
    if len(idx) < 3:
        return inliers
    if motion[idx].mean() < degenerate_motion_px * unit:
        inliers[idx] = motion[idx] < threshold_px * unit
        return inliers

    P = np.concatenate([p[idx], np.ones((len(idx), 1))], axis=1)
    C = np.cross(P, np.concatenate([xy_curr[idx], np.ones((len(idx), 1))], axis=1))

    def line_errors(T: np.ndarray) -> np.ndarray:
        """(M, K) distances of the current points to the epipolar lines ``t × x'_p`` of K hypotheses."""
        num = np.abs(C @ T.T)
        lx = P[:, 1:2] * T[None, :, 2] - P[:, 2:3] * T[None, :, 1]   # (t × p) = -(p × t); sign irrelevant
        ly = P[:, 2:3] * T[None, :, 0] - P[:, 0:1] * T[None, :, 2]
        return num / np.maximum(np.hypot(lx, ly), 1e-12)

    m = len(idx)
    first = rng.integers(0, m, size=iterations)
    second = (first + rng.integers(1, m, size=iterations)) % m
    T = np.cross(C[first], C[second])
    norms = np.linalg.norm(T, axis=1)
    valid = norms > 1e-12
    if not np.any(valid):
        return inliers
    T = T[valid] / norms[valid, None]
    errors = line_errors(T)
    thr = threshold_px * unit
    counts = np.sum(errors < thr, axis=0)
    mean_err = np.array([errors[errors[:, k] < thr, k].mean() if counts[k] else np.inf for k in range(len(T))])
    best = int(np.lexsort((mean_err, -counts))[0])
    if counts[best] < min_inlier_fraction * n:
        return inliers
    best_in = errors[:, best] < thr
    # Refit: t is the right singular vector of the inliers' C with the smallest singular value.
    _, _, vt = np.linalg.svd(C[best_in], full_matrices=False)
    refit_in = line_errors(vt[-1][None, :])[:, 0] < thr
    final = refit_in if refit_in.sum() >= best_in.sum() else best_in
    inliers[idx[final]] = True
    return inliers
