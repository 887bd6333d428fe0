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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["DepthSigmaModel", "RAW_DISPARITY_SIGMA_PX", "FILL_CALIBRATION", "fill_distance_px", "fit_fill_model"]

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
    """

    fx_baseline: float
    disparity_sigma_px: float = RAW_DISPARITY_SIGMA_PX
    fill: dict[str, tuple[float, float, float]] = field(default_factory=lambda: dict(FILL_CALIBRATION))

    @classmethod
    def for_rig(cls, rig) -> DepthSigmaModel:
        """The model for a :class:`msckf.camera.StereoRig` (its rectified fx and baseline)."""
        return cls(float(rig.fx * rig.baseline))

    def raw_sigma(self, depth_m: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(H, W) float32 σ_Z in metres of a raw SGBM map (NaN where not valid)."""
        z = depth_m.astype(np.float32)
        s = z * z * np.float32(self.disparity_sigma_px / self.fx_baseline)
        return np.where(valid, s, np.nan).astype(np.float32)

    def filled_sigma(self, depth_m: np.ndarray, raw_valid: np.ndarray, method: str) -> np.ndarray:
        """(H, W) float32 σ_Z in metres of an inpainted map: raw σ on measured pixels, fill model in the holes."""
        rel0, per_px, rel_max = self.fill.get(method) or self.fill.get("default") or FILL_CALIBRATION["default"]
        z = depth_m.astype(np.float32)
        dist = fill_distance_px(raw_valid)
        rel = np.minimum(np.float32(rel_max), np.float32(rel0) + np.float32(per_px) * dist)
        s_fill = z * rel
        s_raw = z * z * np.float32(self.disparity_sigma_px / self.fx_baseline)
        s = np.where(raw_valid, s_raw, np.maximum(s_fill, s_raw))
        return np.where(np.isfinite(z) & (z > 0), s, np.nan).astype(np.float32)


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
