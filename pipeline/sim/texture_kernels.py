"""Compiled (numba) trilinear sampling of tileable mip-mapped textures (see ``noise.MipTexture``).

A pyramid is packed into one flat float32 buffer (:func:`pack_levels`) so that one kernel call samples any
level. Texel ``(i, j)`` of level ``l`` covers ``[j, j + 1) · texel · 2^l`` metres in x (its centre at
``(j + 0.5) · texel · 2^l``), and every level repeats with the texture's period. Arithmetic is float64 per point.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_NJIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


def pack_levels(levels: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(flat, info)``: all levels (H_l, W_l[, C]) float32 concatenated, and (L, 3) int64 ``(offset, H_l, W_l)``."""
    info = np.zeros((len(levels), 3), np.int64)
    off = 0
    for k, lv in enumerate(levels):
        info[k] = (off, lv.shape[0], lv.shape[1])
        off += lv.size
    flat = np.concatenate([np.ascontiguousarray(lv, np.float32).reshape(-1) for lv in levels])
    return flat, info


@numba.njit(**_NJIT)
def mip_sample(flat: np.ndarray, info: np.ndarray, x: np.ndarray, y: np.ndarray, lod: np.ndarray,
               valid: np.ndarray, inv_texel: float, max_level: int, beyond: float, out: np.ndarray) -> None:
    """Trilinear samples of a packed pyramid at surface points.

    Args:
        flat, info: the pyramid from :func:`pack_levels` (C channels per texel, ``C = out.shape[1]``).
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
        for c in range(c_n):
            out[k, c] = 0.0
        xk = float(x[k]) * inv_texel
        yk = float(y[k]) * inv_texel
        for step in range(2):
            lv = l0 + step
            wgt = 1.0 - f if step == 0 else f
            if wgt <= 0.0 or lv >= n_lev:
                continue
            off, h, w = info[lv, 0], info[lv, 1], info[lv, 2]
            s = 0.5 ** lv
            u = xk * s - 0.5
            v = yk * s - 0.5
            fu = math.floor(u)
            fv = math.floor(v)
            a = u - fu
            b = v - fv
            j0 = int(fu - w * math.floor(fu / w))
            i0 = int(fv - h * math.floor(fv / h))
            j1 = j0 + 1 if j0 + 1 < w else 0
            i1 = i0 + 1 if i0 + 1 < h else 0
            p00 = off + (i0 * w + j0) * c_n
            p01 = off + (i0 * w + j1) * c_n
            p10 = off + (i1 * w + j0) * c_n
            p11 = off + (i1 * w + j1) * c_n
            w00 = (1.0 - a) * (1.0 - b) * wgt
            w01 = a * (1.0 - b) * wgt
            w10 = (1.0 - a) * b * wgt
            w11 = a * b * wgt
            for c in range(c_n):
                out[k, c] += w00 * flat[p00 + c] + w01 * flat[p01 + c] + w10 * flat[p10 + c] + w11 * flat[p11 + c]
