"""Per-pixel depth uncertainty σ_Z (metres) of raw SGBM depth and of inpainted (filled) depth.

Raw stereo depth: ``Z = f·B / d`` so a disparity error σ_d (px) gives ``σ_Z = Z² · σ_d / (f · B)``
(first order). σ_d is a stated constant (:data:`RAW_DISPARITY_SIGMA_PX`), measured on simulated sequences
against the depth of tracked points triangulated from the true poses (benchmarks/bench_depth_oracle.py prints the
measurement; the robust σ of the disparity error at tracked features).

Filled depth (pixels that were holes in the raw map): the error of a fill grows with the distance to the nearest
measured pixel (the fill extrapolates further) and with depth. The model is
``σ_Z = Z · min(FILL_REL_MAX, FILL_REL_0 + FILL_REL_PER_PX · dist_px)``, with the coefficients per method fitted once
on simulated frames against exact depth (``fit_fill_model``; the fit and its data are recorded in
:data:`FILL_CALIBRATION`). Measured pixels of an inpainted map keep the raw σ.

Fills open to the far field carry no depth (σ → ∞). A hole that borders a measured pixel whose disparity is
within a few σ_d of zero (a surface that stereo cannot tell from infinity: the horizon, the far end of the rows)
is not bounded from above by anything the camera measured: sky and the far field beyond the stereo range are
holes of that kind, and a fill there extrapolates the bordering depths into a region whose true depth may be
anywhere beyond them (measured: :data:`FAR_OPEN_SIGMAS`). :meth:`DepthSigmaModel.filled` drops those fills
from the valid mask, so the feature there stays monocular, as it is in ``depth-raw``.

Fills at occlusion edges carry no depth either (:data:`EDGE_DISPARITY_SIGMAS`): where the measured disparities
within a tracker's window of a hole differ by more than SGBM's noise explains, the hole is the occlusion SGBM
leaves at a depth discontinuity, and a corner tracked there is a T-junction of two surfaces whose apparent motion
no single surface depth describes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from pipeline.depth_sigma_kernels import filled_sigma_map, raw_sigma_map
from pipeline.far_field_kernels import geodesic_reach

__all__ = ["DepthSigmaModel", "RAW_DISPARITY_SIGMA_PX", "FILL_CALIBRATION", "FAR_OPEN_SIGMAS", "FAR_OPEN_RADIUS_PX",
           "EDGE_DISPARITY_SIGMAS", "EDGE_RADIUS_PX",
           "fill_distance_px", "fit_fill_model"]

#: σ of SGBM's disparity error, px: robust σ (1.4826·MAD) of ``f·B/Z_sgbm − f·B/Z_exact`` over the valid pixels
#: (0.3–20 m) of every 5th frame of the three 10 s presets, simulator version 4: 0.482 / 0.585 / 0.606 px
#: (rosario-like-01 / 02 / 03), pooled 0.545 px, median bias ≤ 0.015 px
#: (``benchmarks/calibrate_depth_sigma.py --every 5``, 2026-12-02).
RAW_DISPARITY_SIGMA_PX = 0.545

#: Per inpainting method: (rel_0, rel_per_px, rel_max) of the fill σ model, fitted by
#: ``benchmarks/calibrate_depth_sigma.py`` on the same frames (filled pixels with an exact depth in 0.3–20 m).
#: Telea (4.9 M filled pixels): robust σ of the relative error 14.5 % within 4 px of a measured pixel, 15.1 % at
#: 4–16 px, 15.9 % at 16–64 px, 19 % beyond — nearly flat, because holes sit at depth discontinuities (occlusion
#: edges, the left border band, sky/far field), where even a fill next to a measured pixel takes the wrong
#: surface. Same run (``--every 5 --methods telea paper ns ipbasic``, 2026-12-02, the coarse-to-fine ``paper``):
#: ``paper`` 15.8 / 16.0 / 15.0 / 17.5 % in the same distance bins (its fills are not more certain than Telea's at
#: a tracked-feature scale), NS 14.2 → 21 %, IP-Basic 13.8 → 19.5 % (with a −31 % median bias beyond 16 px).
#: Methods without a fit of their own (``paper-greedy``, ``ebm``, ``biharmonic``) use "default" (Telea's figures).
FILL_CALIBRATION: dict[str, tuple[float, float, float]] = {
    "telea": (0.1462, 0.00036, 0.5),
    "paper": (0.1601, 0.0, 0.5),
    "ns": (0.1429, 0.00156, 0.5),
    "ipbasic": (0.1448, 0.00123, 0.5),
    "default": (0.1462, 0.00036, 0.5),
}


#: A measured disparity at most this many σ_d (:data:`RAW_DISPARITY_SIGMA_PX`) above zero is compatible with a
#: point at infinity (5 × 0.545 px = 2.7 px: ≥ 15.5 m on the Rosario rig, f·B ≈ 42 px·m); a filled pixel joined
#: to such a measurement through the hole within :data:`FAR_OPEN_RADIUS_PX` steps is "open to the far field" and
#: carries no depth.
#: Measured (120 s rosario-like-02, seed 0, every 15th frame, the depth front end's hole-fed features): of the
#: features whose tracked point has no depth in 0.3–20 m (sky, far field: their fills are 3.5 / 11 / 18 m at
#: q10 / 50 / 90), 95 % have a measured depth ≥ 16 m within a 63 × 63 window; of the hole-fed features with a
#: tracked 3-D point (or an exact map value) ≤ 1 %. In the VIO those far fills alone took Telea's 120 s ATE from
#: 0.144 m (depth-raw) to 26.6 m; every other fill together gave 0.139 m (benchmarks/bench_depth_oracle.py).
FAR_OPEN_SIGMAS = 5.0
#: Geodesic reach (px, 8-connected steps through hole pixels) from a far-field measurement. Measured on the same
#: features: a 31 px window flags 71 % of the far features (25 % of them have no measured pixel that close) and
#: 1 % / 0 % of the others; a 63-step geodesic reach flags 99 % of the far ones and 6 % / 4 % of those with a 3-D
#: point / an exact map value; a plain "> 31 px from any measurement" rule would cost 20 % / 15 % of those.
FAR_OPEN_RADIUS_PX = 63
#: The occlusion-edge rule (on by default since stop 41, with the filter's ``depth_fills_only_unmeasured``): a filled
#: pixel whose (2r+1)²
#: neighbourhood in the raw map holds measured disparities (``f·B / Z``) spanning more than
#: ``EDGE_DISPARITY_SIGMAS · √2 · σ_d`` (two measurements further apart than SGBM's own noise explains) sits in the
#: hole SGBM leaves at a depth discontinuity, and carries no depth. r is the KLT tracker's half window (15 px,
#: ``FrontendConfig.patch_size``): a corner tracked there is a T-junction of the two surfaces the window straddles,
#: whose apparent motion is that of a virtual point between them, which no fill of either surface gives.
#: Measured (stop 41, oracle back end, 10 s presets 01 / 02 / 03, seeds 0–2, the same tracks in every row): at 10 s
#: the whole cost of `paper`'s fills lay on tracks that are not consistent 3-D points (RMS > 1 px against the true
#: poses; 42 / 46 / 62 % of the fill-fed observations): fills on those tracks only 0.0243 / 0.0188 / 0.0346 m, on
#: the consistent tracks only 0.0150 / 0.0148 / 0.0178 m, depth-raw 0.0136 / 0.0144 / 0.0148 m. With the rule (3 σ,
#: the one setting run) the ladder's `paper` rung goes 0.0211 / 0.0177 / 0.0208 → 0.0143 / 0.0125 / 0.0148 m. But
#: the pipeline at 120 s (5 seeds, depth-raw 0.086 / 0.135 / 0.169 m) gives `paper` 0.116 / 0.176 / 0.197 →
#: 0.142 / 0.163 / 0.190 m (rosario-like-01 worse on 5 of 5 seeds): at 120 s the fills of tracks SGBM measures in
#: other frames hurt too. Together with ``depth_fills_only_unmeasured`` (which leaves those out): 10 s 0.0127 /
#: 0.0130 / 0.0136 m (better than depth-raw on all three), 120 s 0.107 / 0.163 / 0.172 m (better than before on all
#: three, still worse than depth-raw on 01 / 02): both on by default. Stop 38's ratio form (31 px, max / min > 1.25)
#: was measured with stop 40's whitening bug.
EDGE_DISPARITY_SIGMAS = 3.0
EDGE_RADIUS_PX = 7


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def _bool(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=bool)


def _same_shape(*maps: np.ndarray) -> None:
    """The compiled kernels index every map with the first one's shape: refuse maps of different shapes."""
    shapes = {np.shape(m) for m in maps}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"depth σ: maps must be 2-D and of one shape, got {sorted(shapes)}")


