"""Compiled (numba) per-point kernels of the terrain: bilinear height/slope lookup and the ray intersection.

The terrain is the bilinear interpolation of two grids (see :mod:`pipeline.sim.terrain`):

* ``long``: (N, N, 3) float32 ``(h, dh/dx, dh/dy)`` samples at ``origin + (j, i) · step`` (texel centres at
  integer coordinates), zero outside the grid;
* ``relief``: (M, M, 3) float32 samples of a tileable grid, texel ``(j, i)`` centred at ``((j, i) + 0.5) · texel``
  and repeating with period ``M · texel``.

The interpolation is exact bilinear in float64 (no fixed-point weights), evaluated per point in one pass; every
user of the terrain (rendering, plants, wheels) goes through these kernels, so all see one surface.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT


def pad_grids(long: np.ndarray, relief: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grids as the kernels read them: ``long`` with a one-texel zero border on every side, ``relief`` with
    its first row and column repeated after the last (so neither lookup needs a branch per corner). The relief's
    sides must be powers of two (its period is taken with a bit mask)."""
    if any(n & (n - 1) for n in relief.shape[:2]):
        raise ValueError(f"relief grid sides must be powers of two, got {relief.shape[:2]}")
    long_p = np.zeros((long.shape[0] + 2, long.shape[1] + 2, 3), np.float32)
    long_p[1:-1, 1:-1] = long
    relief_p = np.concatenate([relief, relief[:1]], 0)
    relief_p = np.ascontiguousarray(np.concatenate([relief_p, relief_p[:, :1]], 1), np.float32)
    return long_p, relief_p


@numba.njit(**NJIT)
def height_grad_points(long: np.ndarray, lx0: float, ly0: float, inv_lstep: float, relief: np.ndarray,
                       inv_rtexel: float, x: np.ndarray, y: np.ndarray, wu: np.ndarray, wr: np.ndarray,
                       out: np.ndarray) -> None:
    """``out[k, :3] = (h, dh/dx, dh/dy)`` at field points ``(x[k], y[k])`` (1-D float arrays, metres), the
    undulation weighted by ``wu[k]`` and the relief by ``wr[k]`` (level of detail).

    ``long`` and ``relief`` are the padded grids of :func:`pad_grids`; ``long``'s texel (0, 0) sits at
    ``(lx0, ly0)`` in the unpadded grid, ``1 / inv_lstep`` metres apart; the relief's texel is ``1 / inv_rtexel``
    metres. (One loop with the lookups written out: a helper per point, even an inlined one, made it slower;
    so did divisions instead of the multiplications by inverse texel sizes and the bit mask for the period, and
    signed indices, for which numba adds negative-index wrap-around to every load.)
    """
    lw = long.shape[1] - 2
    lh = long.shape[0] - 2
    mask_w = relief.shape[1] - 2  # the period minus one (a power of two, see pad_grids)
    mask_h = relief.shape[0] - 2
    for k in range(x.size):
        xk = float(x[k])
        yk = float(y[k])
        h = hx = hy = 0.0
        wuk = float(wu[k])
        wrk = float(wr[k])
        ul = (xk - lx0) * inv_lstep
        vl = (yk - ly0) * inv_lstep
        fu = math.floor(ul)
        fv = math.floor(vl)
        if wuk > 0.0 and fu >= -1.0 and fv >= -1.0 and fu < lw and fv < lh:  # zero beyond the grid
            j = np.uint64(int(fu) + 1)
            i = np.uint64(int(fv) + 1)
            j1 = j + np.uint64(1)
            i1 = i + np.uint64(1)
            a = ul - fu
            b = vl - fv
            w00 = (1.0 - a) * (1.0 - b) * wuk
            w01 = a * (1.0 - b) * wuk
            w10 = (1.0 - a) * b * wuk
            w11 = a * b * wuk
            h = w00 * long[i, j, 0] + w01 * long[i, j1, 0] + w10 * long[i1, j, 0] + w11 * long[i1, j1, 0]
            hx = w00 * long[i, j, 1] + w01 * long[i, j1, 1] + w10 * long[i1, j, 1] + \
                w11 * long[i1, j1, 1]
            hy = w00 * long[i, j, 2] + w01 * long[i, j1, 2] + w10 * long[i1, j, 2] + \
                w11 * long[i1, j1, 2]
        if wrk > 0.0 and math.isfinite(xk) and math.isfinite(yk):  # periodic
            ur = xk * inv_rtexel - 0.5
            vr = yk * inv_rtexel - 0.5
            fu = math.floor(ur)
            fv = math.floor(vr)
            a = ur - fu
            b = vr - fv
            j = np.uint64(int(fu) & mask_w)
            i = np.uint64(int(fv) & mask_h)
            j1 = j + np.uint64(1)
            i1 = i + np.uint64(1)
            w00 = (1.0 - a) * (1.0 - b) * wrk
            w01 = a * (1.0 - b) * wrk
            w10 = (1.0 - a) * b * wrk
            w11 = a * b * wrk
            h += w00 * relief[i, j, 0] + w01 * relief[i, j1, 0] + w10 * relief[i1, j, 0] + \
                w11 * relief[i1, j1, 0]
            hx += w00 * relief[i, j, 1] + w01 * relief[i, j1, 1] + w10 * relief[i1, j, 1] + \
                w11 * relief[i1, j1, 1]
            hy += w00 * relief[i, j, 2] + w01 * relief[i, j1, 2] + w10 * relief[i1, j, 2] + \
                w11 * relief[i1, j1, 2]
        out[k, 0] = h
        out[k, 1] = hx
        out[k, 2] = hy


