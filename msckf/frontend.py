"""The MSCKF image front end: S-MSCKF's image processor (``stereo``) and the depth-map front end (``depth-*``).

Both front ends track FAST corners on the *raw* (distorted) left image exactly as S-MSCKF's
``image_processor.cpp`` does (msckf.md §1.12), and publish undistorted normalised coordinates:

1. **Gyro prediction.** The IMU gyro samples between the previous and the current image are integrated into the
   inter-frame rotation, rotated into cam0 (``T_cam0_imu``), and each feature's undistorted previous position is
   moved by the infinite homography ``K R K⁻¹`` (rotate the ray, re-project through the distortion) to give the
   initial flow of pyramidal KLT (``cv2.calcOpticalFlowPyrLK`` with ``OPTFLOW_USE_INITIAL_FLOW``). Tracks that
   fail or leave the image are dropped; with ``klt_fb_max_px`` > 0 (off by default) also those whose
   forward–backward round trip misses their previous pixel by more than that.
2. **Stereo matching** (``StereoFrontend`` only). KLT cam0→cam1 from the infinite-depth guess (the cam0 ray
   rotated by the stereo extrinsic rotation and projected into the raw right image), then the epipolar test
   ``|x1ᵀ E x0| / |(E x0)_xy| · f̄ > stereo_threshold`` (``E = [t]× R`` of ``T_right_left``, ``f̄`` the mean
   focal length of both cameras, as S-MSCKF) and, an addition of this port, a positive-depth test (the pair
   must triangulate at Z ≥ ``stereo_min_depth_m`` in both cameras: the epipolar test cannot see a match on the
   wrong side of the epipole). Failed matches are dropped (S-MSCKF), or kept as ``DepthSource.MONO`` with
   ``stereo_keep_mono``.
3. **2-point RANSAC** (``frontend_geometry.two_point_ransac``) between the previous and the current frame with
   the gyro rotation, seeded from the front end's own ``np.random.default_rng(seed)``: on cam0 and, for stereo
   features matched in both frames, on cam1; a feature must pass both.
4. **New features.** FAST is run in the grid cells holding fewer than ``grid_min_feature_num`` features, with
   a ``(2 r + 1)²`` mask around every existing feature; per cell the ``grid_max_feature_num`` strongest corners
   are candidates (stereo-matched first for ``stereo``), and the strongest fill the cell up to
   ``grid_min_feature_num``. Then every cell is pruned to its ``grid_max_feature_num`` longest-lived features.
5. **Depth** (``DepthFrontend`` only). Each feature's rectified left pixel is looked up in the depth map
   (``frontend_depth.sample_depth``: bilinear over four valid pixels by default, rejecting invalid pixels,
   depth edges and depths outside ``[min_depth_m, max_depth_m]``), the point is moved to cam0 and cam1 and the
   feature is published as ``DepthSource.DEPTH_MAP`` with ``depth_m`` = Z in cam0; otherwise ``MONO``.

Feature selection and tracking in the depth front end never look at the depth map, so ``depth-raw`` and
``depth-inpainted`` runs with the same seed see *identical* tracks and differ only in the depths attached to
them — the comparison the project is about.

The only randomness is RANSAC's hypothesis sampling; the same inputs and seed give bit-identical outputs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from msckf.camera import StereoRig, check_transform
from msckf.errors import MsckfInputError
from msckf.frontend_config import FrontendConfig
from msckf.frontend_depth import (
    DepthReject,
    depth_to_stereo,
    nearest_pixel_values,
    sample_depth,
)
from msckf.frontend_geometry import (
    GyroBuffer,
    camera_rotation,
    epipolar_distance,
    rotate_normalised,
    triangulated_depths,
    two_point_ransac,
)
from msckf.frontend_grid import cell_index, detect_fast_in_cells, exclusion_mask, top_per_group
from msckf.types import DepthSource, FeatureObservations


@dataclass(frozen=True)
class FrontendDebug:
    """What the front end did on one frame, for the visual replay and diagnostics.

    Attributes:
        stamp_s: image time, seconds.
        ids: (N,) int64 track ids of the published features.
        cam0_px: (N, 2) raw left pixel positions.
        cam1_px: (N, 2) raw right pixel positions (matched, or projected from depth); NaN for MONO.
        track_length: (N,) int32 frames observed, this one included.
        source: (N,) uint8 ``DepthSource``.
        depth_m: (N,) Z in cam0 (metres) from the depth map; NaN otherwise.
        depth_reject: (N,) uint8 ``frontend_depth.DepthReject`` (depth front end); all ``OK`` for stereo.
        counts: per-step feature counts (``prev``, ``tracked``, ``stereo_ok``, ``ransac_ok``, ``new``,
            ``pruned``, ``published``).
        timings_ms: wall time of each step, milliseconds (diagnostics only; never feeds back into results).
        depth_sigma_m: (N,) σ of ``depth_m`` in metres as given to the filter; NaN without depth or stated σ.
        depth_measured: (N,) bool, the feature's depth pixel was a direct measurement (False: filled, or no
            depth); None when the caller gave no measured mask.
    """

    stamp_s: float
    ids: np.ndarray
    cam0_px: np.ndarray
    cam1_px: np.ndarray
    track_length: np.ndarray
    source: np.ndarray
    depth_m: np.ndarray
    depth_reject: np.ndarray
    counts: dict = field(default_factory=dict)
    timings_ms: dict = field(default_factory=dict)
    depth_sigma_m: np.ndarray | None = None
    depth_measured: np.ndarray | None = None


@dataclass
class _Tracks:
    """Feature tracks of the last processed frame (parallel arrays)."""

    ids: np.ndarray        # (N,) int64
    px0: np.ndarray        # (N, 2) raw left pixels
    xy0: np.ndarray        # (N, 2) cam0 normalised
    px1: np.ndarray        # (N, 2) raw right pixels, NaN if not stereo-matched (stereo front end)
    xy1: np.ndarray        # (N, 2) cam1 normalised, NaN if not matched
    life: np.ndarray       # (N,) int32 frames observed

    @classmethod
    def empty(cls) -> _Tracks:
        return cls(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)),
                   np.zeros(0, np.int32))

    def __len__(self) -> int:
        return len(self.ids)

    def select(self, keep: np.ndarray) -> _Tracks:
        return _Tracks(self.ids[keep], self.px0[keep], self.xy0[keep], self.px1[keep], self.xy1[keep],
                       self.life[keep])

    @staticmethod
    def concat(a: _Tracks, b: _Tracks) -> _Tracks:
        return _Tracks(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in
                         ("ids", "px0", "xy0", "px1", "xy1", "life")))


# First round of candidate matching: try ``ceil(want · slack / rate) + margin`` candidates per cell (see
# StereoFrontend._match_candidates); only the number of KLT calls and points depends on these, not the result.
_FIRST_ROUND_SLACK = 1.15
_FIRST_ROUND_MARGIN = 2


def _as_klt(px: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(px, dtype=np.float32).reshape(-1, 1, 2)


class _TrackerBase:
    """Shared state and steps of both front ends: gyro buffer, KLT tracking, RANSAC, detection, pruning."""

    def __init__(self, config: FrontendConfig, rig: StereoRig, T_cam0_imu: np.ndarray, seed: int) -> None:
        if not isinstance(config, FrontendConfig):
            raise MsckfInputError(f"config must be a FrontendConfig, got {type(config).__name__}")
        if not isinstance(rig, StereoRig):
            raise MsckfInputError(f"rig must be a StereoRig, got {type(rig).__name__}")
        self.config = config
        self.rig = rig
        self.T_cam0_imu = check_transform(T_cam0_imu, "T_cam0_imu")
        self.R_cam0_imu = self.T_cam0_imu[:3, :3]
        self.R_cam1_imu = rig.T_right_left[:3, :3] @ self.R_cam0_imu
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._fast = cv2.FastFeatureDetector_create(threshold=config.fast_threshold, nonmaxSuppression=True)
        self._gyro = GyroBuffer()
        self._klt_criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, config.max_iteration,
                              config.track_precision)
        self._win = (config.patch_size, config.patch_size)
        self._width, self._height = rig.left.width, rig.left.height
        self._tracks = _Tracks.empty()
        self._prev_image: np.ndarray | None = None
        self._prev_stamp: float | None = None
        self._next_id = 0
        self.last_debug: FrontendDebug | None = None
        n_cells = config.grid_row * config.grid_col
        self._min_quota = np.full(n_cells, config.grid_min_feature_num, dtype=np.int64)
        self._max_quota = np.full(n_cells, config.grid_max_feature_num, dtype=np.int64)
        self._focal0 = 0.5 * (rig.left.fx + rig.left.fy)
        self._focal1 = 0.5 * (rig.right.fx + rig.right.fy)

    # ---- inputs ---------------------------------------------------------------------------------------------
    def add_imu(self, t_s: float, gyro_rad_s: np.ndarray) -> None:
        """Buffer one IMU gyro sample (IMU frame, rad/s; ``t_s`` seconds, non-decreasing)."""
        w = np.asarray(gyro_rad_s, dtype=np.float64)
        if w.shape not in ((3,), (3, 1), (1, 3)) or not np.all(np.isfinite(w)) or not np.isfinite(t_s):
            raise MsckfInputError(f"gyro sample at t={t_s} must be 3 finite numbers, got {np.asarray(gyro_rad_s)!r}")
        try:
            self._gyro.add(t_s, w.reshape(3))
        except ValueError as exc:
            raise MsckfInputError(f"IMU samples out of order: {exc}") from None

    def _check_frame(self, stamp_s: float, images: dict[str, np.ndarray]) -> None:
        if not np.isfinite(stamp_s):
            raise MsckfInputError(f"image stamp must be finite, got {stamp_s}")
        if self._prev_stamp is not None and stamp_s <= self._prev_stamp:
            raise MsckfInputError(f"image stamp {stamp_s:.6f} s is not after the previous one "
                                  f"({self._prev_stamp:.6f} s)")
        for name, img in images.items():
            if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 2:
                raise MsckfInputError(f"{name} image must be a 2-D uint8 grey image, got "
                                      f"{getattr(img, 'dtype', type(img))} {getattr(img, 'shape', '')}")
            if img.shape != (self._height, self._width):
                raise MsckfInputError(f"{name} image is {img.shape[1]}x{img.shape[0]}, calibration expects "
                                      f"{self._width}x{self._height}")

    # ---- steps ----------------------------------------------------------------------------------------------
    def _inter_frame_rotations(self, stamp_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(R_c0_p, R_c1_p)``: rotations previous → current frame of cam0 and cam1 from the gyro."""
        R_imu = self._gyro.rotation_imu(self._prev_stamp, stamp_s)
        return camera_rotation(R_imu, self.R_cam0_imu), camera_rotation(R_imu, self.R_cam1_imu)

    def _in_image(self, px: np.ndarray) -> np.ndarray:
        return ((px[:, 0] >= 0) & (px[:, 0] <= self._width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= self._height - 1)
                & np.all(np.isfinite(px), axis=1))

    def _klt(self, img0: np.ndarray, img1: np.ndarray, px: np.ndarray, guess: np.ndarray,
             levels: int) -> tuple[np.ndarray, np.ndarray]:
        """Pyramidal KLT from ``px`` in ``img0`` to ``img1`` starting at ``guess``; returns (px (N,2), ok (N,)).

        Each call builds both pyramids and ``img0``'s derivatives again (≈ 0.3 ms at 672×376, 3 levels, one core;
        the rest, ≈ 10 µs per point, is the tracking). S-MSCKF builds each pyramid once
        (``buildOpticalFlowPyramid``) and passes it to every call, but the Python binding of OpenCV 5.1 takes a
        single image for ``prevImg`` / ``nextImg`` (a pyramid list is rejected), so the front end keeps the number
        of calls small instead (one per step, candidate matching in at most two rounds).
        """
        if len(px) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=bool)
        out, status, _ = cv2.calcOpticalFlowPyrLK(
            img0, img1, _as_klt(px), _as_klt(guess), winSize=self._win, maxLevel=levels,
            criteria=self._klt_criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        out = out.reshape(-1, 2).astype(np.float64)
        ok = status.reshape(-1).astype(bool) & self._in_image(out)
        return out, ok

    def _track_temporal(self, image: np.ndarray, R_c0_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """KLT of the previous tracks into ``image`` with the gyro-predicted initial flow.

        Returns:
            ``(px0, ok)``: (N, 2) new raw left pixels of every previous track and the (N,) success mask.
        """
        tr = self._tracks
        if len(tr) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=bool)
        xy_pred = rotate_normalised(tr.xy0, R_c0_p)
        guess = self.rig.left.project(np.concatenate([xy_pred, np.ones((len(tr), 1))], axis=1))
        bad = ~np.all(np.isfinite(guess), axis=1)
        guess[bad] = tr.px0[bad]
        px0, ok = self._klt(self._prev_image, image, tr.px0, guess, self.config.pyramid_levels)
        if self.config.klt_fb_max_px > 0.0 and ok.any():
            ok = self._forward_backward_ok(image, tr.px0, px0, ok)
        return px0, ok

    def _forward_backward_ok(self, image: np.ndarray, px_prev: np.ndarray, px_curr: np.ndarray,
                             ok: np.ndarray) -> np.ndarray:
        """(N,) mask of the tracks whose round trip (``px_curr`` in ``image`` tracked back into the previous image,
        starting at ``px_prev``) lands within ``klt_fb_max_px`` of ``px_prev``; False where ``ok`` is False."""
        idx = np.flatnonzero(ok)
        back, back_ok = self._klt(image, self._prev_image, px_curr[idx], px_prev[idx], self.config.pyramid_levels)
        err = np.linalg.norm(back - px_prev[idx], axis=1)
        keep = np.zeros(len(ok), dtype=bool)
        keep[idx] = back_ok & (err <= self.config.klt_fb_max_px)
        return keep

    def _track_previous(self, image: np.ndarray, stamp_s: float
                        ) -> tuple[_Tracks, _Tracks, tuple[np.ndarray, np.ndarray] | None]:
        """The temporal step both front ends share: the previous tracks followed into ``image`` (raw left).

        Returns:
            ``(tracks, prev, rotations)``: the tracks found again (new ``px0``/``xy0``; ``px1``/``xy1`` still the
            previous frame's), the same tracks as they were in the previous frame, and ``(R_c0_p, R_c1_p)`` (previous
            → current cam0/cam1 rotations from the gyro). On the first frame or with no tracks: two empty track sets
            and None.
        """
        if self._prev_image is None or not len(self._tracks):
            return _Tracks.empty(), _Tracks.empty(), None
        rotations = self._inter_frame_rotations(stamp_s)
        px0, ok = self._track_temporal(image, rotations[0])
        prev = self._tracks.select(ok)
        tracks = _Tracks(prev.ids, px0[ok], self.rig.left.undistort_points(px0[ok]), prev.px1, prev.xy1, prev.life)
        return tracks, prev, rotations

    def _ransac(self, xy_prev: np.ndarray, xy_curr: np.ndarray, R_c_p: np.ndarray, focal: float) -> np.ndarray:
        c = self.config
        return two_point_ransac(xy_prev, xy_curr, R_c_p, focal, c.ransac_threshold, self._rng,
                                iterations=c.ransac_iterations, max_motion_px=c.ransac_max_motion_px,
                                min_inlier_fraction=c.ransac_min_inlier_fraction,
                                degenerate_motion_px=c.ransac_degenerate_motion_px)

    def _cells(self, px: np.ndarray) -> np.ndarray:
        return cell_index(px, self._width, self._height, self.config.grid_row, self.config.grid_col)

    def _detect_candidates(self, image: np.ndarray, tracks: _Tracks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """FAST candidates in the cells under ``grid_min_feature_num``: the ``grid_max`` strongest per cell.

        Returns:
            ``(px, response, cell)`` sorted by cell then decreasing response.
        """
        c = self.config
        n_cells = c.grid_row * c.grid_col
        counts = np.bincount(self._cells(tracks.px0), minlength=n_cells)
        needy = np.flatnonzero(counts < c.grid_min_feature_num)
        if len(needy) == 0:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
        mask = exclusion_mask(tracks.px0, self._width, self._height, c.mask_radius_px)
        px, resp, cell = detect_fast_in_cells(self._fast, image, needy, mask, c.grid_row, c.grid_col)
        keep = top_per_group(cell, resp, self._max_quota)
        px, resp, cell = px[keep], resp[keep], cell[keep]
        order = np.lexsort((-resp, cell))
        return px[order], resp[order], cell[order]

    def _fill_vacancies(self, tracks: _Tracks, new: _Tracks, new_resp: np.ndarray) -> tuple[_Tracks, int]:
        """Add the strongest new features to each cell up to ``grid_min_feature_num``; assigns their ids.

        ``new.xy0`` may be NaN (not yet undistorted): the kept ones are undistorted here.
        """
        n_cells = self.config.grid_row * self.config.grid_col
        counts = np.bincount(self._cells(tracks.px0), minlength=n_cells)
        vacancy = np.maximum(self._min_quota - counts, 0)
        keep = top_per_group(self._cells(new.px0), new_resp, vacancy)
        added = new.select(keep)
        todo = np.isnan(added.xy0[:, 0])
        if todo.any():
            added.xy0[todo] = self.rig.left.undistort_points(added.px0[todo])
        added.ids = np.arange(self._next_id, self._next_id + len(added), dtype=np.int64)
        self._next_id += len(added)
        return _Tracks.concat(tracks, added), len(added)

    def _prune(self, tracks: _Tracks) -> tuple[_Tracks, int]:
        """Keep the ``grid_max_feature_num`` longest-lived features of each cell.

        Tracks are always stored in increasing id order and the selection is stable, so ties keep older ids.
        """
        keep = top_per_group(self._cells(tracks.px0), tracks.life.astype(np.float64), self._max_quota)
        return tracks.select(keep), len(tracks) - len(keep)

    def _new_tracks(self, px0: np.ndarray, undistort: bool = True) -> _Tracks:
        """Tracks for new corners (id -1 until kept, life 1); ``xy0`` left NaN unless ``undistort``."""
        n = len(px0)
        nan = np.full((n, 2), np.nan)
        xy0 = self.rig.left.undistort_points(px0) if undistort else nan.copy()
        return _Tracks(np.full(n, -1, np.int64), px0, xy0, nan, nan.copy(), np.ones(n, np.int32))

    def _finish(self, stamp_s: float, image: np.ndarray, tracks: _Tracks) -> None:
        self._tracks = tracks
        self._prev_image = image.copy()
        self._prev_stamp = float(stamp_s)
        self._gyro.drop_before(stamp_s)


class StereoFrontend(_TrackerBase):
    """S-MSCKF's image processor (variant ``stereo``): KLT temporal tracking and KLT left→right matching.

    Args:
        config: front-end parameters.
        rig: the calibrated stereo rig (raw cameras, ``T_right_left``).
        T_cam0_imu: (4, 4) maps IMU-frame points into cam0 (rotates the gyro into the cameras).
        seed: seeds the RANSAC generator.
    """

    def __init__(self, config: FrontendConfig, rig: StereoRig, T_cam0_imu: np.ndarray, seed: int) -> None:
        super().__init__(config, rig, T_cam0_imu, seed)
        self._R_10 = rig.T_right_left[:3, :3]
        self._t_10 = rig.T_right_left[:3, 3]
        self._stereo_unit = 4.0 / (rig.left.fx + rig.left.fy + rig.right.fx + rig.right.fy)
        self._candidate_match_rate = 0.8   # fraction of new candidates stereo-matched in the previous frame

    def _stereo_match(self, left: np.ndarray, right: np.ndarray, tracks: _Tracks,
                      prev_px0: np.ndarray | None = None, prev_px1: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Match ``tracks.px0`` into the right image.

        Returns:
            ``(px1, xy1, ok)``: (N, 2) raw right pixels, (N, 2) cam1 normalised coordinates (NaN where ``ok`` is
            False) and the (N,) success mask.
        """
        c = self.config
        n = len(tracks)
        px1 = np.full((n, 2), np.nan)
        xy1 = np.full((n, 2), np.nan)
        if n == 0:
            return px1, xy1, np.zeros(0, dtype=bool)
        rays = np.concatenate([tracks.xy0, np.ones((n, 1))], axis=1) @ self._R_10.T
        guess = self.rig.right.project(rays)
        bad = ~np.all(np.isfinite(guess), axis=1)
        guess[bad] = tracks.px0[bad]
        ok = np.zeros(n, dtype=bool)
        reuse = np.zeros(n, dtype=bool)
        if c.stereo_reuse_disparity and prev_px1 is not None:
            reuse = np.all(np.isfinite(prev_px1), axis=1)
            if reuse.any():
                g = prev_px1[reuse] + (tracks.px0[reuse] - prev_px0[reuse])
                px1[reuse], ok[reuse] = self._klt(left, right, tracks.px0[reuse], g, c.stereo_reuse_levels)
        fresh = ~reuse
        if fresh.any():
            px1[fresh], ok[fresh] = self._klt(left, right, tracks.px0[fresh], guess[fresh], c.pyramid_levels)
        idx = np.flatnonzero(ok)
        if len(idx):
            xy1_ok = self.rig.right.undistort_points(px1[idx])
            dist = epipolar_distance(tracks.xy0[idx], xy1_ok, self._R_10, self._t_10)
            z0, z1 = triangulated_depths(tracks.xy0[idx], xy1_ok, self._R_10, self._t_10)
            good = ((dist <= c.stereo_threshold * self._stereo_unit)
                    & (z0 >= c.stereo_min_depth_m) & (z1 >= c.stereo_min_depth_m))
            ok[idx[~good]] = False
            xy1[idx[good]] = xy1_ok[good]
        px1[~ok] = np.nan
        return px1, xy1, ok

    def _match_candidates(self, left: np.ndarray, right: np.ndarray, tracks: _Tracks, new: _Tracks,
                          cell: np.ndarray) -> np.ndarray:
        """Stereo-match new candidates (sorted by cell, then decreasing response); fills ``new.xy0/px1/xy1``.

        S-MSCKF matches every candidate and then keeps the strongest matched ones per cell. KLT treats each
        point independently, so matching in rounds — each round tries, per cell, the next strongest untried
        candidates, a few more than the cell still has vacancies — selects exactly the same features while
        matching far fewer points. Each KLT call also pays a fixed cost (both image pyramids and the left
        image's derivatives, ≈ 30 points' worth at 672×376), so the first round tries ``want / s`` candidates
        per cell plus a margin, with ``s`` the fraction of candidates matched in the previous frame, and the
        second round everything left in the cells still short: almost always one call, at most two. (The widths
        change only how many points are tried, never which features are selected.) Returns the (N,) mask of
        matched candidates (untried ones are False).
        """
        n_cells = self.config.grid_row * self.config.grid_col
        vacancy = np.maximum(self._min_quota - np.bincount(self._cells(tracks.px0), minlength=n_cells), 0)
        n = len(new)
        ok = np.zeros(n, dtype=bool)
        tried = np.zeros(n, dtype=bool)
        if n == 0:
            return ok
        starts = np.searchsorted(cell, np.arange(n_cells))
        rank = np.arange(n) - starts[cell]          # rank by response within the cell
        next_rank = np.zeros(n_cells, dtype=np.int64)
        rate = min(max(self._candidate_match_rate, 0.25), 1.0)
        for round_ in range(3):  # round 1 tries everything left, so round 2 finds nothing to do
            want = vacancy - np.bincount(cell[ok], minlength=n_cells)
            if round_ == 0:
                width = np.where(want > 0, np.ceil(want * (_FIRST_ROUND_SLACK / rate)).astype(np.int64)
                                 + _FIRST_ROUND_MARGIN, 0)
            else:
                width = np.where(want > 0, n, 0)
            batch = ~tried & (rank >= next_rank[cell]) & (rank < next_rank[cell] + width[cell])
            if not batch.any():
                break
            next_rank = next_rank + width
            new.xy0[batch] = self.rig.left.undistort_points(new.px0[batch])
            px1, xy1, matched = self._stereo_match(left, right, new.select(batch))
            new.px1[batch], new.xy1[batch] = px1, xy1
            ok[batch] = matched
            tried |= batch
        if tried.any():
            self._candidate_match_rate = float(ok.sum()) / float(tried.sum())
        return ok

    def process(self, stamp_s: float, left_grey: np.ndarray, right_grey: np.ndarray) -> FeatureObservations:
        """Track features into a new raw stereo pair and publish their normalised stereo observations.

        Args:
            stamp_s: image time, seconds (strictly increasing).
            left_grey, right_grey: (H, W) uint8 raw (distorted) grey images of cam0 / cam1.
        Returns:
            The frame's features: ``STEREO_MATCH`` with ``cam1_xy``, or (``stereo_keep_mono``) ``MONO``.
        """
        self._check_frame(stamp_s, {"left": left_grey, "right": right_grey})
        c = self.config
        timings: dict[str, float] = {}
        counts: dict[str, int] = {"prev": len(self._tracks)}
        t = time.perf_counter()
        tracks, prev, rotations = self._track_previous(left_grey, stamp_s)
        if rotations is not None:
            R_c0_p, R_c1_p = rotations
            counts["tracked"] = len(tracks)
            t = _lap(timings, "track", t)
            px1, xy1, ok = self._stereo_match(left_grey, right_grey, tracks, prev.px0, prev.px1)
            counts["stereo_ok"] = int(ok.sum())
            keep = ok if not c.stereo_keep_mono else np.ones(len(tracks), dtype=bool)
            prev, tracks = prev.select(keep), tracks.select(keep)
            px1, xy1, ok = px1[keep], xy1[keep], ok[keep]
            t = _lap(timings, "stereo", t)
            inl = self._ransac(prev.xy0, tracks.xy0, R_c0_p, self._focal0)
            both = ok & np.all(np.isfinite(prev.xy1), axis=1)
            if both.any():
                inl1 = np.ones(len(tracks), dtype=bool)
                inl1[both] = self._ransac(prev.xy1[both], xy1[both], R_c1_p, self._focal1)
                inl &= inl1
            tracks = _Tracks(tracks.ids, tracks.px0, tracks.xy0, px1, xy1, tracks.life + 1).select(inl)
            counts["ransac_ok"] = len(tracks)
            t = _lap(timings, "ransac", t)
        else:
            t = _lap(timings, "track", t)

        cand_px, cand_resp, cand_cell = self._detect_candidates(left_grey, tracks)
        new = self._new_tracks(cand_px, undistort=False)
        ok = self._match_candidates(left_grey, right_grey, tracks, new, cand_cell)
        tracks, counts["new"] = self._fill_vacancies(tracks, new.select(ok), cand_resp[ok])
        tracks, counts["pruned"] = self._prune(tracks)
        t = _lap(timings, "detect", t)

        self._finish(stamp_s, left_grey, tracks)
        matched = np.all(np.isfinite(tracks.xy1), axis=1)
        source = np.where(matched, DepthSource.STEREO_MATCH, DepthSource.MONO).astype(np.uint8)
        obs = FeatureObservations(float(stamp_s), tracks.ids.copy(), tracks.xy0.copy(), tracks.xy1.copy(),
                                  np.full(len(tracks), np.nan), source, tracks.life.astype(np.int32))
        counts["published"] = len(tracks)
        self.last_debug = FrontendDebug(float(stamp_s), obs.ids, tracks.px0.copy(), tracks.px1.copy(),
                                        obs.track_length, source, obs.depth_m,
                                        np.zeros(len(tracks), np.uint8), counts, timings)
        return obs


@dataclass(frozen=True)
class DepthTracks:
    """What the depth front end's tracking gives on one frame, before any depth is read (it never reads one).

    ``depth-raw`` and ``depth-inpainted`` runs with the same seed get identical :class:`DepthTracks`, so one pass
    can be recorded and replayed by the others (:class:`msckf.frontend_replay.RecordedDepthFrontend`).

    Attributes:
        stamp_s: image time, s.
        ids: (N,) int64 track ids, increasing.
        px0: (N, 2) float64 raw (distorted) left pixels.
        xy0: (N, 2) float64 cam0 normalised undistorted coordinates.
        life: (N,) int32 frames observed, this one included.
        counts: the tracking steps' feature counts (``prev``, ``tracked``, ``ransac_ok``, ``new``, ``pruned``;
            ``tracked`` / ``ransac_ok`` absent on a frame with nothing to track).
        timings_ms: wall time of the tracking steps, ms (diagnostics only).
    """

    stamp_s: float
    ids: np.ndarray
    px0: np.ndarray
    xy0: np.ndarray
    life: np.ndarray
    counts: dict = field(default_factory=dict)
    timings_ms: dict = field(default_factory=dict)


def check_depth_inputs(shape: tuple[int, int], depth_m: np.ndarray, depth_valid: np.ndarray) -> None:
    """MsckfInputError unless ``depth_m`` is a float map and ``depth_valid`` a bool map of ``shape`` (H, W)."""
    if not isinstance(depth_m, np.ndarray) or depth_m.shape != shape or depth_m.dtype.kind != "f":
        raise MsckfInputError(f"depth map must be a float {shape[1]}x{shape[0]} array (metres), got "
                              f"{getattr(depth_m, 'dtype', type(depth_m))} {getattr(depth_m, 'shape', '')}")
    if not isinstance(depth_valid, np.ndarray) or depth_valid.shape != shape or depth_valid.dtype != bool:
        raise MsckfInputError(f"depth validity must be a bool {shape[1]}x{shape[0]} array, got "
                              f"{getattr(depth_valid, 'dtype', type(depth_valid))} "
                              f"{getattr(depth_valid, 'shape', '')}")


class DepthFrontend(_TrackerBase):
    """Left-image tracking plus per-feature depth from a depth map (variants ``depth-raw`` / ``depth-inpainted``).

    :meth:`process` = :meth:`track` (never looks at the depth map) then :meth:`attach_depth`. The last frame's
    tracks are kept in ``last_tracks`` (for recording them).

    Args:
        config: front-end parameters (``depth_*`` / ``min_depth_m`` / ``max_depth_m`` control the depth read).
        rig: the calibrated stereo rig; the depth map lives in its rectified left frame.
        T_cam0_imu: (4, 4) maps IMU-frame points into cam0.
        seed: seeds the RANSAC generator.
    """

    last_tracks: DepthTracks | None = None

    def process(self, stamp_s: float, left_grey: np.ndarray, depth_m: np.ndarray,
                depth_valid: np.ndarray, depth_sigma: np.ndarray | None = None,
                depth_measured: np.ndarray | None = None) -> FeatureObservations:
        """Track features into a new raw left image and attach depths read from the rectified depth map.

        Args:
            stamp_s: image time, seconds (strictly increasing).
            left_grey: (H, W) uint8 raw (distorted) left image.
            depth_m: (H, W) float depth Z in metres in the rectified left camera frame.
            depth_valid: (H, W) bool, True where ``depth_m`` holds a depth.
            depth_sigma: optional (H, W) float σ of ``depth_m`` in metres (per pixel; read at the feature's nearest
                rectified pixel and carried to cam0 Z as ``depth_sigma_m``); None: no stated σ.
            depth_measured: optional (H, W) bool, True where ``depth_m`` is a direct measurement (not a fill);
                read at the same pixel, passed on per feature (``FeatureObservations.depth_measured``, for the
                filter's ``update.depth_fallback``) and in ``last_debug.depth_measured``.
        Returns:
            The frame's features: ``DEPTH_MAP`` (with ``cam1_xy`` and ``depth_m``) or ``MONO``.
        """
        self._check_frame(stamp_s, {"left": left_grey})
        # checked before tracking (attach_depth checks again): a malformed map must not advance the tracks
        check_depth_inputs((self._height, self._width), depth_m, depth_valid)
        self.last_tracks = self._track(stamp_s, left_grey)
        return self.attach_depth(self.last_tracks, depth_m, depth_valid, depth_sigma, depth_measured)

    def track(self, stamp_s: float, left_grey: np.ndarray) -> DepthTracks:
        """Only the tracking step of :meth:`process` (no depth map needed): the frame's :class:`DepthTracks`."""
        self._check_frame(stamp_s, {"left": left_grey})
        self.last_tracks = self._track(stamp_s, left_grey)
        return self.last_tracks

    def _track(self, stamp_s: float, left_grey: np.ndarray) -> DepthTracks:
        timings: dict[str, float] = {}
        counts: dict[str, int] = {"prev": len(self._tracks)}
        t = time.perf_counter()
        tracks, prev, rotations = self._track_previous(left_grey, stamp_s)
        if rotations is not None:
            counts["tracked"] = len(tracks)
            t = _lap(timings, "track", t)
            inl = self._ransac(prev.xy0, tracks.xy0, rotations[0], self._focal0)
            tracks = _Tracks(tracks.ids, tracks.px0, tracks.xy0, tracks.px1, tracks.xy1, tracks.life + 1)
            tracks = tracks.select(inl)
            counts["ransac_ok"] = len(tracks)
            t = _lap(timings, "ransac", t)
        else:
            t = _lap(timings, "track", t)

        cand_px, cand_resp, _ = self._detect_candidates(left_grey, tracks)
        tracks, counts["new"] = self._fill_vacancies(tracks, self._new_tracks(cand_px, undistort=False),
                                                      cand_resp)
        tracks, counts["pruned"] = self._prune(tracks)
        _lap(timings, "detect", t)
        # Depth observations are recomputed every frame; the tracks keep no cam1 state.
        self._finish(stamp_s, left_grey, tracks)
        return DepthTracks(float(stamp_s), tracks.ids, tracks.px0, tracks.xy0, tracks.life, counts, timings)

    def attach_depth(self, tracks: DepthTracks, depth_m: np.ndarray, depth_valid: np.ndarray,
                     depth_sigma: np.ndarray | None = None, depth_measured: np.ndarray | None = None
                     ) -> FeatureObservations:
        """The depth step of :meth:`process`: each track's depth read from the map (arguments as there); sets
        ``last_debug``. Reads only ``self.config`` and ``self.rig``: it does not touch the tracking state."""
        shape = (self._height, self._width)
        check_depth_inputs(shape, depth_m, depth_valid)
        c = self.config
        timings = dict(tracks.timings_ms)
        counts = dict(tracks.counts)
        t = time.perf_counter()
        rect = self.rig.rectify_left_normalised(tracks.xy0)
        z_rect, reject = sample_depth(depth_m, depth_valid, rect, c.depth_sampling, c.depth_edge_window,
                                      c.depth_edge_threshold, c.min_depth_m, c.max_depth_m, c.patch_size)
        z0, xy1 = depth_to_stereo(tracks.xy0, z_rect, self.rig.R_left, self.rig.T_right_left)
        behind = np.isfinite(z_rect) & ~np.isfinite(z0)
        reject[behind] = DepthReject.BEHIND
        has = np.isfinite(z0)
        px1 = np.full((len(tracks.ids), 2), np.nan)
        if has.any():
            p1 = np.concatenate([xy1[has], np.ones((int(has.sum()), 1))], axis=1)
            px1[has] = self.rig.right.project(p1)
        _lap(timings, "depth", t)
        source = np.where(has, DepthSource.DEPTH_MAP, DepthSource.MONO).astype(np.uint8)
        sigma0 = None
        if depth_sigma is not None:
            if not isinstance(depth_sigma, np.ndarray) or depth_sigma.shape != shape:
                raise MsckfInputError(f"depth σ map must be a float {shape[1]}x{shape[0]} array (metres)")
            with np.errstate(divide="ignore", invalid="ignore"):
                sigma0 = np.where(has, nearest_pixel_values(depth_sigma, rect) * z0 / z_rect, np.nan)
        measured = None
        if depth_measured is not None:
            if not isinstance(depth_measured, np.ndarray) or depth_measured.shape != shape:
                raise MsckfInputError(f"depth measured mask must be a bool {shape[1]}x{shape[0]} array")
            measured = has & nearest_pixel_values(depth_measured.astype(bool), rect).astype(bool)
        obs = FeatureObservations(float(tracks.stamp_s), tracks.ids.copy(), tracks.xy0.copy(), xy1, z0, source,
                                  tracks.life.astype(np.int32), sigma0, measured)
        counts["published"] = len(tracks.ids)
        counts["with_depth"] = int(has.sum())
        self.last_debug = FrontendDebug(float(tracks.stamp_s), obs.ids, tracks.px0.copy(), px1, obs.track_length,
                                        source, z0, reject, counts, timings,
                                        None if sigma0 is None else sigma0.copy(), measured)
        return obs


def _lap(timings: dict[str, float], name: str, t0: float) -> float:
    t1 = time.perf_counter()
    timings[name] = (t1 - t0) * 1000.0
    return t1
