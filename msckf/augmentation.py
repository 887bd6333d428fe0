"""State augmentation: clone the cam0 pose at an image time and grow the covariance.

Clone pose (msckf.md §1.5): ``R_w_c = R_w_i R_i_c``, ``p_c = p_I + R_w_i p_i_c`` (``p_i_c`` = cam0 origin in the
IMU frame). The 6×21 Jacobian of [δθ_c, δp_c] w.r.t. the IMU error state, in this library's local-error
convention (:mod:`msckf.rotation`)::

    J[0:3, 0:3]   = R_c_i              J[0:3, 15:18] = I
    J[3:6, 0:3]   = −R_w_i [p_i_c]×    J[3:6, 12:15] = I     J[3:6, 18:21] = R_w_i

``J[3:6, 18:21] = R_w_i`` is the upstream fix of PR #116 (it was I). ``J[3:6, 0:3]`` is the first-order term
of ``R̂_w_i Exp(δθ) p_i_c`` (msckf.md §1.5 [derived]); msckf_vio's active line uses ``[R̂_w_i p_i_c]×``, which
differs in sign and frame — tests/test_msckf_augmentation.py checks this block against a numerical Jacobian.
"""

from __future__ import annotations

import numpy as np

from msckf.rotation import skew
from msckf.state import IMU_DIM, CloneStore, ImuState

__all__ = ["clone_pose", "augmentation_jacobian", "augment"]


def clone_pose(state: ImuState) -> tuple[np.ndarray, np.ndarray]:
    """cam0 pose of the current IMU state: (R_w_c (3, 3), p_c (3,) world, m)."""
    return state.R_w_i @ state.R_c_i.T, state.p + state.R_w_i @ state.p_i_c


def augmentation_jacobian(state: ImuState) -> np.ndarray:
    """6×21 Jacobian of the new clone's error [δθ_c, δp_c] w.r.t. the IMU error state."""
    J = np.zeros((6, IMU_DIM))
    J[0:3, 0:3] = state.R_c_i
    J[0:3, 15:18] = np.eye(3)
    J[3:6, 0:3] = -state.R_w_i @ skew(state.p_i_c)
    J[3:6, 12:15] = np.eye(3)
    J[3:6, 18:21] = state.R_w_i
    return J


def augment(state: ImuState, P: np.ndarray, clones: CloneStore) -> np.ndarray:
    """Append a clone of the current cam0 pose (newest) and return the grown covariance (n+6)².

    New rows are ``[J P_II, J P_IC]`` and the corner ``J P_II Jᵀ`` (J touches the IMU block only).
    """
    R_w_c, p_c = clone_pose(state)
    clones.add(state.id, state.time, R_w_c, p_c)
    J = augmentation_jacobian(state)
    n = P.shape[0]
    out = np.empty((n + 6, n + 6))
    out[:n, :n] = P
    JP = J @ P[:IMU_DIM, :]
    out[n:, :n] = JP
    out[:n, n:] = JP.T
    corner = JP[:, :IMU_DIM] @ J.T
    out[n:, n:] = 0.5 * (corner + corner.T)
    return out
