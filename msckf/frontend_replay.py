"""A depth front end that replays recorded tracks instead of tracking: the depth variants of one seed share a pass.

The depth front end's tracking never reads the depth map (:mod:`msckf.frontend`), so ``depth-raw`` and every
``depth-inpainted`` run with the same seed, configuration and images get identical
:class:`~msckf.frontend.DepthTracks`. :class:`RecordedDepthFrontend` takes those tracks from an iterator (one per
frame, in order) and only reads each frame's depth (:meth:`DepthFrontend.attach_depth`), so its observations — and
the filter's estimates — are bit-identical to a live :class:`~msckf.frontend.DepthFrontend`'s, at the cost of the
depth read alone (no KLT, FAST or RANSAC, no image needed).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from msckf.camera import StereoRig
from msckf.errors import MsckfInputError
from msckf.frontend import DepthFrontend, DepthTracks
from msckf.frontend_config import FrontendConfig
from msckf.types import FeatureObservations


class RecordedDepthFrontend(DepthFrontend):
    """:class:`DepthFrontend` whose tracking step is a recording.

    Args:
        config, rig, T_cam0_imu, seed: as :class:`DepthFrontend` (the seed is the one the tracks were recorded with;
            only the depth read uses the config).
        tracks: the recorded :class:`DepthTracks` of every frame, in time order (consumed lazily).
    """

    def __init__(self, config: FrontendConfig, rig: StereoRig, T_cam0_imu: np.ndarray, seed: int,
                 tracks: Iterable[DepthTracks]) -> None:
        super().__init__(config, rig, T_cam0_imu, seed)
        self._recorded: Iterator[DepthTracks] = iter(tracks)
        self.n_replayed = 0

    def add_imu(self, t_s: float, gyro_rad_s: np.ndarray) -> None:
        """Nothing to do: the gyro only predicted the recorded tracking."""

    def process(self, stamp_s: float, left_grey: np.ndarray | None, depth_m: np.ndarray,
                depth_valid: np.ndarray, depth_sigma: np.ndarray | None = None,
                depth_measured: np.ndarray | None = None) -> FeatureObservations:
        """As :meth:`DepthFrontend.process`; ``left_grey`` is not used (may be None).

        Raises:
            MsckfInputError: the recording has no more frames, or its next frame is not at ``stamp_s`` (the
                recording belongs to other images), or the depth inputs are malformed.
        """
        return self.attach_depth(self.track(stamp_s, left_grey), depth_m, depth_valid, depth_sigma, depth_measured)

    def track(self, stamp_s: float, left_grey: np.ndarray | None = None) -> DepthTracks:
        """The next recorded frame; MsckfInputError unless it is at ``stamp_s`` (exactly, as recorded)."""
        try:
            tracks = next(self._recorded)
        except StopIteration:
            raise MsckfInputError(f"recorded tracks end after {self.n_replayed} frame(s); no frame at "
                                  f"t={stamp_s:.6f} s") from None
        if tracks.stamp_s != float(stamp_s):
            raise MsckfInputError(f"recorded tracks: frame {self.n_replayed} is at t={tracks.stamp_s:.6f} s, "
                                  f"the image at t={float(stamp_s):.6f} s (recorded from other images?)")
        self.n_replayed += 1
        self.last_tracks = tracks
        return tracks
