"""Compiled kernels of the coarse-to-fine paper method (``inpaint.c2f``): the nearest-neighbour-field search,
candidate block sampling and overlap-averaged pasting. Single-threaded and deterministic (the random search uses a
fixed-seed linear congruential generator inside the kernel, not numpy's global state).

Block similarity (the paper's gradient-structure MSD plus the mean-removed depth term of ``inpaint.block_search``),
for a target block centred at t and a source block centred at s (half-size h, per-pixel target weights w):

    Sim = [ Σ_u w_u (1/C) Σ_c (F_c(t+u) − F_c(s+u))²  +  w_d Σ_u w_u (z_u − z̄)² ] / Σ_u w_u,
    z_u = D(s+u) − (D(t+u) − μ_t),  z̄ = Σ w z / Σ w,   μ_t = Σ w D(t+u) / Σ w

(the depth term is Σ w ((D_t − μ_t) − (D_s − μ_s))², written as the weighted variance of z). ``energy`` is the Sim of
a flat candidate (F = 0, constant D): the target's own structure energy.
"""

from __future__ import annotations

import numba
import numpy as np

from inpaint.jit import NJIT


@numba.njit(**NJIT)
def _sim(feat: np.ndarray, dep: np.ndarray, wt: np.ndarray, ty: int, tx: int, sy: int, sx: int, h: int,
         w_depth: float, inv_c: float, wsum: float, mu_t: float, bound: float) -> float:
    """Sim of target (ty, tx) vs source (sy, sx); stops early (returns inf) once the partial sum, checked after
    every block row, exceeds ``bound``. With C = 8 channels (the anisotropic features) the gradient part keeps one
    float64 accumulator per channel (eight independent chains instead of one serial one: the float64 sum is the same
    up to rounding order), added up at each row end."""
    c_n = feat.shape[2]
    acc = 0.0
    sz = 0.0
    szz = 0.0
    lim = bound * wsum
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 0.0
    for dy in range(-h, h + 1):
        for dx in range(-h, h + 1):
            w = wt[ty + dy, tx + dx]
            if w == 0.0:
                continue
            ft = feat[ty + dy, tx + dx]
            fs = feat[sy + dy, sx + dx]
            if c_n == 8:
                d0 = ft[0] - fs[0]
                d1 = ft[1] - fs[1]
                d2 = ft[2] - fs[2]
                d3 = ft[3] - fs[3]
                d4 = ft[4] - fs[4]
                d5 = ft[5] - fs[5]
                d6 = ft[6] - fs[6]
                d7 = ft[7] - fs[7]
                a0 += w * (d0 * d0)
                a1 += w * (d1 * d1)
                a2 += w * (d2 * d2)
                a3 += w * (d3 * d3)
                a4 += w * (d4 * d4)
                a5 += w * (d5 * d5)
                a6 += w * (d6 * d6)
                a7 += w * (d7 * d7)
            else:
                g = 0.0
                for c in range(c_n):
                    d = ft[c] - fs[c]
                    g += d * d
                a0 += w * g
            z = dep[sy + dy, sx + dx] - (dep[ty + dy, tx + dx] - mu_t)
            sz += w * z
            szz += w * z * z
        acc = (((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7))) * inv_c
        if acc > lim:
            return np.inf
    var = szz - sz * sz / wsum
    return (acc + w_depth * max(var, 0.0)) / wsum


