"""Depth-map reconstruction metrics, on hole pixels (primary) and on the whole image (labelled, secondary).

Conventions (stated once, used by every report):

- Evaluated pixels are those with valid ground truth (``valid``; default: finite GT). Sky or far pixels can be
  excluded by the caller with ``valid = gt <= max_depth``.
- RMSE and MAE in metres.
- PSNR = 10·log10(peak² / MSE) with a FIXED peak (default 20 m: the depth range the stereo camera of the
  Rosario set resolves usefully). A fixed peak makes PSNR comparable across images; it is not the per-image
  range.
- SSIM as Wang et al. 2004: Gaussian window 11×11, σ = 1.5, K1 = 0.01, K2 = 0.03, L = peak, computed on maps
  clipped to [0, peak] (pixels without valid ground truth are set to 0 in both maps) and averaged over the
  evaluated pixels: hole pixels for the hole figure (the SSIM map is windowed, so holes are not cropped out).
- Whole-image figures use every valid pixel. When a method leaves known pixels untouched,
  MSE_whole = ρ·MSE_hole (ρ = hole ratio), so whole-image PSNR is higher by 10·log10(1/ρ) dB: report hole-only
  figures as the result.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from eval.errors import EvalInputError

DEFAULT_PEAK_M = 20.0
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


@dataclass(frozen=True)
class DepthMetrics:
    """Metrics of one reconstructed map. ``*_hole``: over hole pixels with valid ground truth; ``*_whole``: over
    all pixels with valid ground truth. RMSE/MAE in metres, PSNR in dB (peak ``peak_m``), SSIM unitless.
    ``n_hole``: evaluated hole pixels; ``hole_ratio``: evaluated hole pixels / evaluated pixels."""

    rmse_hole: float
    mae_hole: float
    psnr_hole: float
    ssim_hole: float
    rmse_whole: float
    mae_whole: float
    psnr_whole: float
    ssim_whole: float
    n_hole: int
    hole_ratio: float
    peak_m: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def psnr(mse: float, peak: float = DEFAULT_PEAK_M) -> float:
    """10·log10(peak²/mse) in dB; +inf for a perfect reconstruction."""
    return float("inf") if mse <= 0 else float(10.0 * np.log10(peak * peak / mse))


def ssim_map(a: np.ndarray, b: np.ndarray, data_range: float = DEFAULT_PEAK_M) -> np.ndarray:
    """Per-pixel SSIM (H×W float64) of two maps with Wang et al.'s Gaussian 11×11, σ = 1.5 window
    (borders: reflected)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2

    def blur(x: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(x, (SSIM_WINDOW, SSIM_WINDOW), SSIM_SIGMA, borderType=cv2.BORDER_REFLECT)

    mu_a, mu_b = blur(a), blur(b)
    saa = blur(a * a) - mu_a * mu_a
    sbb = blur(b * b) - mu_b * mu_b
    sab = blur(a * b) - mu_a * mu_b
    return ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (saa + sbb + c2))


def depth_metrics(pred: np.ndarray, gt: np.ndarray, hole: np.ndarray, valid: np.ndarray | None = None,
                  peak: float = DEFAULT_PEAK_M) -> DepthMetrics:
    """Metrics of ``pred`` against ``gt`` (both H×W metres) on ``hole`` (bool H×W) and on the whole image.

    ``valid``: bool H×W, pixels whose ground truth counts (default: finite ``gt``). Raises ``EvalInputError`` on
    shape mismatch, non-finite predictions where evaluated, or no evaluated hole pixel.
    """
    pred = np.asarray(pred)
    gt = np.asarray(gt)
    hole = np.asarray(hole)
    if pred.shape != gt.shape or hole.shape != gt.shape or pred.ndim != 2:
        raise EvalInputError(f"depth metrics: shapes differ or are not 2-D: pred {pred.shape}, gt {gt.shape}, "
                             f"hole {hole.shape}")
    if hole.dtype != np.bool_:
        raise EvalInputError(f"depth metrics: hole mask must be bool, got {hole.dtype}")
    if peak <= 0:
        raise EvalInputError(f"depth metrics: peak must be positive, got {peak}")
    ok = np.isfinite(gt) if valid is None else (np.asarray(valid, bool) & np.isfinite(gt))
    ev_hole = hole & ok
    if not ev_hole.any():
        raise EvalInputError("depth metrics: no hole pixel with valid ground truth to evaluate")
    if not np.isfinite(pred[ok]).all():
        raise EvalInputError("depth metrics: prediction is not finite on evaluated pixels")
    p64, g64 = pred.astype(np.float64), gt.astype(np.float64)
    err = np.where(ok, p64 - g64, 0.0)
    mse_h = float(np.mean(err[ev_hole] ** 2))
    mse_w = float(np.mean(err[ok] ** 2))
    pa = np.where(ok, np.clip(p64, 0, peak), 0.0)
    ga = np.where(ok, np.clip(g64, 0, peak), 0.0)
    smap = ssim_map(pa, ga, peak)
    return DepthMetrics(
        rmse_hole=float(np.sqrt(mse_h)), mae_hole=float(np.mean(np.abs(err[ev_hole]))),
        psnr_hole=psnr(mse_h, peak), ssim_hole=float(np.mean(smap[ev_hole])),
        rmse_whole=float(np.sqrt(mse_w)), mae_whole=float(np.mean(np.abs(err[ok]))),
        psnr_whole=psnr(mse_w, peak), ssim_whole=float(np.mean(smap[ok])),
        n_hole=int(ev_hole.sum()), hole_ratio=float(ev_hole.sum() / ok.sum()), peak_m=float(peak))
