"""Compiled (numba) per-pixel σ_Z maps for :class:`pipeline.depth_sigma.DepthSigmaModel`.

One pass over the map instead of numpy's five temporaries (the same float32 arithmetic, in the same order, so the
values are bit-identical to the numpy expressions they replace; checked in ``tests/test_depth_uncertainty.py``).
Compiled once per machine and cached next to the source, with the simulator's options (:data:`pipeline.sim.jit.NJIT`:
no fastmath).
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.sim.jit import NJIT

__all__ = ["raw_sigma_map", "filled_sigma_map"]


@numba.njit(**NJIT)
def raw_sigma_map(depth_m: np.ndarray, valid: np.ndarray, k_raw: np.float32) -> np.ndarray:
    """(H, W) float32 ``σ_Z = Z² · k_raw`` (m) where ``valid``, NaN elsewhere. depth_m: (H, W) float32 metres;
    valid: (H, W) bool; k_raw = σ_d / (f·B) in 1/m (float32)."""
    h, w = depth_m.shape
    out = np.empty((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in range(h):
        for x in range(w):
            if valid[y, x]:
                z = depth_m[y, x]
                out[y, x] = z * z * k_raw
            else:
                out[y, x] = nan
    return out


@numba.njit(**NJIT)
def filled_sigma_map(depth_m: np.ndarray, raw_valid: np.ndarray, keep: np.ndarray, dist_px: np.ndarray,
                     use_dist: bool, rel_0: np.float32, rel_per_px: np.float32, rel_max: np.float32,
                     k_raw: np.float32) -> np.ndarray:
    """(H, W) float32 σ_Z (m) of an inpainted map; NaN where not ``keep`` or where Z is not finite and positive.

    Measured pixels (``raw_valid``): ``Z² · k_raw``; filled ones: ``max(Z · min(rel_max, rel_0 + rel_per_px ·
    dist), Z² · k_raw)``. depth_m: (H, W) float32 m; raw_valid, keep: (H, W) bool; dist_px: (H, W) float32 px to
    the nearest measured pixel, read only when ``use_dist`` (pass any 2-D array otherwise: then dist counts as 0).
    """
    h, w = depth_m.shape
    out = np.empty((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in range(h):
        for x in range(w):
            z = depth_m[y, x]
            if not keep[y, x] or not (np.isfinite(z) and z > 0):
                out[y, x] = nan
                continue
            s_raw = z * z * k_raw
            if raw_valid[y, x]:
                out[y, x] = s_raw
                continue
            d = dist_px[y, x] if use_dist else np.float32(0.0)
            rel = min(rel_max, rel_0 + rel_per_px * d)
            s_fill = z * rel
            out[y, x] = s_fill if s_fill > s_raw else s_raw
    return out
