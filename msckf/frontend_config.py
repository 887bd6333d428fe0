"""Parameters of the MSCKF image front end (one typed, frozen config with the Rosario defaults).

The first block mirrors S-MSCKF's ``image_processor`` parameters with the values of CIFASIS'
``launch/image_processor_rosario.launch`` (references/rosario.md §7, msckf.md §1.14). The second block holds
the constants S-MSCKF hard-codes (kept here so they are visible and testable). The third block configures the
depth-map front end used by the ``depth-raw`` / ``depth-inpainted`` variants.

Build one with keyword overrides (``FrontendConfig(grid_min_feature_num=10)``) or from a mapping read from
YAML (:meth:`FrontendConfig.from_mapping`); every value is validated and a bad value raises
:class:`~msckf.errors.MsckfInputError` naming the parameter.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from msckf.errors import MsckfInputError


@dataclass(frozen=True)
class FrontendConfig:
    """Front-end parameters. Pixel quantities are in raw (distorted) left-image pixels unless stated.

    S-MSCKF ``image_processor`` parameters (Rosario launch values):
        grid_row, grid_col: the image is split into ``grid_row × grid_col`` equal cells for feature bucketing.
        grid_min_feature_num: a cell with fewer tracked features than this gets new FAST features, up to this.
        grid_max_feature_num: a cell keeps at most this many features (the longest-lived ones).
        pyramid_levels: KLT ``maxLevel`` (so ``pyramid_levels + 1`` pyramid images).
        patch_size: KLT window side, pixels.
        fast_threshold: FAST intensity threshold (grey levels).
        max_iteration, track_precision: KLT termination (iterations, epsilon in pixels).
        ransac_threshold: 2-point RANSAC inlier threshold, pixels (point-to-epipolar-line distance).
        stereo_threshold: stereo epipolar threshold, pixels (distance of the cam1 point to the epipolar line of
            the cam0 point, normalised coordinates scaled by the mean focal length).

    Constants S-MSCKF hard-codes:
        ransac_success_probability, ransac_inlier_ratio: give the RANSAC iteration count
            ``ceil(log(1 - p) / log(1 - r²))`` (7 for 0.99 / 0.7).
        ransac_max_motion_px: rotation-compensated motions above this are outliers before RANSAC (50 px).
        ransac_min_inlier_fraction: a motion model needs this fraction of the points as inliers (0.2).
        ransac_degenerate_motion_px: below this mean rotation-compensated motion the translation is treated as
            zero and inliers are the points that moved less than ``ransac_threshold`` (1 px).
        mask_radius_px: new features are not detected within this Chebyshev radius of an existing feature
            (2 → S-MSCKF's 5×5-pixel mask).
        klt_fb_max_px: [port] forward–backward check of the temporal KLT (pixels, raw left image): each tracked
            point is tracked back into the previous image from where it was found, and a track whose round trip
            misses its previous pixel by more than this is dropped (a track that slid across an occlusion edge
            or onto another surface). 0 = off (S-MSCKF has no such check). Measured (stop 45, oracle back end): on
            ``rosario-like-02`` (120 s) 0.7 % of the frame steps have a round-trip error > 0.5 px, and their true
            step is 0.9–1.7 px (median) against 0.16 px for the rest; with the default pixel σ, 0.5 px changes the
            10 s ladder little (depth-raw 0.0139 / 0.0140 / 0.0146 → 0.0143 / 0.0117 / 0.0151 m, stereo 0.0106 /
            0.0117 / 0.0171 → 0.0105 / 0.0114 / 0.0181) and makes ``paper`` worse at 120 s on 02 (0.113 → 0.198 m,
            3 seeds); with honest pixels (0.3 px + drift, gate at that σ) it makes the tracked points' exact depth
            near-consistent on 01 (120 s: 0.084 → 0.041 m, NEES of position 12 → 3.3), not on 03 (0.108 m, NEES
            13.5). Hence off by default.

    Choices of this port (documented in msckf/frontend.py):
        stereo_keep_mono: variant ``stereo`` only. False (S-MSCKF): a tracked feature whose stereo match fails is
            dropped. True: it is kept and published as ``DepthSource.MONO`` (cam1 RANSAC then only judges
            features matched in both frames). New features must be stereo-matched either way.
        stereo_reuse_disparity: variant ``stereo`` only. False (S-MSCKF): every frame, each feature is matched
            left→right from scratch (initial guess: the infinite-depth point rotated into cam1, full pyramid).
            True: a feature matched in the previous frame starts from its previous cam1 pixel moved by its cam0
            flow and is refined on ``stereo_reuse_levels`` pyramid levels (faster; same epipolar check).
        stereo_reuse_levels: KLT ``maxLevel`` for the re-used-disparity matches.
        stereo_min_depth_m: a stereo match must triangulate in front of both cameras, at Z >= this (metres).

    Depth-map front end (variants ``depth-raw`` / ``depth-inpainted``):
        depth_sampling: ``"bilinear"`` (the four neighbours of the rectified pixel must all be valid),
            ``"nearest"``, or ``"patch"`` (accepted as ``"bilinear"``, valued as ``1 / mean(1 / Z)`` over the KLT
            window ``patch_size``: :func:`msckf.frontend_depth.sample_depth`).
        depth_edge_window: odd side, pixels, of the window around the rectified pixel tested for a depth edge.
        depth_edge_threshold: the pixel is on a depth edge (→ no depth) when
            ``(max - min) / depth > depth_edge_threshold`` over the valid depths of the window (dimensionless).
        min_depth_m, max_depth_m: depths outside ``[min_depth_m, max_depth_m]`` (metres) are rejected.
    """

    grid_row: int = 4
    grid_col: int = 5
    grid_min_feature_num: int = 30
    grid_max_feature_num: int = 50
    pyramid_levels: int = 3
    patch_size: int = 15
    fast_threshold: int = 10
    max_iteration: int = 30
    track_precision: float = 0.01
    ransac_threshold: float = 3.0
    stereo_threshold: float = 5.0

    ransac_success_probability: float = 0.99
    ransac_inlier_ratio: float = 0.7
    ransac_max_motion_px: float = 50.0
    ransac_min_inlier_fraction: float = 0.2
    ransac_degenerate_motion_px: float = 1.0
    mask_radius_px: int = 2
    klt_fb_max_px: float = 0.0

    stereo_keep_mono: bool = False
    stereo_reuse_disparity: bool = False
    stereo_reuse_levels: int = 1
    stereo_min_depth_m: float = 0.1

    depth_sampling: str = "bilinear"
    depth_edge_window: int = 5
    depth_edge_threshold: float = 0.15
    min_depth_m: float = 0.3
    max_depth_m: float = 20.0

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> MsckfInputError:
            return MsckfInputError(f"front-end config: {name}={getattr(self, name)!r} {why}")

        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type == "bool" and not isinstance(value, bool):
                raise bad(f.name, "must be true or false")
            if f.type == "int" and (isinstance(value, bool) or not isinstance(value, int)):
                raise bad(f.name, "must be an integer")
            if f.type == "float":
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise bad(f.name, "must be a finite number")
                object.__setattr__(self, f.name, float(value))
        for name in ("grid_row", "grid_col", "grid_min_feature_num", "grid_max_feature_num", "patch_size",
                     "fast_threshold", "max_iteration", "depth_edge_window"):
            if getattr(self, name) < 1:
                raise bad(name, "must be >= 1")
        for name in ("pyramid_levels", "stereo_reuse_levels", "mask_radius_px"):
            if getattr(self, name) < 0:
                raise bad(name, "must be >= 0")
        for name in ("track_precision", "ransac_threshold", "stereo_threshold", "ransac_max_motion_px",
                     "ransac_degenerate_motion_px", "max_depth_m"):
            if getattr(self, name) <= 0:
                raise bad(name, "must be > 0")
        for name in ("stereo_min_depth_m", "min_depth_m", "depth_edge_threshold", "klt_fb_max_px"):
            if getattr(self, name) < 0:
                raise bad(name, "must be >= 0")
        if self.grid_max_feature_num < self.grid_min_feature_num:
            raise bad("grid_max_feature_num", f"must be >= grid_min_feature_num ({self.grid_min_feature_num})")
        if self.patch_size % 2 == 0:
            raise bad("patch_size", "must be odd")
        if self.depth_edge_window % 2 == 0:
            raise bad("depth_edge_window", "must be odd")
        for name in ("ransac_success_probability", "ransac_inlier_ratio"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise bad(name, "must be in (0, 1)")
        if not 0.0 <= self.ransac_min_inlier_fraction <= 1.0:
            raise bad("ransac_min_inlier_fraction", "must be in [0, 1]")
        if self.max_depth_m <= self.min_depth_m:
            raise bad("max_depth_m", f"must be > min_depth_m ({self.min_depth_m})")
        if self.depth_sampling not in ("bilinear", "nearest", "patch"):
            raise bad("depth_sampling", "must be 'bilinear', 'nearest' or 'patch'")

    @property
    def ransac_iterations(self) -> int:
        """Number of 2-point RANSAC hypotheses: ``ceil(log(1 - p) / log(1 - r²))``."""
        p, r = self.ransac_success_probability, self.ransac_inlier_ratio
        return max(1, math.ceil(math.log(1.0 - p) / math.log(1.0 - r * r)))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None, source: str = "front-end config") -> FrontendConfig:
        """Build from a mapping (e.g. a YAML section); keys not given keep their defaults.

        Raises:
            MsckfInputError: an unknown key or a bad value; the message names ``source`` and the key.
        """
        values = dict(values or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise MsckfInputError(f"{source}: unknown front-end parameter(s) {', '.join(unknown)}; "
                                  f"known: {', '.join(sorted(known))}")
        try:
            return cls(**values)
        except MsckfInputError as exc:
            raise MsckfInputError(f"{source}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every parameter (for run records)."""
        return dataclasses.asdict(self)