def fill_distance_px(raw_valid: np.ndarray) -> np.ndarray:
    """(H, W) float32 Euclidean distance (px) of every pixel to the nearest raw-valid pixel (0 on valid ones)."""
    if raw_valid.all():
        return np.zeros(raw_valid.shape, np.float32)
    if not raw_valid.any():
        return np.full(raw_valid.shape, np.float32(max(raw_valid.shape)), np.float32)
    return cv2.distanceTransform((~raw_valid).astype(np.uint8), cv2.DIST_L2, 5).astype(np.float32)


@dataclass(frozen=True)
class DepthSigmaModel:
    """σ_Z of depth maps of one rig.

    Attributes:
        fx_baseline: rectified f·B in px·m. disparity_sigma_px: σ_d of raw SGBM, px.
        fill: method → (rel_0, rel_per_px, rel_max) (see the module doc).
        far_open_sigmas, far_open_radius_px: the far-field rule (:data:`FAR_OPEN_SIGMAS`); 0 sigmas or a reach of
            0 disables it.
        edge_disparity_sigmas, edge_radius_px: the occlusion-edge rule (:data:`EDGE_DISPARITY_SIGMAS`): fills whose
            raw neighbourhood spans more than ``edge_disparity_sigmas · √2 · disparity_sigma_px`` of disparity
            carry no depth (default 3, with ``msckf`` ``depth_fills_only_unmeasured``, since stop 41); 0 disables it.
    """

    fx_baseline: float
    disparity_sigma_px: float = RAW_DISPARITY_SIGMA_PX
    fill: dict[str, tuple[float, float, float]] = field(default_factory=lambda: dict(FILL_CALIBRATION))
    far_open_sigmas: float = FAR_OPEN_SIGMAS
    far_open_radius_px: int = FAR_OPEN_RADIUS_PX
    edge_disparity_sigmas: float = EDGE_DISPARITY_SIGMAS
    edge_radius_px: int = EDGE_RADIUS_PX

    @classmethod
    def for_rig(cls, rig) -> DepthSigmaModel:
        """The model for a :class:`msckf.camera.StereoRig` (its rectified fx and baseline)."""
        return cls(float(rig.fx * rig.baseline))

    @property
    def _k_raw(self) -> np.float32:
        """σ_d / (f·B) in 1/m (float32): ``σ_Z = Z² · k`` for a measured depth."""
        return np.float32(self.disparity_sigma_px / self.fx_baseline)

    def raw_sigma(self, depth_m: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(H, W) float32 σ_Z in metres of a raw SGBM map (NaN where not valid)."""
        _same_shape(depth_m, valid)
        return raw_sigma_map(_f32(depth_m), _bool(valid), self._k_raw)

    def filled_sigma(self, depth_m: np.ndarray, raw_valid: np.ndarray, method: str,
                     keep: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float32 σ_Z in metres of an inpainted map: raw σ on measured pixels, fill model in the holes.

        NaN where Z is not finite and positive, and where ``keep`` (optional (H, W) bool) is False. The distance
        transform is skipped for a method whose fill σ does not grow with distance (``rel_per_px == 0``).
        """
        rel0, per_px, rel_max = self.fill.get(method) or self.fill.get("default") or FILL_CALIBRATION["default"]
        raw_valid = _bool(raw_valid)
        keep = np.ones(raw_valid.shape, bool) if keep is None else _bool(keep)
        _same_shape(depth_m, raw_valid, keep)
        use_dist = per_px != 0
        dist = fill_distance_px(raw_valid) if use_dist else np.zeros((1, 1), np.float32)
        return filled_sigma_map(_f32(depth_m), raw_valid, keep, dist, use_dist, np.float32(rel0),
                                np.float32(per_px), np.float32(rel_max), self._k_raw)

    def far_open(self, raw_depth_m: np.ndarray, raw_valid: np.ndarray) -> np.ndarray:
        """(H, W) bool: the holes of a raw map that reach a far-field measurement through the hole itself.

        A far-field measurement is a measured pixel whose disparity ``f·B / Z`` is at most
        ``far_open_sigmas · disparity_sigma_px``; a hole pixel is open when an 8-connected path of at most
        ``far_open_radius_px`` steps through hole pixels joins it to one (a geodesic distance, so openness does not
        jump across a measured surface into a neighbouring hole). All False when disabled.
        """
        if self.far_open_sigmas <= 0 or raw_valid.all():
            return np.zeros(raw_valid.shape, dtype=bool)
        z_far = self.fx_baseline / (self.far_open_sigmas * self.disparity_sigma_px)
        far = raw_valid & (raw_depth_m >= z_far)
        if not far.any():
            return np.zeros(raw_valid.shape, dtype=bool)
        return geodesic_reach(far, ~raw_valid | far, int(self.far_open_radius_px)) & ~raw_valid

    def disparity_span(self, depth_m: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(H, W) float32 max − min (px) of the measured disparities ``f·B / Z`` (``valid`` and Z > 0) within the
        (2r+1)² neighbourhood (r = ``edge_radius_px``) of every pixel; 0 where it holds no measured pixel."""
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * self.edge_radius_px + 1,) * 2)
        ok = _bool(valid) & (np.asarray(depth_m) > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.float32(self.fx_baseline) / _f32(depth_m)
        # no measured pixel in the window: max −inf (OpenCV's border value −FLT_MAX where the window leaves the
        # image), min +inf: their difference is not finite, and the span is 0 there
        d_max = cv2.dilate(np.where(ok, d, np.float32(-np.inf)), kernel)
        d_min = cv2.erode(np.where(ok, d, np.float32(np.inf)), kernel)
        with np.errstate(invalid="ignore", over="ignore"):
            span = d_max - d_min
        return np.where(np.isfinite(span) & (span > 0), span, np.float32(0.0)).astype(np.float32)

    def occlusion_edge(self, raw_depth_m: np.ndarray, raw_valid: np.ndarray) -> np.ndarray:
        """(H, W) bool: the holes of a raw map whose (2r+1)² neighbourhood (r = ``edge_radius_px``) holds measured
        disparities ``f·B / Z`` spanning more than ``edge_disparity_sigmas · √2 · disparity_sigma_px`` px: holes at
        a depth discontinuity (:meth:`disparity_span`). All False when disabled (``edge_disparity_sigmas`` ≤ 0) or
        where no measured pixel is that near."""
        if self.edge_disparity_sigmas <= 0 or raw_valid.all() or not raw_valid.any():
            return np.zeros(raw_valid.shape, dtype=bool)
        limit = np.float32(self.edge_disparity_sigmas * np.sqrt(2.0) * self.disparity_sigma_px)
        return ~_bool(raw_valid) & (self.disparity_span(raw_depth_m, raw_valid) > limit)

    def filled(self, depth_m: np.ndarray, valid: np.ndarray, raw_depth_m: np.ndarray, raw_valid: np.ndarray,
               method: str) -> tuple[np.ndarray, np.ndarray]:
        """What an inpainted map gives the VIO: ``(valid, σ_Z)``, both (H, W).

        ``valid`` is the inpainted map's mask less the fills open to the far field (:meth:`far_open`) and the
        fills at occlusion edges (:meth:`occlusion_edge`); σ_Z in metres is :meth:`filled_sigma`
        (NaN where not valid). ``raw_*``: the raw SGBM map the fill was made from.
        """
        ok, sigma, _, _ = self.filled_detail(depth_m, valid, raw_depth_m, raw_valid, method)
        return ok, sigma

    def filled_detail(self, depth_m: np.ndarray, valid: np.ndarray, raw_depth_m: np.ndarray, raw_valid: np.ndarray,
                      method: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`filled` and why fills were dropped: ``(valid, σ_Z, far_open, occlusion_edge)``, all (H, W); the
        last two are the rules' masks (:meth:`far_open`, :meth:`occlusion_edge`; a pixel may be in both)."""
        far = self.far_open(raw_depth_m, raw_valid)
        edge = self.occlusion_edge(raw_depth_m, raw_valid)
        ok = valid & ~far & ~edge
        return ok, self.filled_sigma(depth_m, raw_valid, method, keep=ok), far, edge


def fit_fill_model(rel_err: np.ndarray, dist_px: np.ndarray, rel_max: float = 0.5) -> tuple[float, float, float]:
    """Fit (rel_0, rel_per_px, rel_max) of the fill σ model from filled pixels' relative errors and distances.

    The robust σ (1.4826·MAD) of the relative error is computed in distance bins and a line is fitted through
    the bins (weighted by their counts), floored at 0 slope and 0.5 % intercept.
    """
    rel_err = np.asarray(rel_err, dtype=np.float64)
    dist_px = np.asarray(dist_px, dtype=np.float64)
    ok = np.isfinite(rel_err) & np.isfinite(dist_px)
    rel_err, dist_px = rel_err[ok], dist_px[ok]
    edges = np.array([0, 2, 4, 8, 12, 16, 24, 32, 48, 64, 1e9])
    xs, ys, ws = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (dist_px > lo) & (dist_px <= hi)
        if np.count_nonzero(sel) >= 30:
            e = rel_err[sel]
            xs.append(float(np.median(dist_px[sel])))
            ys.append(float(1.4826 * np.median(np.abs(e - np.median(e)))))
            ws.append(float(np.count_nonzero(sel)))
    if len(xs) < 2:
        return (0.05, 0.01, rel_max)
    slope, icpt = np.polyfit(xs, ys, 1, w=np.sqrt(ws))
    return (max(float(icpt), 0.005), max(float(slope), 0.0), rel_max)
