"""The simulator's true IMU poses in a VIO run's own world frame, for the NEES of oracle runs (issue 17).

A VIO starts in a world frame of its own (gravity-aligned, its yaw and origin where it initialised), so the true
poses (ENU) are expressed in it by the one yaw + translation that maps the true pose at the run's first estimate
onto that estimate: the four directions a VIO cannot observe. Roll and pitch are not aligned (they are observable:
their initial error counts), and nothing is fitted afterwards, so the position and orientation errors grow as the
filter drifts and are compared with the covariance the filter reports (``msckf.filter.MsckfFilter.pose_nees``;
:func:`tilt_yaw_nees` splits the orientation part). :func:`imu_without_true_acc_bias` is the oracle IMU input of the
``--true-acc-bias`` diagnostic.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from msckf.rotation import so3_log

__all__ = ["TrueImuPoses", "AnchoredTruth", "tilt_yaw_nees", "imu_without_true_acc_bias", "PINNED_ACC_BIAS"]

#: MSCKF overrides for runs fed :func:`imu_without_true_acc_bias`: the filter starts at the (now zero) true bias
#: and keeps it there (initial variance 0, random walk 1e-9 m/s³/√Hz).
PINNED_ACC_BIAS: dict[str, float] = {"acc_bias_cov": 0.0, "acc_bias_noise": 1e-9}


@dataclass(frozen=True)
class TrueImuPoses:
    """True IMU poses of a simulated sequence, interpolated in time.

    Attributes:
        t_s: (N,) increasing stamps, s (the bag's clock).
        p_E: (N, 3) IMU position in ENU, m.
        q_E_xyzw: (N, 4) IMU orientation (maps IMU-frame vectors into ENU), x, y, z, w.
    """

    t_s: np.ndarray
    p_E: np.ndarray
    q_E_xyzw: np.ndarray

    @classmethod
    def from_truth(cls, truth: Mapping[str, np.ndarray]) -> TrueImuPoses:
        """From a simulated sequence's truth arrays (``imu_stamp_ns``, ``p_E``, ``q_E_xyzw``)."""
        return cls(np.asarray(truth["imu_stamp_ns"], dtype=np.float64) / 1e9,
                   np.asarray(truth["p_E"], dtype=np.float64), np.asarray(truth["q_E_xyzw"], dtype=np.float64))

    def covers(self, t_s: float) -> bool:
        """Whether ``t_s`` lies within the truth's time span."""
        return bool(self.t_s[0] <= t_s <= self.t_s[-1])

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(R_E_I (3, 3), p_E (3,)) at ``t_s`` (linear in position, spherical-linear in orientation).

        Raises:
            ValueError: ``t_s`` outside the truth's time span.
        """
        if not self.covers(t_s):
            raise ValueError(f"t = {t_s:.6f} s is outside the truth's span {self.t_s[0]:.3f}–{self.t_s[-1]:.3f} s")
        return self._slerp([t_s]).as_matrix()[0], self.positions(np.array([t_s]))[0]

    def positions(self, t_s: np.ndarray) -> np.ndarray:
        """(M, 3) p_E (m) at the (M,) stamps ``t_s`` (s), linear in time; stamps outside the span get the end values
        (callers keep to :meth:`covers`)."""
        return np.stack([np.interp(t_s, self.t_s, self.p_E[:, k]) for k in range(3)], axis=1)

    @cached_property
    def _slerp(self) -> Slerp:
        """Spherical-linear interpolation of the orientations over all samples (built once)."""
        return Slerp(self.t_s, Rotation.from_quat(self.q_E_xyzw))


class AnchoredTruth:
    """True IMU poses in one run's world frame W: the yaw and origin of W fixed at the run's first estimate.

    ``truth(t_s, R_w_i_est, p_w_est)`` returns ``(R_w_i_true, p_w_true)``; the first call fixes the anchor
    (``R_W_E`` a rotation about the vertical, ``t_W_E`` a translation, m) so that the true pose at that time has the
    estimate's yaw and position.
    """

    def __init__(self, poses: TrueImuPoses) -> None:
        self.poses = poses
        self._R_W_E: np.ndarray | None = None
        self._t_W_E = np.zeros(3)

    def __call__(self, t_s: float, R_w_i_est: np.ndarray, p_w_est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R_E, p_E = self.poses.at(t_s)
        if self._R_W_E is None:
            M = np.asarray(R_w_i_est) @ R_E.T
            self._R_W_E = Rotation.from_rotvec([0.0, 0.0, np.arctan2(M[1, 0], M[0, 0])]).as_matrix()
            self._t_W_E = np.asarray(p_w_est, dtype=np.float64) - self._R_W_E @ p_E
        return self._R_W_E @ R_E, self._R_W_E @ p_E + self._t_W_E


def tilt_yaw_nees(R_w_i_est: np.ndarray, P_theta: np.ndarray, R_w_i_true: np.ndarray) -> tuple[float, float]:
    """The orientation NEES split into tilt (roll / pitch against gravity) and yaw.

    ``R_w_i_est`` / ``R_w_i_true`` (3, 3) map IMU-frame vectors into the run's world frame (z up); ``P_theta`` (3, 3)
    the covariance of the filter's local orientation error θ (rad², ``R_true = R_est Exp(θ)``, IMU frame). The error
    and its covariance are turned into the world frame (``R_est θ``): the x / y part is the tilt, χ²(2) for a
    consistent filter (mean 2), the z part the yaw, χ²(1) (mean 1). A VIO observes tilt only through the
    accelerometer, where a tilt error can hide behind an accelerometer-bias error while the robot drives straight
    and level; yaw it cannot observe at all. NaN where the block is singular.
    """
    R_est = np.asarray(R_w_i_est, dtype=np.float64)
    e_w = R_est @ so3_log(R_est.T @ np.asarray(R_w_i_true, dtype=np.float64))   # the error pose_nees tests
    C_w = R_est @ np.asarray(P_theta) @ R_est.T
    try:
        tilt = float(e_w[:2] @ np.linalg.solve(C_w[:2, :2], e_w[:2]))
    except np.linalg.LinAlgError:
        tilt = float("nan")
    yaw = float(e_w[2] ** 2 / C_w[2, 2]) if C_w[2, 2] > 0 else float("nan")
    return tilt, yaw


def imu_without_true_acc_bias(imu: np.ndarray, truth: Mapping[str, np.ndarray]) -> np.ndarray:
    """A copy of the IMU array ``(N, 7)`` (t s, gyro rad/s ×3, accel m/s² ×3) with the simulator's true
    accelerometer bias (``truth["bias_accel"]`` at ``truth["imu_stamp_ns"]``, linearly interpolated, m/s², IMU
    frame) subtracted: an oracle input for runs configured with :data:`PINNED_ACC_BIAS`, which separates what the
    accelerometer-bias estimate costs from what the depth costs (noise and vibration stay in the samples)."""
    out = np.array(imu, dtype=np.float64, copy=True)
    t_true = np.asarray(truth["imu_stamp_ns"], dtype=np.float64) / 1e9
    bias = np.asarray(truth["bias_accel"], dtype=np.float64)
    for j in range(3):
        out[:, 4 + j] -= np.interp(out[:, 0], t_true, bias[:, j])
    return out