@numba.njit(**NJIT)
def nnf_search(feat: np.ndarray, dep: np.ndarray, wt: np.ndarray, source_ok: np.ndarray, centres: np.ndarray,
               init: np.ndarray, nbr: np.ndarray, h: int, iters: int, rmax: int, seed: int, w_depth: float,
               best: np.ndarray, sim: np.ndarray, energy: np.ndarray) -> None:
    """PatchMatch (Barnes et al. 2009) over a grid of target blocks.

    ``feat`` H×W×C float32 features, ``dep`` H×W float32 depth (working units), ``wt`` H×W float32 target weights,
    ``source_ok`` H×W bool (a source block centred there lies in the source region), ``centres`` K×2 int (y, x)
    block centres (blocks inside the image), ``init`` K×M×2 int candidate source centres tried first (−1: none),
    ``nbr`` K×4 int neighbour block indices (left, up, right, down; −1: none). ``iters`` alternating scans
    (forward: propagate from left/up; backward: right/down), each followed by a random search at radii
    rmax, rmax/2, …, 1 around the current best. Outputs ``best`` K×2 (−1 if no source), ``sim`` K, ``energy`` K.
    """
    k_n = centres.shape[0]
    c_n = feat.shape[2]
    inv_c = 1.0 / c_n
    wsums = np.zeros(k_n)
    mus = np.zeros(k_n)
    state = np.uint64(seed) * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
    for k in range(k_n):
        ty, tx = centres[k, 0], centres[k, 1]
        s = 0.0
        sd = 0.0
        en = 0.0
        for dy in range(-h, h + 1):
            for dx in range(-h, h + 1):
                w = wt[ty + dy, tx + dx]
                s += w
                sd += w * dep[ty + dy, tx + dx]
        s = max(s, 1e-12)
        mu = sd / s
        ed = 0.0
        for dy in range(-h, h + 1):
            for dx in range(-h, h + 1):
                w = wt[ty + dy, tx + dx]
                g = 0.0
                for c in range(c_n):
                    g += feat[ty + dy, tx + dx, c] ** 2
                en += w * g * inv_c
                e = dep[ty + dy, tx + dx] - mu
                ed += w * e * e
        wsums[k] = s
        mus[k] = mu
        energy[k] = (en + w_depth * ed) / s
        best[k, 0] = -1
        best[k, 1] = -1
        sim[k] = np.inf
        for m in range(init.shape[1]):
            _try(feat, dep, wt, source_ok, k, ty, tx, init[k, m, 0], init[k, m, 1], h, w_depth, inv_c, s, mu, best,
                 sim)
    for it in range(iters):
        fwd = it % 2 == 0
        for kk in range(k_n):
            k = kk if fwd else k_n - 1 - kk
            ty, tx = centres[k, 0], centres[k, 1]
            for j in range(2):
                n = nbr[k, j] if fwd else nbr[k, 2 + j]
                if n < 0 or best[n, 0] < 0:
                    continue
                _try(feat, dep, wt, source_ok, k, ty, tx, ty + best[n, 0] - centres[n, 0],
                     tx + best[n, 1] - centres[n, 1], h, w_depth, inv_c, wsums[k], mus[k], best, sim)
            if best[k, 0] < 0:
                continue
            r = rmax
            while r >= 1:
                state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
                ry = int((state >> np.uint64(33)) % np.uint64(2 * r + 1)) - r
                state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
                rx = int((state >> np.uint64(33)) % np.uint64(2 * r + 1)) - r
                _try(feat, dep, wt, source_ok, k, ty, tx, best[k, 0] + ry, best[k, 1] + rx, h, w_depth, inv_c,
                     wsums[k], mus[k], best, sim)
                r //= 2


@numba.njit(**NJIT)
def _try(feat: np.ndarray, dep: np.ndarray, wt: np.ndarray, source_ok: np.ndarray, k: int, ty: int, tx: int,
         sy: int, sx: int, h: int, w_depth: float, inv_c: float, wsum: float, mu_t: float, best: np.ndarray,
         sim: np.ndarray) -> None:
    """Try source centre (sy, sx) for target block k: skipped when outside the image or the source region or
    already the best; taken when its Sim is lower than the best so far."""
    hh, ww = source_ok.shape
    if sy < 0 or sy >= hh or sx < 0 or sx >= ww or not source_ok[sy, sx]:
        return
    if sy == best[k, 0] and sx == best[k, 1]:
        return
    v = _sim(feat, dep, wt, ty, tx, sy, sx, h, w_depth, inv_c, wsum, mu_t, sim[k])
    if v < sim[k]:
        sim[k] = v
        best[k, 0] = sy
        best[k, 1] = sx


@numba.njit(**NJIT)
def sample_blocks(img: np.ndarray, centres: np.ndarray, h: int, inv_scale: float, offsets: np.ndarray,
                  out: np.ndarray) -> None:
    """out[k] (b×b, b = 2h+1) = bilinear samples of ``img`` at ((centre_k + u) · inv_scale + offset_k), u the
    block's pixel offsets, coordinates clamped to the image: the block of a finer level (centres in its pixels)
    read from ``img``, a level ``1/inv_scale`` times coarser. ``offsets`` K×2 float (y, x) in ``img`` pixels; rows
    with NaN offsets are left as they are."""
    hh, ww = img.shape
    for k in range(centres.shape[0]):
        oy, ox = offsets[k, 0], offsets[k, 1]
        if not (oy == oy):
            continue
        for dy in range(-h, h + 1):
            y = (centres[k, 0] + dy) * inv_scale + oy
            y = min(max(y, 0.0), hh - 1.0)
            y0 = min(int(y), hh - 2) if hh > 1 else 0
            fy = y - y0
            y1 = min(y0 + 1, hh - 1)
            for dx in range(-h, h + 1):
                x = (centres[k, 1] + dx) * inv_scale + ox
                x = min(max(x, 0.0), ww - 1.0)
                x0 = min(int(x), ww - 2) if ww > 1 else 0
                fx = x - x0
                x1 = min(x0 + 1, ww - 1)
                top = img[y0, x0] * (1.0 - fx) + img[y0, x1] * fx
                bot = img[y1, x0] * (1.0 - fx) + img[y1, x1] * fx
                out[k, dy + h, dx + h] = top * (1.0 - fy) + bot * fy