@numba.njit(**NJIT)
def intersect_rays(long: np.ndarray, lx0: float, ly0: float, inv_lstep: float, relief: np.ndarray,
                   inv_rtexel: float, h_min: float, h_max: float, origin: np.ndarray, dirs: np.ndarray, t_max: float,
                   iterations: int, ref_x: float, ref_y: float, use_lod: bool, fades: np.ndarray, guess: np.ndarray,
                   tol: float, out: np.ndarray) -> None:
    """First ground hit of rays ``origin + t · dirs[k]`` (see :meth:`pipeline.sim.terrain.Terrain.intersect`):
    Newton steps kept inside the slab ``[h_min, h_max]``, from the hit with the plane z = 0 or from a guess.

    Args:
        long, lx0, ly0, inv_lstep, relief, inv_rtexel: the terrain grids, as in :func:`height_grad_points`.
        origin: (3,) float64 ray origin, field frame, metres.
        dirs: (N, 3) float32 directions.
        iterations: Newton steps (the most, for rays with a guess).
        ref_x, ref_y, use_lod: level-of-detail reference point (used when ``use_lod``); a ray's fade weights are
            taken at its plane hit whether it has a guess or not (one surface for every bundle).
        fades: (4,) float64 ``(u0, u1, r0, r1)`` undulation and relief fade distances, metres.
        guess: (N,) float64 starting ``t`` per ray (NaN: start from the plane); a ray with a guess stops once a
            Newton step moves it by less than ``tol`` (ray-parameter units; Newton converges quadratically, so
            the error left is far smaller).
        out: (N, 4) float32 ``(t, h, hx, hy)`` (``t = inf`` for no hit; h and slopes of the last evaluation, zero
            for rays that do not point down).
    """
    n_all = dirs.shape[0]
    ox, oy, oz = origin[0], origin[1], origin[2]
    u0, u1, r0, r1 = fades[0], fades[1], fades[2], fades[3]
    # only rays pointing down can meet the ground (unsigned indices: no negative-index wrap-around per load)
    down = np.empty(n_all, np.uint64)
    n = 0
    for k in range(n_all):
        out[k, 0] = np.inf
        out[k, 1] = 0.0
        out[k, 2] = 0.0
        out[k, 3] = 0.0
        if dirs[k, 2] < -1e-5:
            down[n] = k
            n += 1
    t = np.empty(n)
    t_in = np.empty(n)
    t_out = np.empty(n)
    guessed = np.zeros(n, np.bool_)
    wu_all = np.ones(n, np.float32)
    wr_all = np.ones(n, np.float32)
    for m in range(n):
        k = down[m]
        dz = float(dirs[k, 2])
        t_in[m] = max((h_max - oz) / dz, 1e-3)
        t_out[m] = (h_min - oz) / dz
        tk = min(max(-oz / dz, t_in[m]), t_out[m])
        if use_lod:
            ex = ox + tk * float(dirs[k, 0]) - ref_x
            ey = oy + tk * float(dirs[k, 1]) - ref_y
            dist = math.sqrt(ex * ex + ey * ey)
            wu_all[m] = min(max((u1 - dist) / (u1 - u0), 0.0), 1.0)
            wr_all[m] = min(max((r1 - dist) / (r1 - r0), 0.0), 1.0)
        g = guess[k]
        if g == g and t_in[m] <= g <= t_out[m]:  # not NaN, inside the slab
            tk = g
            guessed[m] = True
        t[m] = tk
    # Newton steps over the rays still active (compacted each step)
    active = np.arange(n).astype(np.uint64)
    n_act = n
    px = np.empty(n)
    py = np.empty(n)
    wu = np.empty(n, np.float32)
    wr = np.empty(n, np.float32)
    hg = np.zeros((n, 3), np.float32)
    for _ in range(iterations):
        if n_act == 0:
            break
        for a in range(n_act):
            m = active[a]
            k = down[m]
            px[a] = ox + t[m] * float(dirs[k, 0])
            py[a] = oy + t[m] * float(dirs[k, 1])
            wu[a] = wu_all[m]
            wr[a] = wr_all[m]
        height_grad_points(long, lx0, ly0, inv_lstep, relief, inv_rtexel, px[:n_act], py[:n_act], wu[:n_act],
                           wr[:n_act], hg[:n_act])
        keep = 0
        for a in range(n_act):
            m = active[a]
            k = down[m]
            dx = float(dirs[k, 0])
            dy = float(dirs[k, 1])
            dz = float(dirs[k, 2])
            f = oz + t[m] * dz - hg[a, 0]
            fp = min(dz - hg[a, 1] * dx - hg[a, 2] * dy, 0.2 * dz)
            tk = min(max(t[m] - f / fp, t_in[m]), t_out[m])
            step = abs(tk - t[m])
            t[m] = tk
            out[k, 1] = hg[a, 0]
            out[k, 2] = hg[a, 1]
            out[k, 3] = hg[a, 2]
            if not (guessed[m] and step < tol):
                active[keep] = m
                keep += 1
        n_act = keep
    for m in range(n):
        if t[m] < t_max:
            out[down[m], 0] = t[m]


