"""The VIO facade: front end (images → feature observations) + back end (MSCKF filter) behind one object.

Drive it from arrays, in time order::

    vio = Msckf(config, rig, variant="stereo", seed=0)
    for each IMU sample:      vio.add_imu(t_s, gyro_rad_s, accel_m_s2)
    for each stereo frame:    pose = vio.add_frame(t_s, left_grey, right_grey)          # variant "stereo"
                              pose = vio.add_frame(t_s, left_grey, depth=d, depth_valid=m)  # variant "depth"

``pose`` is a :class:`~msckf.types.PoseEstimate` of the IMU (body) frame at the image time, world frame
gravity-aligned z up with its origin at the start, or ``None`` while the filter is initialising. Images are
the raw (distorted) grey images as in the bags; a depth map is in metres in the *rectified* left camera frame.
Feature observations can also be fed directly with :meth:`Msckf.add_features` (no images).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from msckf.camera import StereoRig
from msckf.config import MsckfConfig, load_config
from msckf.errors import MsckfInputError
from msckf.filter import FrameStats, MsckfFilter
from msckf.types import FeatureObservations, PoseEstimate

__all__ = ["Msckf", "VARIANTS"]

VARIANTS = ("stereo", "depth")


class _Frontend(Protocol):
    def add_imu(self, t_s: float, gyro_rad_s: np.ndarray) -> None: ...


def filter_config(config: MsckfConfig, variant: str) -> MsckfConfig:
    """The back end's config for a front end: the ``stereo`` front end uses ``update.stereo_gate_noise``,
    ``stereo_feature_noise`` and ``stereo_track_drift_psd`` (each where > 0) in place of ``gate_noise``,
    ``feature_noise`` and ``track_drift_psd``; the ``depth`` front end uses the config as it is."""
    u = config.update
    if variant != "stereo":
        return config
    return replace(config, update=replace(
        u, gate_noise=u.stereo_gate_noise if u.stereo_gate_noise > 0 else u.gate_noise,
        feature_noise=u.stereo_feature_noise if u.stereo_feature_noise > 0 else u.feature_noise,
        track_drift_psd=u.stereo_track_drift_psd if u.stereo_track_drift_psd > 0 else u.track_drift_psd))


class Msckf:
    """Stereo (or left image + depth map) MSCKF visual–inertial odometry.

    Args:
        config: :class:`MsckfConfig`, a mapping or a YAML path (see :func:`~msckf.config.load_config`).
        rig: the calibrated :class:`~msckf.camera.StereoRig` (``T_left_imu`` = cam0/T_cam_imu,
            ``T_right_left`` = cam1/T_cn_cnm1).
        variant: ``"stereo"`` (S-MSCKF front end: KLT left→right matching) or ``"depth"`` (features on the left
            image, depth read from a depth map).
        seed: seeds the front end's random draws (RANSAC); the back end is deterministic.
        frontend: optional front-end object to use instead of the default (tests, custom trackers); it needs
            ``add_imu(t_s, gyro)`` and ``process(...)`` with the signature of the variant's front end.
    """

    def __init__(self, config: MsckfConfig | dict[str, Any] | str | None, rig: StereoRig, variant: str = "stereo",
                 seed: int = 0, frontend: Any | None = None) -> None:
        if variant not in VARIANTS:
            raise MsckfInputError(f"unknown VIO variant {variant!r}; expected one of {', '.join(VARIANTS)}")
        if not isinstance(rig, StereoRig):
            raise MsckfInputError(f"rig must be a StereoRig, got {type(rig).__name__}")
        self.config = load_config(config)
        self.rig = rig
        self.variant = variant
        self.seed = int(seed)
        self.filter = MsckfFilter(filter_config(self.config, variant), rig.T_left_imu, rig.T_right_left)
        if frontend is None:
            from msckf.frontend import DepthFrontend, StereoFrontend  # imported lazily (OpenCV set-up)
            cls = StereoFrontend if variant == "stereo" else DepthFrontend
            frontend = cls(self.config.frontend, rig, rig.T_left_imu, self.seed)
        self.frontend: Any = frontend  # StereoFrontend or DepthFrontend (or a test's): process() differs by variant
        self.last_observations: FeatureObservations | None = None
        self.n_frames = 0

    # ---------------------------------------------------------------------------------------------- input
    def add_imu(self, t_s: float, gyro: np.ndarray, accel: np.ndarray) -> None:
        """One IMU sample: stamp (s), angular rate (3,) rad/s and specific force (3,) m/s², both IMU frame.

        Raises what :meth:`MsckfFilter.feed_imu` raises (e.g. ``NonStaticStartError``; the front end has the
        sample already, so a caller may catch it and keep feeding).
        """
        self.frontend.add_imu(float(t_s), np.asarray(gyro, dtype=np.float64))
        self.filter.feed_imu(t_s, gyro, accel)

    def add_frame(self, stamp_s: float, left_grey: np.ndarray, right_grey: np.ndarray | None = None,
                  depth: np.ndarray | None = None, depth_valid: np.ndarray | None = None,
                  depth_sigma: np.ndarray | None = None, depth_measured: np.ndarray | None = None
                  ) -> PoseEstimate | None:
        """Process one frame; returns the pose at ``stamp_s`` (None while initialising).

        Args:
            stamp_s: image time, s.
            left_grey: raw left image, uint8 H×W.
            right_grey: raw right image (variant ``stereo``).
            depth: float H×W depth in metres in the rectified left frame (variant ``depth``).
            depth_valid: bool H×W; default: finite and positive depth.
            depth_sigma: float H×W σ of ``depth`` in metres (variant ``depth``), or None (the filter's configured
                depth noise model applies).
            depth_measured: bool H×W, True where ``depth`` is a direct measurement rather than a fill, or
                None; passed per feature to the filter (its ``update.depth_fallback`` re-gates a rejected feature
                without its filled depths) and reported in ``last_debug.depth_measured``.
        Raises:
            MsckfInputError: missing or malformed images for the variant.
            FilterDivergedError: the filter diverged (the run failed; the reason is in the exception).
        """
        if self.variant == "stereo":
            if right_grey is None:
                raise MsckfInputError(f"frame at t={stamp_s:.3f} s: variant 'stereo' needs the right image")
            obs = self.frontend.process(float(stamp_s), left_grey, right_grey)
        else:
            if depth is None:
                raise MsckfInputError(f"frame at t={stamp_s:.3f} s: variant 'depth' needs a depth map")
            d = np.asarray(depth, dtype=np.float32)
            if depth_valid is None:
                depth_valid = np.isfinite(d) & (d > 0)
            valid = np.asarray(depth_valid, dtype=bool)
            sigma = None if depth_sigma is None else np.asarray(depth_sigma, dtype=np.float32)
            measured = None if depth_measured is None else np.asarray(depth_measured, dtype=bool)
            obs = self.frontend.process(float(stamp_s), left_grey, d, valid, sigma, measured)
        return self.add_features(obs)

    def add_features(self, obs: FeatureObservations) -> PoseEstimate | None:
        """Feed one frame's feature observations straight to the back end (bypassing the front end)."""
        self.last_observations = obs
        self.n_frames += 1
        return self.filter.feed_features(obs)

    # ---------------------------------------------------------------------------------------------- output
    @property
    def initialized(self) -> bool:
        """True once the static initialisation (or :meth:`MsckfFilter.initialize`) has happened."""
        return self.filter.initialized

    @property
    def last_stats(self) -> FrameStats:
        """What the back end did with the last frame (counts and stage timings)."""
        return self.filter.last_stats

    @property
    def last_debug(self) -> Any:
        """The front end's debug record of the last frame (pixels, track lengths, sources) for the replay."""
        return getattr(self.frontend, "last_debug", None)