@numba.njit(**NJIT)
def anchor_blocks(est: np.ndarray, known: np.ndarray, centres: np.ndarray, h: int, w_anchor: np.float32,
                  cands: np.ndarray, est_blk: np.ndarray, known_blk: np.ndarray, clamp: bool = False) -> None:
    """Target blocks and candidate shift of a refinement pass: ``est_blk[k]`` / ``known_blk[k]`` (b×b, b = 2h+1)
    = ``est`` / ``known`` (H×W) around centre k; every candidate ``cands[k, s]`` (K×S×b×b, in place) is shifted by
    μ_t − μ_c, the difference of the target's and the candidate's weighted block means, weights 1 on measured
    pixels and ``w_anchor`` on estimated ones (float64 sums). ``clamp``: the shifted candidate is then clamped to
    the range of the values that exist in the unshifted candidate or in the target block (measured or estimated):
    the shift copies structure, but cannot invent a depth that neither the source nor the target holds (a block
    straddling a depth edge, shifted by the mean, would otherwise push its far side beyond anything measured)."""
    k_n, s_n, b, _ = cands.shape
    one = np.float32(1.0)
    for k in range(k_n):
        cy, cx = centres[k, 0] - h, centres[k, 1] - h
        ws = 0.0
        st = 0.0
        t_lo = np.float32(np.inf)
        t_hi = np.float32(-np.inf)
        for y in range(b):
            for x in range(b):
                kn = known[cy + y, cx + x]
                v = est[cy + y, cx + x]
                est_blk[k, y, x] = v
                known_blk[k, y, x] = kn
                w = one if kn else w_anchor
                ws += w
                st += w * v
                t_lo = min(t_lo, v)
                t_hi = max(t_hi, v)
        mu_t = st / ws
        for s in range(s_n):
            sc = 0.0
            lo = t_lo
            hi = t_hi
            for y in range(b):
                for x in range(b):
                    w = one if known_blk[k, y, x] else w_anchor
                    c = cands[k, s, y, x]
                    sc += w * c
                    lo = min(lo, c)
                    hi = max(hi, c)
            d = np.float32(mu_t - sc / ws)
            if clamp:
                for y in range(b):
                    for x in range(b):
                        cands[k, s, y, x] = min(max(cands[k, s, y, x] + d, lo), hi)
            else:
                for y in range(b):
                    for x in range(b):
                        cands[k, s, y, x] += d


@numba.njit(**NJIT)
def paste_blocks(blocks: np.ndarray, centres: np.ndarray, h: int, window: np.ndarray, acc: np.ndarray,
                 wacc: np.ndarray) -> None:
    """acc += window · block, wacc += window at every block's pixels (overlap averaging: acc / wacc)."""
    for k in range(centres.shape[0]):
        cy, cx = centres[k, 0], centres[k, 1]
        for dy in range(-h, h + 1):
            for dx in range(-h, h + 1):
                w = window[dy + h, dx + h]
                acc[cy + dy, cx + dx] += w * blocks[k, dy + h, dx + h]
                wacc[cy + dy, cx + dx] += w