@numba.njit(**NJIT)
def interpolate_guess(t_coarse: np.ndarray, rows: np.ndarray, cols: np.ndarray, height: int, width: int,
                      max_ratio: float, out: np.ndarray) -> None:
    """Bilinear interpolation of ray parameters traced on a coarse grid of an image's rays.

    Args:
        t_coarse: (R, C) float32 ``t`` at pixel rows ``rows`` (R,) and columns ``cols`` (C,) (increasing, first 0,
            last ``height - 1`` / ``width - 1``).
        max_ratio: no guess (NaN) where the four corners differ by more than this factor, or one is inf
            (the horizon, depth edges).
        out: (height * width,) float64 guesses.
    """
    i0 = 0
    for y in range(height):
        while i0 + 2 < rows.size and rows[i0 + 1] <= y:
            i0 += 1
        fy = (y - rows[i0]) / (rows[i0 + 1] - rows[i0])
        j0 = 0
        for x in range(width):
            while j0 + 2 < cols.size and cols[j0 + 1] <= x:
                j0 += 1
            fx = (x - cols[j0]) / (cols[j0 + 1] - cols[j0])
            a = float(t_coarse[i0, j0])
            b = float(t_coarse[i0, j0 + 1])
            c = float(t_coarse[i0 + 1, j0])
            d = float(t_coarse[i0 + 1, j0 + 1])
            lo = min(min(a, b), min(c, d))
            hi = max(max(a, b), max(c, d))
            if math.isfinite(hi) and lo > 0.0 and hi <= max_ratio * lo:
                out[y * width + x] = (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
            else:
                out[y * width + x] = np.nan
