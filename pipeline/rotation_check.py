"""Is the rotation ATE of a position-based alignment determined? (nearly straight paths: roll is not)

An SE(3)/Sim(3) alignment fitted on positions only fixes the rotation about the direction of travel through the
path's spread *across* that direction. On a nearly straight path that spread is a few centimetres against
centimetre-level position noise, so the fitted roll is noise, and every estimated orientation inherits it: the
rotation ATE then measures the alignment, not the estimate (seen: 4.5–14.7° after SE(3) where a pos+yaw
alignment, which takes roll and pitch from gravity, gives 0.3–0.4°).

:func:`roll_uncertainty_deg` estimates the alignment's roll uncertainty as the translational ATE RMS (the noise
left after alignment) over the RMS spread of the reference positions perpendicular to their principal axis, in
degrees. Above :data:`MAX_ROLL_UNCERTAINTY_DEG` the rotation ATE of that alignment is not reported as such.
"""

from __future__ import annotations

import math

import numpy as np

#: Largest roll uncertainty (degrees) of a position-only alignment for which its rotation ATE is reported.
MAX_ROLL_UNCERTAINTY_DEG = 1.0


def roll_uncertainty_deg(ref_positions_m: np.ndarray, ate_rmse_m: float) -> float:
    """Roll uncertainty (deg) of a position fit: ``ate_rmse_m`` / RMS spread across the principal axis.

    Args:
        ref_positions_m: (N, 3) associated reference positions, metres.
        ate_rmse_m: translational ATE RMSE after the alignment, metres.
    Returns:
        degrees; ``inf`` when the positions have no spread across their principal axis.
    """
    p = np.asarray(ref_positions_m, dtype=np.float64).reshape(-1, 3)
    if len(p) < 3:
        return math.inf
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    across = float(np.sqrt((s[1] ** 2 + s[2] ** 2) / len(p)))  # RMS distance from the principal axis
    if across <= 0.0:
        return math.inf
    return math.degrees(math.atan2(max(float(ate_rmse_m), 1e-9), across))


def rotation_is_determined(method: str, ref_positions_m: np.ndarray, ate_rmse_m: float) -> bool:
    """False for a position-only SE(3)/Sim(3) fit whose roll uncertainty exceeds the limit (posyaw/none: True)."""
    if method not in ("se3", "sim3"):
        return True
    return roll_uncertainty_deg(ref_positions_m, ate_rmse_m) <= MAX_ROLL_UNCERTAINTY_DEG


__all__ = ["MAX_ROLL_UNCERTAINTY_DEG", "roll_uncertainty_deg", "rotation_is_determined"]
