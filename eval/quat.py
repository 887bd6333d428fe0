"""Vectorised unit-quaternion helpers in scipy's ``xyzw`` order (faster than ``Rotation`` products on large
batches; checked against scipy in the tests).

All functions take (N, 4) or (4,) arrays and broadcast.
"""

from __future__ import annotations

import numpy as np

__all__ = ["qmul", "qconj", "qrotate", "qangle_deg"]


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` (rotation ``R(a)·R(b)``), xyzw."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def qconj(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse rotation of a unit quaternion), xyzw."""
    out = np.array(q, dtype=np.float64, copy=True)
    out[..., :3] *= -1.0
    return out


def qrotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (…, 3) by unit quaternions ``q`` (…, 4): ``R(q)·v``."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def qangle_deg(q: np.ndarray) -> np.ndarray:
    """Rotation angle of unit quaternions, degrees in [0, 180]."""
    q = np.asarray(q, dtype=np.float64)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3])))
