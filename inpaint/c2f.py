"""The paper's depth inpainting, coarse-to-fine: the method ``paper`` (``paper-greedy`` is ``inpaint.method``).

The paper assigns global shapes and large structures to the coarse levels (1/4, 1/8) and textures and details to
the fine ones (1/1, 1/2). This formulation keeps every component of the paper and changes the order of work:

1. Masked Gaussian pyramid of the working map (inverse depth u = 10 m / depth, as ``paper-greedy``), levels
   0..L_max (L_max = ``levels``, fewer on small images). A level-L pixel is known when ≥ 50 % of its Gaussian
   support was known.
2. **Coarsest level**: filled completely by ``paper-greedy``'s priority-ordered multi-scale block search (fill
   front, scale-adaptive priority P = max_L λ^(L) C^(L) D^(L) 1_match(L) with λ^(L) = 2^−L, anisotropic-gradient
   similarity, 1_match fall-back, fusion) on 1/64 of the pixels, where the order of filling matters; its block
   search is the compiled ``c2f_kernels.block_search`` (the same Sim and the same blocks as
   ``block_search.search_level``, without the per-block Python calls).
3. **Each finer level L** (L_max−1 … 0): the hole is initialised by bilinear upsampling of the coarser result, then
   ``passes[L]`` parallel passes refine *all* hole blocks at once:

   - features: the 8 directional anisotropic-gradient means × 3 templates (``inpaint.gradient``, box filters) of the
     current estimate, computed once per pass (``gradient.anisotropic_channels_fast``, bit-identical);
   - NNF search (``c2f_kernels.nnf_search``, compiled): PatchMatch propagation + random search over a grid of
     blocks (``block`` at level 0, smaller at coarser levels, ``overlap`` pixels of overlap) that covers the hole;
     sources are blocks lying wholly in the known region of that level; initialised from the coarser level's
     field (offsets × 2), the nearest source block and the previous pass; similarity = the paper's
     gradient-structure MSD + ``w_depth`` × mean-removed depth MSD, target pixels weighted 1 (known) or
     ``w_estimate`` (estimated);
   - candidates: the best block at this level and, for each coarser level, the best block that level's field holds
     at the same place (sampled at that level and upsampled bilinearly), each shifted to the block mean of the
     measured pixels (estimated ones weigh ``w_anchor``, so a block without measured pixels keeps the estimate's
     mean) and clamped to the values of the source and the target block (``shift_clamp``); quality
     q = −min(Sim/energy, 10), valid where Sim/energy < ``match_threshold`` (1_match), else
     the levels that found any block (fall-back), else the current estimate;
   - fusion of the candidates (``fusion``): the PLIP-softmax network (one compiled call per pass,
     ``fusion_kernels.fuse_clamped``: the inference form ``FusionNet.forward_valid`` of the same weights as one
     numba loop over blocks, equal to it to 1e-5; ``COMPILED_NET = False`` runs torch instead; its own weights,
     trained on the candidates of this formulation, ``weights/fusion_net_c2f.pt``), the softmax(α·q) mean, or the
     best block. With the network, a block whose
     valid candidates agree to ``FUSE_TOL`` at every hole pixel (or that has a single one) takes the softmax mean:
     the network's output is clamped to the candidates' range, so that changes no value by more than the tolerance;
   - paste: overlap averaging with a tent window into hole pixels only, clipped to the range of the measured
     values.

Known pixels are returned unchanged; the output is deterministic (single-threaded kernels with a fixed-seed
generator, one torch thread).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from inpaint.block_search import LevelGrid, SearchResult
from inpaint.c2f_kernels import anchor_blocks, block_search, nnf_search, paste_blocks, sample_blocks
from inpaint.errors import InpaintInputError
from inpaint.fusion import softmax_weights
from inpaint.fusion_kernels import NetArrays, fuse_clamped, net_arrays, run_net_compiled
from inpaint.fusion_net import SIGMA_MIN, WEIGHTS_DIR, load_net, normalise, run_net
from inpaint.gradient import anisotropic_channels_fast, gradient_channels
from inpaint.method import PaperOptions, _Filler, check_shared_options, fill_in_domain, options_from_kwargs
from inpaint.pyramid import masked_pyrdown

C2F_WEIGHTS_FILE = WEIGHTS_DIR / "fusion_net_c2f.pt"
ENERGY_EPS = 1e-4
Q_CLIP = 10.0
MIN_COARSE_SIDE = 24  # the coarsest level keeps at least this many pixels on its short side
NET_CHUNK = 128  # blocks per network forward call (measured fastest of 48/128/512)
NATIVE_CONV = False  # oneDNN convolutions: 3–6 % less CPU per frame than torch's native ones (measured)
COMPILED_NET = True  # the network as one compiled loop (``inpaint.fusion_kernels``) instead of torch
FUSE_TOL = 1e-3  # relative candidate spread below which a block's fusion is determined (see ``_fuse``)


@dataclass(frozen=True)
class C2FOptions:
    """Options of the coarse-to-fine method (defaults in brackets).

    - levels [3]: L_max (1/1 … 1/2^L_max; fewer when the image is small); single_scale [False]: ablation, every
      fusion uses only the block of its own level (and the coarsest fill searches one level).
    - block [11]: level-0 block (odd); coarser levels use ``max(7, block/2^L + 3)`` rounded to odd.
    - overlap [2]: overlap of neighbouring blocks (pixels); passes [(1, 1, 1)]: refinement passes at levels 0, 1, 2…
      (last value repeats); iters [1]: PatchMatch scans per pass (2: simulator hole RMSE 1.3 % lower, ≈ 10 %
      slower, measured); search [(4, 8, 16, 16)]: random-search radius per level (level pixels, last repeats).
    - gradient ["anisotropic"|"sobel"]; fusion ["net"|"mean"|"best"]; w_depth [1.0]; match_threshold [1.0];
      alpha [4.0]; w_estimate [0.5]: similarity weight of estimated (not measured) target pixels; w_anchor [0.01]:
      their weight in the mean that candidates are shifted to (measured pixels weigh 1).
    - coarse_block [7], coarse_levels [2], coarse_radius [(6, 5, 4)], coarse_max_blocks [64]: the greedy fill of
      the coarsest level (``paper-greedy``'s block, levels, radius and blocks per round there); coarse_fusion
      ["best"; None = ``fusion``] its fusion (``paper-greedy``'s network is trained on full-resolution blocks; at the
      coarsest level the best block was measured better: simulator hole RMSE 0.822 vs 0.888 m, and faster).
    - domain ["inverse"|"depth"]; weights [None]: fusion weights of the fine levels (None = shipped
      ``fusion_net_c2f.pt``); coarse_weights [None]: those of the greedy coarsest fill (None = ``fusion_net.pt``).
    - seed [0]: seed of the random search (the output is deterministic for a given seed); clamp_fusion [True]: the
      network's fused value of a pixel is kept within the range of the valid candidates there; scales [4]: candidate
      levels per pass (this level and the next coarser ones; fewer is faster and measured worse).
    - shift_clamp [True]: a candidate shifted to the target's anchored mean is clamped to the range of the values of
      its unshifted block and of the target block (measured and estimated): structure is copied, but no depth that
      neither holds is invented. Without it a block straddling a depth edge, shifted by its mean, pushed its far side
      beyond anything measured, up to the farthest (noisiest) measured depth — with stereo noise hundreds of metres
      (issue 12, generalisation: stereo-noise hole RMSE 1.77 → 1.06 m).
    """

    levels: int = 3
    single_scale: bool = False
    block: int = 11
    overlap: int = 2
    passes: tuple[int, ...] = (1, 1, 1)
    iters: int = 1
    search: tuple[int, ...] = (4, 8, 16, 16)
    gradient: str = "anisotropic"
    fusion: str = "net"
    w_depth: float = 1.0
    match_threshold: float = 1.0
    alpha: float = 4.0
    w_estimate: float = 0.5
    w_anchor: float = 0.01
    coarse_block: int = 7
    coarse_levels: int = 2
    coarse_radius: tuple[int, ...] = (6, 5, 4)
    coarse_max_blocks: int = 64
    coarse_fusion: str | None = "best"
    domain: str = "inverse"
    weights: str | None = None
    coarse_weights: str | None = None
    seed: int = 0
    clamp_fusion: bool = True
    scales: int = 4
    shift_clamp: bool = True

    @classmethod
    def from_kwargs(cls, **options: object) -> C2FOptions:
        return options_from_kwargs(cls, "paper", options, tuple_fields=("passes", "search", "coarse_radius"))

    def check(self) -> None:
        check_shared_options(self, blocks=("block", "coarse_block"))
        if not self.passes or min(self.passes) < 0 or not self.search or min(self.search) < 0 or self.iters < 0:
            raise InpaintInputError("passes, search and iters must be non-negative (and passes/search non-empty)")
        if not 0 <= self.overlap < self.block // 2 or self.w_depth < 0 or self.match_threshold <= 0:
            raise InpaintInputError("overlap must be in [0, block/2), w_depth ≥ 0 and match_threshold > 0")
        if not 0 < self.w_estimate <= 1:
            raise InpaintInputError(f"w_estimate must be in (0, 1], got {self.w_estimate}")


# Called once per pass with the blocks about to be fused: (level, centres K×2 (y, x) at that level, cands K×S×b×b,
# estimate K×b×b, known K×b×b, q K×S, valid K×S), working units. Used by training to collect examples.
PassObserver = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]


def inpaint_paper_c2f(depth: np.ndarray, mask: np.ndarray, guide: np.ndarray | None = None,
                      observer: PassObserver | None = None, **options: object) -> np.ndarray:
    """Fill ``mask`` (bool H×W, True = hole) of ``depth`` (float32 H×W, metres) with the coarse-to-fine method.

    ``guide`` is validated but not used (the method works on depth only). Known pixels are returned unchanged.
    """
    opts = C2FOptions.from_kwargs(**options)
    return fill_in_domain(depth, mask, guide, opts.domain,
                          lambda work, hole: _CoarseToFine(work, hole, opts, observer).run())


def _search_compiled(grid: LevelGrid, centres: np.ndarray, w_depth: float = 1.0) -> SearchResult:
    """``block_search.search_level`` as one compiled call (``c2f_kernels.block_search``)."""
    k_n = len(centres)
    best = np.full((k_n, 2), -1, np.intp)
    sim = np.full(k_n, np.inf)
    energy = np.zeros(k_n)
    if k_n:
        block_search(grid.fd, grid.known, grid.source_ok, np.ascontiguousarray(centres, np.intp), grid.t, grid.r,
                     float(w_depth), best, sim, energy)
    return SearchResult(best, sim, energy)


class _CoarseFiller(_Filler):
    """``paper-greedy``'s fill with the compiled block search: the coarsest level of ``paper``."""

    search = staticmethod(_search_compiled)


def _odd(v: float) -> int:
    n = int(round(v))
    return n if n % 2 == 1 else n + 1


@dataclass
class _LevelField:
    """The final nearest-neighbour field of one level: block grid and best sources (level pixels)."""

    h: int
    stride: int
    ys: np.ndarray  # grid rows of block centres
    xs: np.ndarray
    gid: np.ndarray  # len(ys)×len(xs) → block index or −1
    centres: np.ndarray  # K×2
    best: np.ndarray  # K×2 (−1: none)
    e: np.ndarray  # K: Sim/energy (inf: none)

    def lookup(self, pts: np.ndarray) -> np.ndarray:
        """Block index (−1: none) of the grid cell nearest to each (float) point (N×2, level pixels)."""
        i = np.clip(np.rint((pts[:, 0] - self.ys[0]) / self.stride), 0, len(self.ys) - 1).astype(np.intp)
        j = np.clip(np.rint((pts[:, 1] - self.xs[0]) / self.stride), 0, len(self.xs) - 1).astype(np.intp)
        return self.gid[i, j]


def _axis(n: int, h: int, stride: int) -> np.ndarray:
    pos = list(range(h, n - h, stride))
    if not pos or pos[-1] != n - 1 - h:
        pos.append(n - 1 - h)
    return np.array(pos, np.intp)


def _block_grid(hole: np.ndarray, h: int, stride: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    """Grid of (2h+1)² blocks, ``stride`` apart, that contain a hole pixel: (ys, xs, gid, centres K×2, nbr K×4)."""
    hh, ww = hole.shape
    ys, xs = _axis(hh, h, stride), _axis(ww, h, stride)
    ii = cv2.integral(hole.astype(np.uint8))
    y0, y1 = ys - h, ys + h + 1
    x0, x1 = xs - h, xs + h + 1
    cnt = ii[y1][:, x1] - ii[y0][:, x1] - ii[y1][:, x0] + ii[y0][:, x0]
    keep = cnt > 0
    gid = np.full(keep.shape, -1, np.intp)
    gi, gj = np.nonzero(keep)
    gid[gi, gj] = np.arange(len(gi))
    centres = np.stack([ys[gi], xs[gj]], 1).astype(np.intp)
    pad = np.pad(gid, 1, constant_values=-1)
    nbr = np.stack([pad[gi + 1, gj], pad[gi, gj + 1], pad[gi + 1, gj + 2], pad[gi + 2, gj + 1]], 1)  # l, u, r, d
    return ys, xs, gid, centres, nbr.astype(np.intp)


class _CoarseToFine:
    def __init__(self, work: np.ndarray, hole: np.ndarray, opts: C2FOptions,
                 observer: PassObserver | None) -> None:
        self.o = opts
        self.observer = observer
        known_vals = work[~hole]
        self.value_range = (float(known_vals.min()), float(known_vals.max()))
        # masked pyramid: level-L depth and known mask
        self.d = [work.astype(np.float32)]
        self.known = [~hole]
        wgt = (~hole).astype(np.float32)
        d = self.d[0]
        while len(self.d) <= opts.levels and min(d.shape) // 2 >= MIN_COARSE_SIDE:
            d, wgt = masked_pyrdown(d, wgt)
            self.d.append(d)
            self.known.append(wgt >= 0.5)
        self.n_lv = len(self.d)
        self.fields: list[_LevelField | None] = [None] * self.n_lv
        self.est: list[np.ndarray | None] = [None] * self.n_lv

    def _h(self, lv: int) -> int:
        h = self.o.block // 2 if lv == 0 else _odd(max(7.0, self.o.block / 2 ** lv + 3)) // 2
        return min(h, (min(self.d[lv].shape) - 1) // 2)

    def run(self) -> np.ndarray:
        o = self.o
        top = self.n_lv - 1
        kt = self.known[top]
        if kt.all():
            est = self.d[top].copy()
        elif not kt.any():  # nothing survives at the coarsest level: constant fill with the known mean
            est = np.full(kt.shape, float(self.d[0][self.known[0]].mean()), np.float32)
        else:
            popts = PaperOptions(levels=0 if o.single_scale else o.coarse_levels, single_scale=o.single_scale,
                                 block=min(o.coarse_block, (min(kt.shape) - 1) // 2 * 2 + 1),
                                 radius=o.coarse_radius, gradient=o.gradient,
                                 fusion=o.coarse_fusion or o.fusion, w_depth=o.w_depth,
                                 match_threshold=o.match_threshold,
                                 alpha=o.alpha, weights=o.coarse_weights, max_blocks=o.coarse_max_blocks)
            est = _CoarseFiller(np.where(kt, self.d[top], 0).astype(np.float32), ~kt, popts, None).run()
        np.clip(est, *self.value_range, out=est)
        self.est[top] = est
        if top > 0:  # the coarsest level's field, for the candidates of the finer levels
            self._pass(top, est, fuse_paste=False)
        for lv in range(top - 1, -1, -1):
            est = self._upsample(self.est[lv + 1], self.d[lv].shape)
            est = np.where(self.known[lv], self.d[lv], est).astype(np.float32)
            n_pass = o.passes[min(lv, len(o.passes) - 1)]
            if n_pass == 0:
                self._pass(lv, est, fuse_paste=False)
            for _ in range(n_pass):
                est = self._pass(lv, est, fuse_paste=True)
            self.est[lv] = est
        return self.est[0]

    @staticmethod
    def _upsample(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        hh, ww = shape
        my, mx = np.mgrid[0:hh, 0:ww].astype(np.float32)
        return cv2.remap(img, mx * 0.5, my * 0.5, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _pass(self, lv: int, est: np.ndarray, fuse_paste: bool) -> np.ndarray:
        o = self.o
        h = self._h(lv)
        b = 2 * h + 1
        known = self.known[lv]
        hole = ~known
        hh, ww = est.shape
        stride = max(1, b - o.overlap)
        ys, xs, gid, centres, nbr = _block_grid(hole, h, stride)
        k_n = len(centres)
        feat = anisotropic_channels_fast(est) if o.gradient == "anisotropic" else gradient_channels(est, None,
                                                                                                     o.gradient)
        wt = np.where(known, np.float32(1.0), np.float32(o.w_estimate)).astype(np.float32)
        src = cv2.erode(known.astype(np.uint8), np.ones((b, b), np.uint8), borderType=cv2.BORDER_CONSTANT,
                        borderValue=0) > 0
        # initial sources: previous field of this level, the coarser level's field (offsets × 2), nearest source
        init = np.full((k_n, 3, 2), -1, np.intp)
        prev = self.fields[lv]
        if prev is not None and len(prev.centres) == k_n:
            init[:, 0] = prev.best
        if lv + 1 < self.n_lv and self.fields[lv + 1] is not None:
            cf = self.fields[lv + 1]
            j = cf.lookup(centres / 2.0)
            ok = (j >= 0)
            ok[ok] = cf.best[j[ok], 0] >= 0
            jj = j[ok]
            init[ok, 1] = centres[ok] + 2 * (cf.best[jj] - cf.centres[jj])
        if src.any() and (lv == self.n_lv - 1 or (init[:, 1, 0] < 0).any()):  # else the coarse init suffices
            init[:, 2] = _nearest(src, centres)
        best = np.full((k_n, 2), -1, np.intp)
        sim = np.full(k_n, np.inf)
        energy = np.zeros(k_n)
        rmax = o.search[min(lv, len(o.search) - 1)]
        nnf_search(np.ascontiguousarray(feat, np.float32), est, wt, src, centres, init, nbr, h, o.iters, rmax,
                   o.seed * 1000 + lv, float(o.w_depth), best, sim, energy)
        e = np.where(best[:, 0] >= 0, sim / (energy + ENERGY_EPS), np.inf)
        self.fields[lv] = _LevelField(h, stride, ys, xs, gid, centres, best, e)
        if not fuse_paste:
            return est
        # candidates: this level's block, then each coarser level's (upsampled)
        scales = [lv] if o.single_scale else list(range(lv, min(self.n_lv, lv + o.scales)))
        s_n = len(scales)
        cands = np.zeros((k_n, s_n, b, b), np.float32)
        q = np.full((k_n, s_n), -Q_CLIP, np.float32)
        found = np.zeros((k_n, s_n), bool)
        for si, lc in enumerate(scales):
            f = self.fields[lc]
            k = 2 ** (lc - lv)
            if lc == lv:
                j = np.arange(k_n)
            else:
                j = f.lookup(centres / float(k))
            ok = j >= 0
            ok[ok] = f.best[j[ok], 0] >= 0
            off = np.full((k_n, 2), np.nan)
            jj = j[ok]
            off[ok] = f.best[jj] - f.centres[jj]
            sample_blocks(self.est[lc] if lc != lv else est, centres, h, 1.0 / k, off, cands[:, si])
            found[:, si] = ok
            q[ok, si] = -np.minimum(f.e[jj], Q_CLIP)
        valid = found & (q > -o.match_threshold)
        none = ~valid.any(axis=1)
        valid[none] = found[none]  # 1_match fall-back: every level that found a block
        off = np.arange(-h, h + 1)
        # the target block (estimate, measured mask) and every candidate shifted to its anchored mean
        est_blk = np.empty((k_n, b, b), np.float32)
        known_blk = np.empty((k_n, b, b), bool)
        anchor_blocks(est, known, centres, h, np.float32(o.w_anchor), cands, est_blk, known_blk, o.shift_clamp)
        still = ~valid.any(axis=1)
        if still.any():  # no block anywhere: keep the current estimate
            cands[still, 0] = est_blk[still]
            valid[still, 0] = True
            q[still, 0] = 0.0
        if self.observer is not None:
            self.observer(lv, centres, cands, est_blk, known_blk, q, valid)
        fill = _fuse(o, cands, est_blk, known_blk, q, valid)
        np.clip(fill, *self.value_range, out=fill)
        tent = (h + 1 - np.abs(off)).astype(np.float32)
        window = np.outer(tent, tent).astype(np.float32)
        acc = np.zeros((hh, ww), np.float32)
        wacc = np.zeros((hh, ww), np.float32)
        paste_blocks(fill, centres, h, window, acc, wacc)
        upd = hole & (wacc > 0)
        out = est.copy()
        out[upd] = acc[upd] / wacc[upd]
        return out


def _nearest(src: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """For each point (N×2 int (y, x)), a nearby pixel of ``src`` (bool H×W, at least one True): the one whose
    label OpenCV's distance transform (5×5 mask, approximately Euclidean) assigns there. N×2 int."""
    _, lab = cv2.distanceTransformWithLabels((~src).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                             labelType=cv2.DIST_LABEL_PIXEL)
    seeds = np.argwhere(src)  # labels number the zero pixels (here: the sources) in raster order, from 1
    return seeds[lab[pts[:, 0], pts[:, 1]] - 1]


@lru_cache(maxsize=4)
def _net_arrays(path: str) -> NetArrays:
    """The compiled network's weights of ``load_net(path)``."""
    return net_arrays(load_net(path))


def _fuse(o: C2FOptions, cands: np.ndarray, est_blk: np.ndarray, known_blk: np.ndarray, q: np.ndarray,
          valid: np.ndarray) -> np.ndarray:
    if o.fusion == "best":
        qq = np.where(valid, q, -np.inf)
        return cands[np.arange(len(cands)), np.argmax(qq, axis=1)].astype(np.float32)
    if o.fusion == "mean":
        w = softmax_weights(q, valid, o.alpha)
        return (w[:, :, None, None] * cands).sum(axis=1).astype(np.float32)
    if COMPILED_NET and o.clamp_fusion:
        return fuse_clamped(_net_arrays(o.weights or str(C2F_WEIGHTS_FILE)), cands, est_blk, known_blk, q, valid,
                            o.alpha, FUSE_TOL, SIGMA_MIN)[0]
    vm = valid[:, :, None, None]
    lo = np.where(vm, cands, np.inf).min(axis=1)
    hi = np.where(vm, cands, -np.inf).max(axis=1)
    hole = ~known_blk
    run = np.ones(len(cands), bool)
    out = np.empty(est_blk.shape, np.float32)
    if o.clamp_fusion:
        # The clamped fusion of a pixel lies in [lo, hi] of its valid candidates. Where that range is below
        # FUSE_TOL (relative) at every hole pixel of a block — one valid candidate, or candidates that agree — any
        # fusion, the network's included, gives the same block to within that bound: the softmax mean is used
        # and the network is not run (the paper fuses k ≥ 2 blocks).
        spread = np.where(hole, hi - lo, 0.0).max(axis=(1, 2))
        scale = np.where(hole, np.abs(hi), 0.0).max(axis=(1, 2))
        run = spread > FUSE_TOL * scale
        if (~run).any():
            w = softmax_weights(q[~run], valid[~run], o.alpha)
            out[~run] = (w[:, :, None, None] * cands[~run]).sum(axis=1)
    if run.any():
        cn, tn, mu, sigma = normalise(cands[run], est_blk[run], np.ones(est_blk[run].shape, bool), valid[run])
        if COMPILED_NET:
            res = run_net_compiled(_net_arrays(o.weights or str(C2F_WEIGHTS_FILE)), cn, tn, hole[run], q[run],
                                   valid[run])
        else:
            res = run_net(load_net(o.weights or str(C2F_WEIGHTS_FILE)), cn, tn, hole[run], q[run], valid[run],
                          native_conv=NATIVE_CONV, chunk=NET_CHUNK, fast=True)
        out[run] = res * sigma[:, None, None] + mu[:, None, None]
    if o.clamp_fusion:  # a fusion of the candidates stays within their per-pixel range
        out = np.minimum(np.maximum(out, lo), hi)
    return out.astype(np.float32)



__all__ = ["C2FOptions", "inpaint_paper_c2f"]
