"""Static initialisation (S-MSCKF ``initializeGravityAndBias``) with a check that the start really is static.

From the first N IMU samples (robot standing still): gyro bias = mean angular rate; gravity magnitude =
|mean specific force|; initial orientation = the smallest rotation taking the mean specific force (which
points *up* at rest) onto world +z (``FromTwoVectors(gravity_imu, −g)``). The accelerometer bias stays zero
(as in msckf_vio). Yaw is arbitrary (unobservable), position is the origin.

A start is declared *not static* when, over the window, the angular rate or specific force fluctuates more
than the configured per-axis standard deviations, when the mean rate is larger than a plausible gyro bias,
or when the mean angular rate or specific force differs between the first and last quarter of the window
(turning, starting to accelerate or tilting during part of it).
Motion at constant velocity on a straight, smooth path is indistinguishable from rest for an IMU and cannot
be detected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msckf.errors import MsckfInputError
from msckf.options import InitOptions
from msckf.rotation import from_two_vectors

__all__ = ["NonStaticStartError", "StaticInit", "static_initialize"]


class NonStaticStartError(MsckfInputError):
    """The IMU window used for the static initialisation shows motion (the message says which test failed)."""


@dataclass(frozen=True)
class StaticInit:
    """Result of the static initialisation.

    Attributes:
        R_w_i: (3, 3) initial IMU → world rotation (gravity aligned, yaw arbitrary).
        gyro_bias: (3,) rad/s. gravity_norm: |g| in m/s². t_end: stamp of the last sample used, s.
        gyro_std, acc_std: (3,) per-axis standard deviations over the window (rad/s, m/s²).
        gyro_bias_var: (3,) per-axis variance of ``gyro_bias`` as a measurement, (rad/s)²: the window's sample
            variance of the angular rate over the number of samples (the bias is the window's mean rate).
        duration_s: time spanned by the window, s.
    """

    R_w_i: np.ndarray
    gyro_bias: np.ndarray
    gravity_norm: float
    t_end: float
    gyro_std: np.ndarray
    acc_std: np.ndarray
    gyro_bias_var: np.ndarray
    duration_s: float


def static_initialize(t_s: np.ndarray, gyro: np.ndarray, acc: np.ndarray, options: InitOptions) -> StaticInit:
    """Initialise gravity direction and gyro bias from a window of IMU samples taken at rest.

    Args:
        t_s: (N,) stamps, s. gyro: (N, 3) rad/s, IMU frame. acc: (N, 3) specific force, m/s², IMU frame.
        options: the static-start limits ``init_max_gyro_std``, ``init_max_gyro_mean`` (rad/s),
            ``init_max_acc_std``, ``init_max_acc_drift`` (m/s²), ``init_max_gyro_drift`` (rad/s); see the module
            doc. (The window length ``init_imu_samples`` is the caller's: N = len(gyro).)
    Raises:
        NonStaticStartError: the window shows motion; the message gives the measured values and limits.
    """
    max_gyro_std, max_gyro_mean = options.init_max_gyro_std, options.init_max_gyro_mean
    max_acc_std, max_acc_drift = options.init_max_acc_std, options.init_max_acc_drift
    max_gyro_drift = options.init_max_gyro_drift
    gyro = np.asarray(gyro, dtype=np.float64)
    acc = np.asarray(acc, dtype=np.float64)
    n = len(gyro)
    g_mean = gyro.mean(axis=0)
    a_mean = acc.mean(axis=0)
    g_std = gyro.std(axis=0)
    a_std = acc.std(axis=0)
    q = max(1, n // 4)
    drift = float(np.linalg.norm(acc[-q:].mean(axis=0) - acc[:q].mean(axis=0)))
    g_drift = float(np.linalg.norm(gyro[-q:].mean(axis=0) - gyro[:q].mean(axis=0)))
    problems = []
    if np.max(g_std) > max_gyro_std:
        problems.append(f"angular-rate std {np.max(g_std):.3f} rad/s > {max_gyro_std:g}")
    if np.linalg.norm(g_mean) > max_gyro_mean:
        problems.append(f"mean angular rate {np.linalg.norm(g_mean):.3f} rad/s > {max_gyro_mean:g} "
                        "(rotating, or an implausible gyro bias)")
    if g_drift > max_gyro_drift:
        problems.append(f"mean angular rate changed by {g_drift:.3f} rad/s between the first and last quarter "
                        f"> {max_gyro_drift:g} (turning during the window)")
    if np.max(a_std) > max_acc_std:
        problems.append(f"specific-force std {np.max(a_std):.3f} m/s² > {max_acc_std:g}")
    if drift > max_acc_drift:
        problems.append(f"mean specific force changed by {drift:.3f} m/s² between the first and last quarter "
                        f"> {max_acc_drift:g} (accelerating or tilting)")
    g_norm = float(np.linalg.norm(a_mean))
    if not np.isfinite(g_norm) or not 5.0 < g_norm < 15.0:
        problems.append(f"|mean specific force| = {g_norm:.3f} m/s² is not gravity")
    t_s = np.asarray(t_s, dtype=np.float64)
    if problems:
        raise NonStaticStartError(
            f"the start is not static over the first {n} IMU samples "
            f"(t = {t_s[0]:.3f} … {t_s[-1]:.3f} s): " + "; ".join(problems)
            + ". S-MSCKF's static initialisation needs the robot standing still at the start "
              "(skip the moving part, or raise the init_max_* limits if this is vibration at rest).")
    R_w_i = from_two_vectors(a_mean, np.array([0.0, 0.0, 1.0]))
    g_var_mean = gyro.var(axis=0, ddof=1) / n if n > 1 else np.zeros(3)
    return StaticInit(R_w_i, g_mean, g_norm, float(t_s[-1]), g_std, a_std, g_var_mean, float(t_s[-1] - t_s[0]))
