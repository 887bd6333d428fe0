"""Compiled (numba) conversion of a cached depth map (uint16 millimetres) to metres, for
:func:`pipeline.depth.decode_depth_mm`: one pass instead of four numpy passes and three temporaries (a run decodes
one or two maps per frame). Same IEEE float32 arithmetic as the numpy expression (no fastmath): the same bits.
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.sim.jit import NJIT

__all__ = ["mm_to_metres"]


@numba.njit(**NJIT)
def mm_to_metres(depth_mm: np.ndarray, mm_per_m: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) uint16 millimetres (0 = hole) → ``(depth (H, W) float32 metres with NaN holes, valid (H, W) bool)``;
    depth = float32(mm) / ``mm_per_m`` (float32 division)."""
    h, w = depth_mm.shape
    depth = np.empty((h, w), np.float32)
    valid = np.empty((h, w), np.bool_)
    nan = np.float32(np.nan)
    for y in range(h):
        for x in range(w):
            v = depth_mm[y, x]
            if v > 0:
                valid[y, x] = True
                depth[y, x] = np.float32(v) / mm_per_m
            else:
                valid[y, x] = False
                depth[y, x] = nan
    return depth, valid
