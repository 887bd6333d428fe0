"""The fusion network's inference form (``FusionNet.forward_valid``) as one compiled loop over blocks.

Same weights, same operations, same result to float32 rounding (≈ 1e-6 in normalised units, tested against
``forward_valid``): per block, the encoder on each valid scale (the target / hole part of its first convolution
once per block), the PLIP-softmax sum in the log domain, and the decoder, every intermediate map held in a small
per-call scratch buffer (a few kB: it stays in the L1 cache) instead of a batch of torch tensors. Why: the narrow
network of ``paper`` (4–8 channels on 11×11 blocks) is dominated by per-operator overhead in torch, not by
arithmetic.

Layout: every map is stored flat, channel-major, zero-padded to (b+2)×(b+2) pixels (the 3×3 convolutions'
zero padding). A 3×3 convolution is, per (output channel, input channel, tap), one contiguous multiply-add over the
flat interior span ``[bp+1, b·bp+b]`` (bp = b+2), which LLVM vectorises; the two pad columns that span crosses are
zeroed after each layer. IEEE float32 arithmetic (no fastmath), single-threaded: deterministic, bit-identical on
repeated calls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from inpaint.jit import NJIT


@dataclass(frozen=True)
class NetArrays:
    """The weights of a ``FusionNet`` as contiguous float32 numpy arrays (torch layout: out × in × 3 × 3).

    ``w0`` F×3×3×3 / ``b0`` F (first encoder convolution on [candidate, target, hole]); ``wd`` / ``bd``: the dense
    layers, packed: layer i's weights are ``wd[i]`` G×(F+D·G)×3×3 (input channels beyond F+i·G are unused) and
    ``bd[i]`` G; ``w1`` F×(F+D·G) / ``b1`` F (the 1×1 convolution); decoder ``v0`` H×(F+3)×3×3, ``v1`` H×H×3×3,
    ``v2`` 1×H×3×3 and biases ``c0`` H, ``c1`` H, ``c2`` 1; ``gamma`` (PLIP), ``alpha`` (softmax of α·q)."""

    w0: np.ndarray
    b0: np.ndarray
    wd: np.ndarray
    bd: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    v0: np.ndarray
    c0: np.ndarray
    v1: np.ndarray
    c1: np.ndarray
    v2: np.ndarray
    c2: np.ndarray
    gamma: float
    alpha: float


def net_arrays(net: object) -> NetArrays:
    """Extract the weights of a ``inpaint.fusion_net.FusionNet`` (duck-typed: no torch import here)."""

    def a(t: object) -> np.ndarray:
        return np.ascontiguousarray(t.detach().cpu().numpy(), np.float32)  # type: ignore[attr-defined]

    enc, dec = net.encoder, net.decoder  # type: ignore[attr-defined]
    dense = enc[2].layers
    f = enc[0].weight.shape[0]
    n_d = len(dense)
    g = dense[0][0].weight.shape[0] if n_d else 0
    wd = np.zeros((max(n_d, 1), max(g, 1), f + n_d * g, 3, 3), np.float32)
    bd = np.zeros((max(n_d, 1), max(g, 1)), np.float32)
    for i, layer in enumerate(dense):
        w = a(layer[0].weight)
        wd[i, :, :w.shape[1]] = w
        bd[i] = a(layer[0].bias)
    return NetArrays(a(enc[0].weight), a(enc[0].bias), wd, bd, a(enc[3].weight)[:, :, 0, 0], a(enc[3].bias),
                     a(dec[0].weight), a(dec[0].bias), a(dec[2].weight), a(dec[2].bias), a(dec[4].weight),
                     a(dec[4].bias), float(net.gamma), float(net.alpha.detach()))  # type: ignore[attr-defined]


def softmax_q(q: np.ndarray, valid: np.ndarray, alpha: float) -> np.ndarray:
    """w = softmax over valid scales of α·q (B×S float32, 0 on invalid scales), as ``FusionNet.scale_weights``."""
    logits = np.where(valid, np.float32(alpha) * q.astype(np.float32), np.float32(-1e9))
    logits = logits - logits.max(axis=1, keepdims=True)
    e = np.exp(logits)
    return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)


def run_net_compiled(arrs: NetArrays, cands: np.ndarray, target: np.ndarray, hole: np.ndarray, q: np.ndarray,
                     valid: np.ndarray) -> np.ndarray:
    """``FusionNet.forward_valid`` on normalised numpy blocks: ``cands`` B×S×b×b, ``target`` B×b×b (0 in the
    hole), ``hole`` B×b×b (bool or 0/1), ``q`` / ``valid`` B×S (at least one valid scale per block). Returns
    B×b×b float32 (normalised units)."""
    b_n, s_n, b, _ = cands.shape
    out = np.empty((b_n, b, b), np.float32)
    if b_n == 0:
        return out
    wts = softmax_q(q, valid, arrs.alpha)
    cands = np.ascontiguousarray(cands, np.float32)
    target = np.ascontiguousarray(target, np.float32)
    hole = np.ascontiguousarray(hole, np.float32)
    valid = np.ascontiguousarray(valid, np.bool_)
    _forward_blocks(cands, target, hole, wts, valid, arrs.w0, arrs.b0, arrs.wd, arrs.bd, arrs.w1, arrs.b1,
                    arrs.v0, arrs.c0, arrs.v1, arrs.c1, arrs.v2, arrs.c2, np.float32(arrs.gamma), out,
                    np.arange(b_n))
    return out


def fuse_clamped(arrs: NetArrays, cands: np.ndarray, est: np.ndarray, known: np.ndarray, q: np.ndarray,
                 valid: np.ndarray, alpha: float, tol: float, sigma_min: float) -> tuple[np.ndarray, np.ndarray]:
    """The clamped network fusion of ``paper`` (``inpaint.c2f._fuse``) in compiled passes; working units.

    ``cands`` K×S×b×b candidate blocks (shifted to the target), ``est`` K×b×b the current estimate of the target
    block, ``known`` K×b×b measured pixels, ``q`` / ``valid`` K×S. Per block: lo / hi = the per-pixel range of the
    valid candidates; where hi − lo ≤ ``tol``·max|hi| at every hole pixel the block's fusion is determined to that
    bound and it takes the softmax(``alpha``·q) mean, else the network runs on the block normalised as
    ``fusion_net.normalise`` does with every pixel of ``est`` as target (σ ≥ ``sigma_min``); the fused value is
    clamped to [lo, hi]. Returns (fused K×b×b float32, ran K bool: the network ran on the block)."""
    k_n, s_n, b, _ = cands.shape
    cands = np.ascontiguousarray(cands, np.float32)
    est = np.ascontiguousarray(est, np.float32)
    hole = np.ascontiguousarray(~known, np.float32)
    valid = np.ascontiguousarray(valid, np.bool_)
    wq = softmax_q(q, valid, alpha)
    out = np.empty((k_n, b, b), np.float32)
    run = np.zeros(k_n, np.bool_)
    cn = np.empty_like(cands)
    tn = np.empty_like(est)
    mu = np.zeros(k_n, np.float32)
    sg = np.ones(k_n, np.float32)
    lo = np.empty_like(est)
    hi = np.empty_like(est)
    _fuse_prep(cands, est, hole, valid, wq, np.float32(tol), np.float32(sigma_min), out, run, lo, hi, cn, tn, mu,
               sg)
    sel = np.flatnonzero(run)
    if len(sel):
        wn = softmax_q(q, valid, arrs.alpha)
        res = np.empty_like(est)
        _forward_blocks(cn, tn, hole, wn, valid, arrs.w0, arrs.b0, arrs.wd, arrs.bd, arrs.w1, arrs.b1, arrs.v0,
                        arrs.c0, arrs.v1, arrs.c1, arrs.v2, arrs.c2, np.float32(arrs.gamma), res, sel)
        _fuse_finish(res, sel, mu, sg, lo, hi, out)
    return out, run


@numba.njit(**NJIT)
def _fuse_prep(cands: np.ndarray, est: np.ndarray, hole: np.ndarray, valid: np.ndarray, wq: np.ndarray,
               tol: np.float32, sigma_min: np.float32, out: np.ndarray, run: np.ndarray, lo: np.ndarray,
               hi: np.ndarray, cn: np.ndarray, tn: np.ndarray, mu: np.ndarray, sg: np.ndarray) -> None:
    """Range, skip decision, softmax mean of skipped blocks and normalisation of the others (``fuse_clamped``)."""
    k_n, s_n, b, _ = cands.shape
    for k in range(k_n):
        spread = np.float32(0.0)
        scale = np.float32(0.0)
        for y in range(b):
            for x in range(b):
                lv = np.float32(np.inf)
                hv = np.float32(-np.inf)
                for s in range(s_n):
                    if valid[k, s]:
                        v = cands[k, s, y, x]
                        lv = min(lv, v)
                        hv = max(hv, v)
                lo[k, y, x] = lv
                hi[k, y, x] = hv
                if hole[k, y, x] > np.float32(0.0):
                    spread = max(spread, hv - lv)
                    scale = max(scale, abs(hv))
        run[k] = spread > tol * scale
        if not run[k]:
            for y in range(b):
                for x in range(b):
                    m = np.float32(0.0)
                    for s in range(s_n):
                        if valid[k, s]:
                            m += wq[k, s] * cands[k, s, y, x]
                    out[k, y, x] = min(max(m, lo[k, y, x]), hi[k, y, x])
            continue
        # fusion_net.normalise with every pixel of the estimate as target
        st = 0.0
        for y in range(b):
            for x in range(b):
                st += est[k, y, x]
        m = st / (b * b)
        dev = 0.0
        cnt = b * b
        for y in range(b):
            for x in range(b):
                dev += (est[k, y, x] - m) ** 2
        for s in range(s_n):
            if valid[k, s]:
                cnt += b * b
                for y in range(b):
                    for x in range(b):
                        dev += (cands[k, s, y, x] - m) ** 2
        sig = max(np.sqrt(dev / cnt), sigma_min)
        mu[k] = m
        sg[k] = sig
        inv = 1.0 / sig
        for y in range(b):
            for x in range(b):
                tn[k, y, x] = (est[k, y, x] - m) * inv
                for s in range(s_n):
                    cn[k, s, y, x] = (cands[k, s, y, x] - m) * inv


@numba.njit(**NJIT)
def _fuse_finish(res: np.ndarray, sel: np.ndarray, mu: np.ndarray, sg: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 out: np.ndarray) -> None:
    """out[k] = clamp(res[k]·σ_k + μ_k, lo[k], hi[k]) for k in ``sel``."""
    b = res.shape[1]
    for kk in range(sel.shape[0]):
        k = sel[kk]
        for y in range(b):
            for x in range(b):
                out[k, y, x] = min(max(res[k, y, x] * sg[k] + mu[k], lo[k, y, x]), hi[k, y, x])


@numba.njit(**NJIT)
def _conv(src: np.ndarray, c_in: int, w: np.ndarray, bias: np.ndarray, c_out: int, relu: bool, dst: np.ndarray,
          d0: int, bp: int, b: int) -> None:
    """dst[d0 + co] = (ReLU of) bias[co] + Σ_ci w[co, ci] ⋆ src[ci] (k×k, k = 1 or 3, zero padding; ``w``
    co×ci×k×k) over the interior span of the flat (bp·bp) maps; the pad columns inside the span are zeroed
    afterwards (rows 0 and bp−1 are never written: they stay 0).

    Four output channels and one kernel row per sweep over an input map, and unsigned indices in the hot loop (no
    negative-index wrap-around check): that is what lets LLVM vectorise it (≈ 10 GMAC/s vs ≈ 1 GMAC/s, measured)."""
    pp = bp * bp
    k = w.shape[2]
    r = k // 2
    p0 = bp + 1
    n = numba.uint64(b * bp + b + 1 - p0)
    sf = src.reshape(-1)
    df = dst.reshape(-1)
    co = 0
    while co < c_out:
        m = 4 if c_out - co >= 4 else 1
        a0 = numba.uint64((d0 + co) * pp + p0)
        for j in range(m):
            bv = bias[co + j]
            aj = a0 + numba.uint64(j * pp)
            for i in range(n):
                df[aj + i] = bv
        for ci in range(c_in):
            if k == 3:  # a whole kernel row (3 taps) per sweep: 3 loads for 12 (or 3) multiply-adds
                for ky in range(3):
                    s0 = numba.uint64(ci * pp + p0 + (ky - 1) * bp - 1)
                    s1 = s0 + numba.uint64(1)
                    s2 = s0 + numba.uint64(2)
                    if m == 4:
                        u0, u1, u2 = w[co, ci, ky, 0], w[co, ci, ky, 1], w[co, ci, ky, 2]
                        v0, v1, v2 = w[co + 1, ci, ky, 0], w[co + 1, ci, ky, 1], w[co + 1, ci, ky, 2]
                        t0, t1, t2 = w[co + 2, ci, ky, 0], w[co + 2, ci, ky, 1], w[co + 2, ci, ky, 2]
                        q0, q1, q2 = w[co + 3, ci, ky, 0], w[co + 3, ci, ky, 1], w[co + 3, ci, ky, 2]
                        a1 = a0 + numba.uint64(pp)
                        a2 = a1 + numba.uint64(pp)
                        a3 = a2 + numba.uint64(pp)
                        for i in range(n):
                            xa = sf[s0 + i]
                            xb = sf[s1 + i]
                            xc = sf[s2 + i]
                            df[a0 + i] += u0 * xa + u1 * xb + u2 * xc
                            df[a1 + i] += v0 * xa + v1 * xb + v2 * xc
                            df[a2 + i] += t0 * xa + t1 * xb + t2 * xc
                            df[a3 + i] += q0 * xa + q1 * xb + q2 * xc
                    else:
                        u0, u1, u2 = w[co, ci, ky, 0], w[co, ci, ky, 1], w[co, ci, ky, 2]
                        for i in range(n):
                            df[a0 + i] += u0 * sf[s0 + i] + u1 * sf[s1 + i] + u2 * sf[s2 + i]
                continue
            for ky in range(k):
                for kx in range(k):
                    s0 = numba.uint64(ci * pp + p0 + (ky - r) * bp + (kx - r))
                    if m == 4:
                        w0 = w[co, ci, ky, kx]
                        w1 = w[co + 1, ci, ky, kx]
                        w2 = w[co + 2, ci, ky, kx]
                        w3 = w[co + 3, ci, ky, kx]
                        a1 = a0 + numba.uint64(pp)
                        a2 = a1 + numba.uint64(pp)
                        a3 = a2 + numba.uint64(pp)
                        for i in range(n):
                            x = sf[s0 + i]
                            df[a0 + i] += w0 * x
                            df[a1 + i] += w1 * x
                            df[a2 + i] += w2 * x
                            df[a3 + i] += w3 * x
                    else:
                        w0 = w[co, ci, ky, kx]
                        for i in range(n):
                            df[a0 + i] += w0 * sf[s0 + i]
        for j in range(m):
            aj = a0 + numba.uint64(j * pp)
            if relu:
                for i in range(n):
                    v = df[aj + i]
                    df[aj + i] = v if v > np.float32(0.0) else np.float32(0.0)
            acc = dst[d0 + co + j]
            for y in range(1, b):  # pad columns crossed by the span: x = bp−1 of row y and x = 0 of row y+1
                acc[y * bp + bp - 1] = np.float32(0.0)
                acc[(y + 1) * bp] = np.float32(0.0)
        co += m


@numba.njit(**NJIT)
def _exp_inplace(buf: np.ndarray, n: int, ib: np.ndarray) -> None:
    """buf[:n] = exp(buf[:n]) (float32, arguments clipped to ±87): Cody–Waite reduction, degree-7 Taylor
    polynomial, 2^k from the exponent bits (relative error < 1e-7 measured); vectorisable, unlike libm calls."""
    fb = ib.view(np.float32)
    for i in range(numba.uint64(n)):
        v = min(max(buf[i], np.float32(-87.0)), np.float32(87.0))
        t = np.floor(v * np.float32(1.4426950408889634) + np.float32(0.5))
        r = v - t * np.float32(0.693145751953125) - t * np.float32(1.428606765330187e-06)
        p = np.float32(1.0 / 5040.0)
        p = p * r + np.float32(1.0 / 720.0)
        p = p * r + np.float32(1.0 / 120.0)
        p = p * r + np.float32(1.0 / 24.0)
        p = p * r + np.float32(1.0 / 6.0)
        p = p * r + np.float32(0.5)
        p = p * r + np.float32(1.0)
        buf[i] = p * r + np.float32(1.0)
        ib[i] = (np.int32(t) + np.int32(127)) << np.int32(23)
    for i in range(numba.uint64(n)):
        buf[i] *= fb[i]


@numba.njit(**NJIT)
def _log_inplace(buf: np.ndarray, n: int, ib: np.ndarray) -> None:
    """buf[:n] = log(buf[:n]) for positive normal float32: exponent from the bits, mantissa in [√½, √2), atanh
    series to s⁹ (absolute error < 1e-6 measured); vectorisable."""
    xb = buf.view(np.int32)
    fb = ib.view(np.float32)
    for i in range(numba.uint64(n)):
        bits = xb[i]
        ib[i] = (bits & np.int32(0x7FFFFF)) | np.int32(0x3F800000)
        buf[i] = np.float32((bits >> np.int32(23)) - np.int32(127))
    for i in range(numba.uint64(n)):
        m = fb[i]
        e = buf[i]
        big = m > np.float32(1.4142135)
        m = m * np.float32(0.5) if big else m
        e = e + np.float32(1.0) if big else e
        f = m - np.float32(1.0)
        s = f / (np.float32(2.0) + f)
        z = s * s
        p = np.float32(2.0 / 9.0)
        p = p * z + np.float32(2.0 / 7.0)
        p = p * z + np.float32(2.0 / 5.0)
        p = p * z + np.float32(2.0 / 3.0)
        p = p * z + np.float32(2.0)
        buf[i] = e * np.float32(0.693145751953125) + (s * p + e * np.float32(1.428606765330187e-06))


@numba.njit(**NJIT)
def _forward_blocks(cands: np.ndarray, target: np.ndarray, hole: np.ndarray, wts: np.ndarray, valid: np.ndarray,
                    w0: np.ndarray, b0: np.ndarray, wd: np.ndarray, bd: np.ndarray, w1: np.ndarray, b1: np.ndarray,
                    v0: np.ndarray, c0: np.ndarray, v1: np.ndarray, c1: np.ndarray, v2: np.ndarray, c2: np.ndarray,
                    gamma: np.float32, out: np.ndarray, sel: np.ndarray) -> None:
    """For each block k in ``sel``: shared part of the first encoder convolution; per valid scale the encoder up to its
    sigmoid and the PLIP term w·log(1 − F/γ) with F = γ(1 − 1e-4)·sigmoid(pre), i.e. log((e + 1e-4)/(1 + e)),
    e = exp(−pre) (no cancellation); fused = γ·(1 − exp(Σ terms)); then the decoder on [fused, target, hole, base] and
    out = base + residual, base = Σ_s w_s cands[s]."""
    b_n, s_n, b, _ = cands.shape
    f_n = w0.shape[0]
    n_dense = bd.shape[0] if wd.shape[2] > f_n else 0
    g_n = bd.shape[1]
    cat_n = f_n + n_dense * g_n
    h_n = v0.shape[0]
    bp = b + 2
    pp = bp * bp
    zero = np.zeros(f_n, np.float32)
    inp = np.zeros((3, pp), np.float32)  # candidate, target, hole (zero-padded)
    shared = np.zeros((f_n, pp), np.float32)
    cat = np.zeros((cat_n, pp), np.float32)
    pre = np.zeros((f_n, pp), np.float32)
    logsum = np.zeros((f_n, pp), np.float32)
    dec = np.zeros((f_n + 3, pp), np.float32)  # fused, target, hole, base
    h1 = np.zeros((h_n, pp), np.float32)
    h2 = np.zeros((h_n, pp), np.float32)
    res = np.zeros((1, pp), np.float32)
    ib = np.zeros(f_n * pp, np.int32)
    w0s = np.ascontiguousarray(w0[:, 1:3])
    w0c = np.ascontiguousarray(w0[:, 0:1])
    w1k = np.ascontiguousarray(w1.reshape(w1.shape[0], w1.shape[1], 1, 1))
    pre_f = pre.reshape(-1)
    cat_f = cat.reshape(-1)
    shared_f = shared.reshape(-1)
    log_f = logsum.reshape(-1)
    nf = f_n * pp
    eps = np.float32(1e-4)
    one = np.float32(1.0)
    for kk in range(sel.shape[0]):
        k = sel[kk]
        for y in range(b):
            for x in range(b):
                i = (y + 1) * bp + x + 1
                inp[1, i] = target[k, y, x]
                inp[2, i] = hole[k, y, x]
                bs = np.float32(0.0)
                for s in range(s_n):
                    bs += wts[k, s] * cands[k, s, y, x]
                dec[f_n + 2, i] = bs
        _conv(inp[1:3], 2, w0s, b0, f_n, False, shared, 0, bp, b)
        log_f[:] = np.float32(0.0)
        for s in range(s_n):
            if not valid[k, s]:
                continue
            for y in range(b):
                for x in range(b):
                    inp[0, (y + 1) * bp + x + 1] = cands[k, s, y, x]
            _conv(inp[0:1], 1, w0c, zero, f_n, False, cat, 0, bp, b)
            for i in range(numba.uint64(nf)):  # ReLU(own + shared): channels 0..F−1 of ``cat``
                v = cat_f[i] + shared_f[i]
                cat_f[i] = v if v > np.float32(0.0) else np.float32(0.0)
            for i in range(n_dense):
                _conv(cat, f_n + i * g_n, wd[i], bd[i], g_n, True, cat, f_n + i * g_n, bp, b)
            _conv(cat, cat_n, w1k, b1, f_n, False, pre, 0, bp, b)
            for i in range(numba.uint64(nf)):
                pre_f[i] = -pre_f[i]
            _exp_inplace(pre_f, nf, ib)
            for i in range(numba.uint64(nf)):
                e = pre_f[i]
                pre_f[i] = (e + eps) / (e + one)
            _log_inplace(pre_f, nf, ib)
            ws = wts[k, s]
            for i in range(numba.uint64(nf)):
                log_f[i] += ws * pre_f[i]
        _exp_inplace(log_f, nf, ib)
        for c in range(f_n):
            for y in range(b):
                for x in range(b):
                    i = (y + 1) * bp + x + 1
                    dec[c, i] = gamma * (one - logsum[c, i])
        dec[f_n] = inp[1]
        dec[f_n + 1] = inp[2]
        _conv(dec, f_n + 3, v0, c0, h_n, True, h1, 0, bp, b)
        _conv(h1, h_n, v1, c1, h_n, True, h2, 0, bp, b)
        _conv(h2, h_n, v2, c2, 1, False, res, 0, bp, b)
        for y in range(b):
            for x in range(b):
                i = (y + 1) * bp + x + 1
                out[k, y, x] = dec[f_n + 2, i] + res[0, i]
