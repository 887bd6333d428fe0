"""How well a filter's χ² gate statistics match their χ² distribution: one number per run, independent of the mix
of degrees of freedom.

A feature's gate statistic γ = rᵀS⁻¹r with ``dof`` degrees of freedom is χ²(dof)-distributed when the residual
covariance S the filter states is right. The median of γ/dof is then *not* 1: it is the χ² median over dof
(0.45 at dof 1, 0.79 at dof 3, 0.93 at dof 10), so a median γ/dof of 0.24 over features that mostly have 3 dof is
3.3× below calibration, not 4×. :func:`chi2_noise_scale` removes that dependence: it is the factor c by which S
would have to be multiplied for the γ's to sit at their χ² medians (half of the probability-integral transforms
``F_dof(γ / c)`` below ½). c = 1: calibrated; c < 1: S too large (the gate is loose, the filter states more
uncertainty than its residuals show); c > 1: S too small.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq
from scipy.stats import chi2

__all__ = ["chi2_noise_scale", "chi2_exceed_fraction", "gate_statistics"]


def _valid(gamma: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    g = np.asarray(gamma, dtype=np.float64).reshape(-1)
    d = np.broadcast_to(np.asarray(dof, dtype=np.float64), g.shape).reshape(-1)   # raises if they cannot match
    ok = np.isfinite(g) & (g >= 0) & np.isfinite(d) & (d > 0)
    return g[ok], d[ok]


def chi2_noise_scale(gamma: np.ndarray, dof: np.ndarray) -> float:
    """The factor c (dimensionless, > 0) with median over features of ``F_χ²(γ / c; dof)`` = ½.

    Args:
        gamma: (M,) gate statistics γ ≥ 0 (non-finite or negative entries are ignored).
        dof: (M,) or scalar degrees of freedom > 0 (entries ≤ 0 are ignored).
    Returns:
        c, or NaN when no feature is valid. When every γ is 0, returns 0.
    """
    g, d = _valid(gamma, dof)
    if g.size == 0:
        return float("nan")
    if not np.any(g > 0):
        return 0.0

    def excess(log_c: float) -> float:
        return float(np.median(chi2.cdf(g / np.exp(log_c), d))) - 0.5

    lo, hi = -30.0, 30.0                       # c from 1e-13 to 1e13: the median CDF goes from ≈ 1 to ≈ 0
    if excess(lo) <= 0.0:
        return float(np.exp(lo))
    if excess(hi) >= 0.0:
        return float(np.exp(hi))
    return float(np.exp(brentq(excess, lo, hi, xtol=1e-10)))


def chi2_exceed_fraction(gamma: np.ndarray, dof: np.ndarray, quantile: float = 0.95) -> float:
    """Share of features whose γ exceeds the χ²(dof) ``quantile`` (1 − quantile when calibrated); NaN if none."""
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must be in (0, 1), got {quantile}")
    g, d = _valid(gamma, dof)
    if g.size == 0:
        return float("nan")
    return float(np.mean(g > chi2.ppf(quantile, d)))


def gate_statistics(gamma: np.ndarray, dof: np.ndarray) -> dict[str, float]:
    """One run's gate in four numbers: median and mean γ/dof, the χ² noise scale (:func:`chi2_noise_scale`) and
    the share above the χ²(dof) 95 % quantile (:func:`chi2_exceed_fraction`); NaN each when no feature is valid.

    Args:
        gamma: (M,) gate statistics. dof: (M,) or scalar degrees of freedom.
    """
    g, d = _valid(gamma, dof)
    if g.size == 0:
        return {"gamma_per_dof_median": float("nan"), "gamma_per_dof_mean": float("nan"),
                "chi2_noise_scale": float("nan"), "above_chi2_95": float("nan")}
    r = g / d
    return {"gamma_per_dof_median": float(np.median(r)), "gamma_per_dof_mean": float(np.mean(r)),
            "chi2_noise_scale": chi2_noise_scale(g, d), "above_chi2_95": chi2_exceed_fraction(g, d)}
