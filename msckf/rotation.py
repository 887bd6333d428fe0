"""Rotation conventions of the MSCKF filter — the ONE place they are stated.

Storage
    The filter stores every orientation as a 3×3 rotation matrix (float64), never as a quaternion:

    * ``R_w_i``  — IMU orientation: maps IMU-frame vectors into the world frame (``v_w = R_w_i @ v_i``).
    * ``R_w_c``  — camera clone orientation: maps cam0-frame vectors into the world frame.
    * ``R_c_i``  — cam0–IMU extrinsic rotation: maps IMU-frame vectors into cam0 (Kalibr ``T_cam_imu``).

    World frame: gravity aligned, z up, gravity vector ``g_w = (0, 0, -|g|)``.

Error (perturbation) convention
    All rotation errors are *local* (right) perturbations, 3-vectors in radians::

        R_w_i = R̂_w_i · Exp(δθ)          (δθ in the IMU frame)
        R_w_c = R̂_w_c · Exp(δθ_c)        (δθ_c in the cam0 frame)
        R_c_i = Exp(-δθ_e) · R̂_c_i       (equivalently R_i_c = R̂_i_c · Exp(δθ_e))

    This is *exactly* S-MSCKF's convention written with matrices: S-MSCKF stores the JPL quaternion
    q_I_G (world→IMU, Trawny & Roumeliotis) with the left-multiplicative error ``q = δq(δθ) ⊗ q̂``, i.e.
    ``C(q) = (I − [δθ]×) Ĉ``; transposing gives ``R_w_i = R̂_w_i (I + [δθ]×)``. Hence every Jacobian of
    msckf_vio (F, G, Φ, H, OC projections) carries over unchanged, with their ``C(q)`` = our ``R_w_i.T``.
    (Numerically, a JPL quaternion of world→IMU equals the Hamilton quaternion of IMU→world, so the xyzw
    quaternion leaving the library — Hamilton, ``scipy`` order — equals S-MSCKF's stored orientation.)

Quaternions at the boundary
    Quaternions cross the library boundary only as Hamilton ``xyzw`` (``scipy.spatial.transform.Rotation``
    order), e.g. ``PoseEstimate.q_world_imu_xyzw`` is the Hamilton quaternion of ``R_w_i``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "skew", "so3_exp", "so3_exp3", "so3_log", "rotation_angle", "orthonormalize", "from_two_vectors",
    "matrix_to_quat_xyzw", "quat_xyzw_to_matrix",
]


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric (cross-product) matrix ``[v]×`` — the one implementation in the library.

    Args:
        v: (3,) vector or (..., 3) vectors.
    Returns:
        (3, 3) or (..., 3, 3) matrices with ``[v]× @ w == cross(v, w)``. A single 3-vector takes a fast path
        (one small ``np.array``) for per-sample code; the values are the same either way.
    """
    v = np.asarray(v, dtype=np.float64)
    if v.shape == (3,):
        x, y, z = float(v[0]), float(v[1]), float(v[2])
        return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def so3_exp3(phi: np.ndarray) -> np.ndarray:
    """``Exp(φ)`` of a single rotation vector (fast path of :func:`so3_exp` for per-sample code)."""
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    t2 = x * x + y * y + z * z
    if t2 < 1e-16:
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        t = math.sqrt(t2)
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    return np.array([[1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z],
                     [a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z],
                     [-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)]])


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vector (radians) to rotation matrix, ``Exp(φ) = exp([φ]×)``.

    Args:
        phi: (3,) or (N, 3) rotation vectors in radians.
    Returns:
        (3, 3) or (N, 3, 3) rotation matrices. Uses the 2nd-order Taylor series below 1e-8 rad.
    """
    phi = np.asarray(phi, dtype=np.float64)
    single = phi.ndim == 1
    p = phi.reshape(-1, 3)
    theta = np.linalg.norm(p, axis=1)
    K = skew(p)
    K2 = K @ K
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    R = np.eye(3) + a[:, None, None] * K + b[:, None, None] * K2
    return R[0] if single else R


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix to rotation vector (radians), inverse of :func:`so3_exp` (angle in [0, π])."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def rotation_angle(R: np.ndarray) -> float:
    """Angle (radians, [0, π]) of a rotation matrix, robust to round-off."""
    c = (np.trace(R) - 1.0) * 0.5
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD projection); keeps long integrations on SO(3)."""
    U, _, Vt = np.linalg.svd(R)
    Rn = U @ Vt
    if np.linalg.det(Rn) < 0:
        U[:, -1] *= -1
        Rn = U @ Vt
    return Rn


def from_two_vectors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation R with ``R @ a/|a| == b/|b|`` (Eigen's ``FromTwoVectors``).

    Args:
        a, b: (3,) non-zero vectors.
    Returns:
        (3, 3) rotation matrix.
    """
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite vectors: rotate by π about any axis orthogonal to a.
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return so3_exp(np.pi * axis / np.linalg.norm(axis))
    return so3_exp(v / s * np.arctan2(s, c))


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrix to the Hamilton quaternion, scalar last ``(x, y, z, w)``, with ``w >= 0``."""
    q = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    return q if q[3] >= 0 else -q


def quat_xyzw_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Hamilton quaternion ``(x, y, z, w)`` to a rotation matrix."""
    return Rotation.from_quat(np.asarray(q_xyzw, dtype=np.float64)).as_matrix()
