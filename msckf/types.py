"""Data passed between the MSCKF front end and back end (plain arrays, frozen dataclasses).

Frames: ``cam0`` is the raw left camera, ``cam1`` the raw right camera (OpenCV optical frames). Normalised
coordinates are undistorted ``(X/Z, Y/Z)`` in that camera's frame — what S-MSCKF's image processor publishes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from enum import IntEnum
from typing import Any

import numpy as np


class DepthSource(IntEnum):
    """Where a feature's second (right-camera) observation comes from."""

    MONO = 0          # left image only: no right observation, no depth
    STEREO_MATCH = 1  # KLT left→right stereo matching (variant `stereo`)
    DEPTH_MAP = 2     # depth read from a depth map, turned into a right observation (variants `depth-*`)


@dataclass(frozen=True)
class FeatureObservations:
    """All features observed in one stereo frame.

    Attributes:
        stamp_s: image time in seconds (bag clock).
        ids: (N,) int64 feature track ids, unique within the frame, stable across frames of one track.
        cam0_xy: (N, 2) normalised undistorted coordinates in cam0.
        cam1_xy: (N, 2) normalised undistorted coordinates in cam1; NaN rows where ``source == MONO``.
        depth_m: (N,) depth Z in the cam0 frame in metres from a depth map; NaN where not available.
        source: (N,) uint8 ``DepthSource`` per feature.
        track_length: (N,) int32 number of frames the track has been observed, this one included.
        depth_sigma_m: (N,) σ of ``depth_m`` in metres (cam0 Z), or None. NaN entries (or None) mean "no stated
            σ": the filter then uses its configured depth noise model (``MsckfConfig.depth``:
            :class:`~msckf.options.DepthOptions`).
        depth_measured: (N,) bool, True where ``depth_m`` is a direct measurement, False where it was filled
            (inpainted), or None (unknown: every depth counts as possibly filled). Used by
            ``update.depth_fallback``.
    """

    stamp_s: float
    ids: np.ndarray
    cam0_xy: np.ndarray
    cam1_xy: np.ndarray
    depth_m: np.ndarray
    source: np.ndarray
    track_length: np.ndarray
    depth_sigma_m: np.ndarray | None = None
    depth_measured: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.ids)
        checks = [("cam0_xy", (n, 2)), ("cam1_xy", (n, 2)), ("depth_m", (n,)), ("source", (n,)),
                  ("track_length", (n,))]
        if self.depth_sigma_m is not None:
            checks.append(("depth_sigma_m", (n,)))
        if self.depth_measured is not None:
            checks.append(("depth_measured", (n,)))
        for name, shape in checks:
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"FeatureObservations.{name} must have shape {shape}, "
                                 f"got {np.shape(getattr(self, name))}")

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, keep: np.ndarray) -> FeatureObservations:
        """The observations where ``keep`` ((N,) bool) is True, every per-feature array cut alike."""
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "stamp_s"}
        cut: dict[str, Any] = {k: None if a is None else np.asarray(a)[keep] for k, a in arrays.items()}
        return replace(self, **cut)


@dataclass(frozen=True)
class PoseEstimate:
    """The filter's IMU (body) state at an image time.

    Attributes:
        stamp_s: image time, seconds.
        p_world: (3,) IMU position in the world frame (gravity-aligned, z up; origin at the first pose), metres.
        q_world_imu_xyzw: (4,) orientation of the IMU frame in the world frame, scalar last.
        v_world: (3,) velocity in the world frame, m/s.
        gyro_bias: (3,) rad/s. acc_bias: (3,) m/s².
        cov_diag: (21,) diagonal of the IMU error-state covariance (θ, b_g, v, b_a, p, θ_ext, p_ext).
    """

    stamp_s: float
    p_world: np.ndarray
    q_world_imu_xyzw: np.ndarray
    v_world: np.ndarray
    gyro_bias: np.ndarray
    acc_bias: np.ndarray
    cov_diag: np.ndarray