@numba.njit(**NJIT)
def directional_means(nsum: np.ndarray, dsum: np.ndarray, idx: np.ndarray, oy: np.ndarray, ox: np.ndarray,
                      r: int, h: int, w: int, out: np.ndarray) -> None:
    """The anisotropic-gradient channels of ``inpaint.gradient.gradient_channels`` from precomputed region sums,
    in one pass over the pixels with the same float32 operations in the same order (bit-identical result).

    ``nsum`` / ``dsum``: U×(h+2r)×(w+2r) float32, Σ K·I and Σ K of each distinct region shape (top-left anchored,
    zero-padded image); region t·9 + j of template t (j = 0 centre, 1..8 directions) reads shape ``idx[t·9+j]``
    at offset (``oy``, ``ox``). ``out``: h×w×8 float32."""
    eps = np.float32(1e-6)
    third = np.float32(1.0 / 3.0)
    n_t = idx.shape[0] // 9
    acc = np.zeros((8, w), np.float32)
    mc = np.zeros(w, np.float32)
    mce = np.zeros(w, np.float32)
    for y in range(h):
        acc[:] = np.float32(0.0)
        for t in range(n_t):
            k = t * 9
            nrow = nsum[idx[k], r + y + oy[k], r + ox[k]:r + ox[k] + w]
            drow = dsum[idx[k], r + y + oy[k], r + ox[k]:r + ox[k] + w]
            for x in range(w):
                mc[x] = nrow[x] / (drow[x] + eps)
                mce[x] = mc[x] * eps
            for i in range(8):
                kk = k + 1 + i
                nrow = nsum[idx[kk], r + y + oy[kk], r + ox[kk]:r + ox[kk] + w]
                drow = dsum[idx[kk], r + y + oy[kk], r + ox[kk]:r + ox[kk] + w]
                for x in range(w):
                    acc[i, x] = acc[i, x] + (nrow[x] + mce[x]) / (drow[x] + eps)
            for i in range(8):
                for x in range(w):
                    acc[i, x] = acc[i, x] - mc[x]
        c_d = dsum[idx[0], r + y + oy[0], r + ox[0]:r + ox[0] + w]
        for x in range(w):
            unknown = c_d[x] <= np.float32(1e-3)
            for i in range(8):
                out[y, x, i] = np.float32(0.0) if unknown else acc[i, x] * third


@numba.njit(**NJIT)
def block_search(fd: np.ndarray, known: np.ndarray, source_ok: np.ndarray, centres: np.ndarray, t: int, r: int,
                 w_depth: float, best: np.ndarray, sim: np.ndarray, energy: np.ndarray) -> None:
    """Exhaustive masked block search of ``inpaint.block_search.search_level`` (the same Sim, evaluated directly
    in float64 instead of by correlation; results equal up to rounding), compiled, for the coarsest-level greedy
    fill of ``paper``.

    ``fd`` padded H×W×(C+1) float32 (C feature channels, then depth), ``known`` / ``source_ok`` padded H×W bool,
    ``centres`` K×2 int (padded (y, x)), template (2t+1)², window ± ``r``. For each target: the first candidate
    centre (row-major in the window) of least Sim = 1/(n·C) Σ_u M Σ_c (G^t − G^c)² + w_d/n Σ_u M (z − z̄)²
    (z = D^c − (D^t − μ^t)); a candidate is dropped as soon as its gradient part alone exceeds the best so far
    (a lower bound: both parts are sums of non-negative terms over rows). Outputs ``best`` K×2 (−1: none),
    ``sim`` K (inf: none), ``energy`` K (Sim of a flat candidate; 0 when there is none)."""
    c_n = fd.shape[2] - 1
    for k in range(centres.shape[0]):
        cy, cx = centres[k, 0], centres[k, 1]
        best[k, 0] = -1
        best[k, 1] = -1
        sim[k] = np.inf
        n = 0.0
        sd = 0.0
        sdd = 0.0
        eg = 0.0
        for dy in range(-t, t + 1):
            for dx in range(-t, t + 1):
                if known[cy + dy, cx + dx]:
                    n += 1.0
                    v = fd[cy + dy, cx + dx, c_n]
                    sd += v
                    sdd += v * v
                    for c in range(c_n):
                        eg += fd[cy + dy, cx + dx, c] ** 2
        if n < 1.0:
            energy[k] = 0.0
            continue
        mu = sd / n
        a = 1.0 / (n * c_n)
        b = w_depth / n
        energy[k] = a * eg + b * max(sdd - sd * mu, 0.0)
        bv = np.inf
        by = -1
        bx = -1
        for sy in range(cy - r, cy + r + 1):
            for sx in range(cx - r, cx + r + 1):
                if not source_ok[sy, sx]:
                    continue
                g = 0.0
                sz = 0.0
                szz = 0.0
                dropped = False
                for dy in range(-t, t + 1):
                    for dx in range(-t, t + 1):
                        if not known[cy + dy, cx + dx]:
                            continue
                        for c in range(c_n):
                            d = fd[cy + dy, cx + dx, c] - fd[sy + dy, sx + dx, c]
                            g += d * d
                        z = fd[sy + dy, sx + dx, c_n] - (fd[cy + dy, cx + dx, c_n] - mu)
                        sz += z
                        szz += z * z
                    if a * g >= bv:
                        dropped = True
                        break
                if dropped:
                    continue
                v = a * g + b * max(szz - sz * sz / n, 0.0)
                if v < bv:
                    bv = v
                    by = sy
                    bx = sx
        if by >= 0:
            best[k, 0] = by
            best[k, 1] = bx
            sim[k] = bv
        else:
            energy[k] = 0.0  # as ``search_level``: no candidate, no energy
