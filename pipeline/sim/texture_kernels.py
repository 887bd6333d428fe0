"""Compiled (numba) trilinear sampling of tileable mip-mapped textures (see ``noise.MipTexture``).

A pyramid is packed into one flat float32 buffer (:func:`pack_levels`) so that one kernel call samples any
level. Texel ``(i, j)`` of level ``l`` covers ``[j, j + 1) · texel · 2^l`` metres in x (its centre at
``(j + 0.5) · texel · 2^l``), and every level repeats with the texture's period. Arithmetic is float64 per point.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT


def pack_levels(levels: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(flat, info, scale)``: all levels (H_l, W_l[, C]) float32 concatenated, (L, 3) int64
    ``(offset, H_l, W_l)`` and (L,) float64 ``2^-l``. Sides must be powers of two (the kernels wrap texel
    indices with a bit mask)."""
    info = np.zeros((len(levels), 3), np.int64)
    scale = np.zeros(len(levels), np.float64)
    off = 0
    for k, lv in enumerate(levels):
        if any(n & (n - 1) for n in lv.shape[:2]):
            raise ValueError(f"mip level {k}: sides must be powers of two, got {lv.shape[:2]}")
        info[k] = (off, lv.shape[0], lv.shape[1])
        scale[k] = 0.5 ** k
        off += lv.size
    flat = np.concatenate([np.ascontiguousarray(lv, np.float32).reshape(-1) for lv in levels])
    return flat, info, scale


@numba.njit(inline="always", **NJIT)
def _taps(u: float, v: float, off: int, h: int, w: int, c_n: int, wgt: float
          ) -> tuple[np.uint64, np.uint64, np.uint64, np.uint64, float, float, float, float]:
    """Offsets into the packed buffer of the 4 texels around texel coordinates (u, v) of a periodic (h, w) level
    starting at ``off``, and their bilinear weights times ``wgt`` (scalars only: cheap to call per point). The
    offsets are unsigned: numba adds negative-index wrap-around to loads with signed indices (1.5× slower)."""
    fu = math.floor(u)
    fv = math.floor(v)
    a = u - fu
    b = v - fv
    j0 = int(fu) & (w - 1)  # periodic (level sides are powers of two; two's complement for negative fu)
    i0 = int(fv) & (h - 1)
    j1 = (j0 + 1) & (w - 1)
    i1 = (i0 + 1) & (h - 1)
    return (np.uint64(off + (i0 * w + j0) * c_n), np.uint64(off + (i0 * w + j1) * c_n),
            np.uint64(off + (i1 * w + j0) * c_n), np.uint64(off + (i1 * w + j1) * c_n),
            (1.0 - a) * (1.0 - b) * wgt, a * (1.0 - b) * wgt, (1.0 - a) * b * wgt, a * b * wgt)


@numba.njit(**NJIT)
def mip_sample(flat: np.ndarray, info: np.ndarray, scale: np.ndarray, x: np.ndarray, y: np.ndarray,
               lod: np.ndarray, valid: np.ndarray, inv_texel: float, max_level: int, beyond: float,
               out: np.ndarray) -> None:
    """Trilinear samples of a packed pyramid at surface points.

    Args:
        flat, info, scale: the pyramid from :func:`pack_levels` (C channels per texel, ``C = out.shape[1]``).
        x, y: (N,) surface coordinates, metres (x → columns, y → rows).
        lod: (N,) level of detail, log2(footprint / level-0 texel); clamped to the pyramid; the two levels around
            it are blended by its fraction.
        valid: (N,) bool points to sample (others are left untouched).
        inv_texel: 1 / level-0 texel size, 1/m.
        max_level: points whose lower level is ``max_level`` or coarser get the constant ``beyond`` (a detail
            texture that has averaged out); pass the level count for no limit.
        out: (N, C) float32 output.
    """
    n_lev = info.shape[0]
    c_n = out.shape[1]
    for k in range(x.size):
        if not valid[k]:
            continue
        lk = float(lod[k])
        if not (lk > 0.0):  # also NaN
            lk = 0.0
        lk = min(lk, n_lev - 1.0)
        l0 = min(int(math.floor(lk)), max(n_lev - 2, 0))
        f = min(max(lk - l0, 0.0), 1.0)
        if l0 >= max_level:
            for c in range(c_n):
                out[k, c] = beyond
            continue
        xk = float(x[k]) * inv_texel
        yk = float(y[k]) * inv_texel
        # the 4 + 4 taps of the two levels (offsets into flat, weights), then one pass over the channels
        p0 = p1 = p2 = p3 = p4 = p5 = p6 = p7 = np.uint64(0)
        w0 = w1 = w2 = w3 = w4 = w5 = w6 = w7 = 0.0
        for step in range(2):
            lv = l0 + step
            wgt = 1.0 - f if step == 0 else f
            if wgt <= 0.0 or lv >= n_lev:
                continue
            s = scale[lv]
            q00, q01, q10, q11, v00, v01, v10, v11 = _taps(xk * s - 0.5, yk * s - 0.5, info[lv, 0], info[lv, 1],
                                                           info[lv, 2], c_n, wgt)
            if step == 0:
                p0, p1, p2, p3, w0, w1, w2, w3 = q00, q01, q10, q11, v00, v01, v10, v11
            else:
                p4, p5, p6, p7, w4, w5, w6, w7 = q00, q01, q10, q11, v00, v01, v10, v11
        for c in range(c_n):
            uc = np.uint64(c)  # (uint64 + int64 would be float64 in numba)
            out[k, c] = (w0 * flat[p0 + uc] + w1 * flat[p1 + uc] + w2 * flat[p2 + uc] + w3 * flat[p3 + uc]
                         + w4 * flat[p4 + uc] + w5 * flat[p5 + uc] + w6 * flat[p6 + uc] + w7 * flat[p7 + uc])


@numba.njit(**NJIT)
def level_sample(flat: np.ndarray, info: np.ndarray, scale: np.ndarray, level: int, x: np.ndarray, y: np.ndarray,
                 inv_texel: float, out: np.ndarray) -> None:
    """Bilinear samples of one level of a packed pyramid (the fixed-level case of :func:`mip_sample`, without
    its per-point level logic): ``out[k]`` (C channels) at surface points ``(x[k], y[k])`` metres."""
    c_n = out.shape[1]
    off, h, w = info[level, 0], info[level, 1], info[level, 2]
    s = scale[level] * inv_texel
    for k in range(x.size):
        p0, p1, p2, p3, w0, w1, w2, w3 = _taps(float(x[k]) * s - 0.5, float(y[k]) * s - 0.5, off, h, w, c_n,
                                               1.0)
        for c in range(c_n):
            uc = np.uint64(c)
            out[k, c] = w0 * flat[p0 + uc] + w1 * flat[p1 + uc] + w2 * flat[p2 + uc] + w3 * flat[p3 + uc]
