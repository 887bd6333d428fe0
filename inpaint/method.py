"""The paper's depth inpainting: multi-scale block search, scale-adaptive priority, anisotropic gradient, fusion.

``inpaint_paper(depth, mask, guide=None, **options)`` fills the hole pixels of a float32 depth map (metres).
One fill round (repeated until no hole is left):

1. Fill front (hole pixels next to known ones), its normals, and per level L the priority
   P^(L) = C^(L)·D^(L) of every front pixel (``priority``); P = max_L 2^−L P^(L) 1_match(L).
2. Blocks (``block``×``block`` at level 0, centred on front pixels) are chosen greedily by decreasing P, without
   overlap, up to ``max_blocks`` per round (block-granular, batched filling; the classical one-block-per-iteration
   order is ``max_blocks=1``).
3. For every chosen block and every level L = 0..L_max: masked block search (``block_search``) around the
   block's position at level L, bounded window ± ``radius[L]`` level-L pixels, similarity = MSD of the
   gradient structure (+ ``w_depth`` × mean-removed depth MSD) over the known pixels of the target template.
   A level "matches" (1_match) when Sim < ``match_threshold`` × the target's own structure energy. A block with no
   matching level gets P = 0 and is deferred until its neighbourhood changes; if a whole round is deferred, the
   blocks are filled from every level that found any candidate (fall-back to whatever scale is available).
4. The best block of each matching level is upsampled to level 0 (bilinear), shifted to the target's depth (mean
   over the target's known pixels) and fused: trained network (``fusion="net"``), softmax(α·q) mean (``"mean"``) or
   the best single block (``"best"``), with q = −min(Sim/energy, 10).
5. The fused block, clipped to the range of the known values (a filled depth is never nearer than the nearest or
   farther than the farthest measured one), is pasted into the hole pixels only; the filled pixels get the
   block's confidence C(p̂); the pyramid, known masks and gradient features are updated where pixels changed.

Ablations (one option each): ``single_scale=True`` (level 0 only), ``gradient="sobel"`` (isotropic),
``fusion="best"`` / ``"mean"``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from typing import Protocol, TypeVar

import cv2
import numpy as np

from inpaint.block_search import LevelGrid, search_level
from inpaint.errors import InpaintInputError
from inpaint.fusion import FUSION_MODES, fuse
from inpaint.gradient import (
    GRADIENT_KINDS,
    FeatureJob,
    n_channels,
    run_feature_jobs,
    template_radius,
    vector_from_channels,
)
from inpaint.priority import confidence_term, data_term, fill_front, front_normals, select_blocks
from inpaint.pyramid import masked_pyrdown, sample_bilinear
from inpaint.validate import check_inputs, finish

ENERGY_EPS = 1e-4  # working units²: floor of a target's structure energy in the match test
Q_CLIP = 10.0  # quality q = −min(Sim/energy, Q_CLIP)
INVERSE_REF_M = 10.0  # u = INVERSE_REF_M / depth: u = 1 at 10 m, 5 at 2 m
U_MIN = INVERSE_REF_M / 1000.0  # filled inverse depth is kept ≥ this (≤ 1 km)


_Options = TypeVar("_Options")


def options_from_kwargs(cls: type[_Options], method: str, options: dict[str, object],
                        tuple_fields: tuple[str, ...] = ()) -> _Options:
    """An options dataclass of the paper's method (``paper-greedy``: :class:`PaperOptions`, ``paper``:
    ``inpaint.c2f.C2FOptions``) from keyword options: unknown names are an error naming ``method``; each of
    ``tuple_fields`` given as a number or a list becomes a tuple of ints; the result is checked (its ``check()``)."""
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(options) - names)
    if unknown:
        raise InpaintInputError(f"unknown option(s) for method '{method}': {unknown}; known: {sorted(names)}")
    for key in set(tuple_fields) & set(options):
        v = options[key]
        if not isinstance(v, tuple):
            options[key] = tuple(int(x) for x in v) if isinstance(v, list) else (int(v),)  # type: ignore[call-overload]
    opts = cls(**options)
    opts.check()  # type: ignore[attr-defined]
    return opts


class _SharedOptions(Protocol):
    gradient: str
    fusion: str
    levels: int
    domain: str


def check_shared_options(opts: _SharedOptions, blocks: tuple[str, ...]) -> None:
    """The checks both formulations share: ``gradient``, ``fusion``, ``levels`` (0..6), ``domain`` and the block
    sizes named in ``blocks`` (odd, ≥ 3)."""
    if opts.gradient not in GRADIENT_KINDS:
        raise InpaintInputError(f"gradient must be one of {GRADIENT_KINDS}, got {opts.gradient!r}")
    if opts.fusion not in FUSION_MODES:
        raise InpaintInputError(f"fusion must be one of {FUSION_MODES}, got {opts.fusion!r}")
    for name in blocks:
        v = getattr(opts, name)
        if v < 3 or v % 2 == 0:
            raise InpaintInputError(f"{name} must be an odd number ≥ 3, got {v}")
    if not 0 <= opts.levels <= 6:
        raise InpaintInputError(f"levels must be in 0..6, got {opts.levels}")
    if opts.domain not in ("inverse", "depth"):
        raise InpaintInputError(f"domain must be 'inverse' or 'depth', got {opts.domain!r}")


@dataclass(frozen=True)
class PaperOptions:
    """Options of the paper's method (defaults in brackets).

    - levels [3]: L_max, pyramid levels 1/1 … 1/2^L_max; single_scale [False]: ablation, level 0 only.
    - block [11]: level-0 block size (odd, pixels); radius [(12, 10, 8, 6)]: search radius per level (level-L
      pixels; the last value repeats).
    - gradient ["anisotropic"|"sobel"]; fusion ["net"|"mean"|"best"] (ablation switches).
    - w_depth [1.0]: weight of the mean-removed depth term in Sim; match_threshold [1.0]: 1_match when
      Sim/energy < this (the candidate explains the target better than a flat block).
    - source ["current"|"original"]: candidates come from pixels known now (original or already filled) or only
      from the originally known pixels.
    - domain ["inverse"|"depth"]: work on u = INVERSE_REF_M / depth (disparity-like: planes are affine in u, so
      offset-corrected blocks fit the perspective ground) or on depth itself.
    - alpha [4.0]: softmax sharpness of ``fusion="mean"``; max_blocks [64]: blocks filled per round.
    - weights [None]: path of fusion-network weights (None = the shipped ``inpaint/weights/fusion_net.pt``).
    """

    levels: int = 3
    single_scale: bool = False
    block: int = 11
    radius: tuple[int, ...] = (12, 10, 8, 6)
    gradient: str = "anisotropic"
    fusion: str = "net"
    w_depth: float = 1.0
    match_threshold: float = 1.0
    source: str = "current"
    domain: str = "inverse"
    alpha: float = 4.0
    max_blocks: int = 64
    weights: str | None = None

    @classmethod
    def from_kwargs(cls, **options: object) -> PaperOptions:
        return options_from_kwargs(cls, "paper-greedy", options, tuple_fields=("radius",))

    def check(self) -> None:
        check_shared_options(self, blocks=("block",))
        if not self.radius or min(self.radius) < 1:
            raise InpaintInputError(f"radius must be positive, got {self.radius}")
        if self.source not in ("current", "original"):
            raise InpaintInputError(f"source must be 'current' or 'original', got {self.source!r}")
        if self.max_blocks < 1 or self.w_depth < 0 or self.match_threshold <= 0:
            raise InpaintInputError("max_blocks must be ≥ 1, w_depth ≥ 0 and match_threshold > 0")


# Called once per round with the blocks about to be fused: (centres B×2 (y, x) level 0, cands B×S×b×b metres,
# target B×b×b, known B×b×b, q B×S, valid B×S). Used by training to collect examples.
BlockObserver = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]


def inpaint_paper(depth: np.ndarray, mask: np.ndarray, guide: np.ndarray | None = None,
                  observer: BlockObserver | None = None, **options: object) -> np.ndarray:
    """Fill ``mask`` (bool H×W, True = hole) of ``depth`` (float32 H×W, metres) with the paper's method.

    ``guide`` is accepted for interface compatibility and validated, but not used: the method works on depth only.
    Returns float32 H×W; known pixels are returned unchanged.
    """
    opts = PaperOptions.from_kwargs(**options)
    return fill_in_domain(depth, mask, guide, opts.domain, lambda work, hole: _Filler(work, hole, opts, observer).run())


def fill_in_domain(depth: np.ndarray, mask: np.ndarray, guide: np.ndarray | None, domain: str,
                   fill: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Validate, fill the hole in the chosen domain and finish (known pixels unchanged, range clipped).

    ``domain == "inverse"`` fills ``u = INVERSE_REF_M / depth`` (holes 0) and maps the result back, ``u`` kept
    ≥ ``U_MIN``; any other value fills depth in metres. ``fill(work, hole)`` returns the filled float32 H×W map.
    """
    chk = check_inputs(depth, mask, guide)
    if not chk.hole.any():
        return depth.copy()
    work = chk.depth
    if domain == "inverse":
        work = np.where(chk.hole, 0.0, INVERSE_REF_M / np.maximum(chk.depth, 1e-6)).astype(np.float32)
    filled = fill(work, chk.hole)
    if domain == "inverse":
        filled = INVERSE_REF_M / np.maximum(filled, U_MIN)
    return finish(filled, chk, depth)


class _Filler:
    """State of one fill: level-0 depth/hole/confidence plus a ``LevelGrid`` per pyramid level. ``search`` is the
    per-level block search (``block_search.search_level``; ``paper``'s coarsest fill uses a compiled one)."""

    search = staticmethod(search_level)

    def __init__(self, depth: np.ndarray, hole: np.ndarray, opts: PaperOptions,
                 observer: BlockObserver | None) -> None:
        self.o = opts
        self.observer = observer
        self.h, self.w = depth.shape
        b = min(opts.block, (min(self.h, self.w) - 1) // 2 * 2 + 1)
        self.block, self.hb = b, b // 2
        self.kind = opts.gradient
        self.c_n = n_channels(self.kind)
        self.rad = template_radius(self.kind)
        self.depth = depth.astype(np.float32).copy()
        self.hole = hole.copy()
        self.conf = (~hole).astype(np.float32)
        self.deferred = np.zeros(hole.shape, bool)
        n_lv = 0 if opts.single_scale else opts.levels
        shapes = [(self.h, self.w)]
        while len(shapes) <= n_lv and min(shapes[-1]) >= 16:
            shapes.append(((shapes[-1][0] + 1) // 2, (shapes[-1][1] + 1) // 2))
        self.shapes = shapes
        self.grids: list[LevelGrid] = []
        self.gvec: list[np.ndarray] = []  # per level, padded H×W×2 (gy, gx) gradient vectors of the features
        src_d, src_w = self.depth, (~hole).astype(np.float32)
        for lv, (hh, ww) in enumerate(shapes):
            if lv > 0:
                src_d, src_w = masked_pyrdown(src_d, src_w)
            t = self.hb if lv == 0 else max(3, math.ceil(self.hb / 2 ** lv + 1.5))
            r = opts.radius[min(lv, len(opts.radius) - 1)]
            pad = t + r
            source = (src_w >= (1.0 if lv == 0 else 0.5)).astype(np.uint8)
            ok = cv2.erode(source, np.ones((2 * t + 1, 2 * t + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                           borderValue=0) > 0
            okp = np.zeros((hh + 2 * pad, ww + 2 * pad), bool)
            okp[pad:pad + hh, pad:pad + ww] = ok
            self.grids.append(LevelGrid(lv, pad, t, r, np.zeros((hh + 2 * pad, ww + 2 * pad, self.c_n + 1),
                                                                np.float32),
                                        np.zeros((hh + 2 * pad, ww + 2 * pad), bool), okp))
            self.gvec.append(np.zeros((hh + 2 * pad, ww + 2 * pad, 2), np.float32))
        self.lv_depth: list[np.ndarray] = [self.depth] * len(shapes)
        self.lv_known: list[np.ndarray] = [~self.hole] * len(shapes)
        self.lv_conf: list[np.ndarray] = [self.conf] * len(shapes)
        self._update_levels(None)
        g0 = self.grids[0]
        ch = g0.fd[g0.pad:g0.pad + self.h, g0.pad:g0.pad + self.w, :self.c_n]
        gx, gy = vector_from_channels(ch[~self.hole], self.kind)
        mag = np.hypot(gx, gy)
        self.alpha = float(max(np.percentile(mag, 99) if mag.size else 0.0, 1e-3))
        self.rounds = 0
        known_vals = depth[~hole]
        self.value_range = (float(known_vals.min()), float(known_vals.max()))
        self.pool: ThreadPoolExecutor | None = None

    # ----------------------------------------------------------------------------------------- level data
    def _level_view(self, lv: int) -> tuple[np.ndarray, np.ndarray]:
        g = self.grids[lv]
        hh, ww = self.shapes[lv]
        return g.fd[g.pad:g.pad + hh, g.pad:g.pad + ww], g.known[g.pad:g.pad + hh, g.pad:g.pad + ww]

    def _update_levels(self, rects: list[tuple[int, int, int, int]] | None) -> None:
        """Refresh every level after level-0 pixels changed inside ``rects`` (y0, y1, x0, x1; None = all)."""
        d, wgt, c = self.depth, (~self.hole).astype(np.float32), self.conf
        cur = rects
        jobs: list[FeatureJob] = []
        for lv, g in enumerate(self.grids):
            hh, ww = self.shapes[lv]
            if lv > 0:
                d, wgt = masked_pyrdown(d, wgt)
                c = cv2.pyrDown(c)
                if cur is not None:
                    cur = [(max(0, (y0 - 2) // 2), min(hh, (y1 + 2) // 2 + 1), max(0, (x0 - 2) // 2),
                            min(ww, (x1 + 2) // 2 + 1)) for y0, y1, x0, x1 in cur]
            known = (wgt >= 0.5) if lv > 0 else ~self.hole
            self.lv_depth[lv], self.lv_known[lv], self.lv_conf[lv] = d, known, c
            if self.o.source == "current":
                ok = cv2.erode(known.astype(np.uint8), np.ones((2 * g.t + 1, 2 * g.t + 1), np.uint8),
                               borderType=cv2.BORDER_CONSTANT, borderValue=0)
                g.source_ok[g.pad:g.pad + hh, g.pad:g.pad + ww] = ok > 0
            fd, kn = self._level_view(lv)
            p = g.pad
            if cur is None:
                fd[..., self.c_n] = d
                kn[...] = known
            else:
                for y0, y1, x0, x1 in cur:
                    fd[y0:y1, x0:x1, self.c_n] = d[y0:y1, x0:x1]
                    kn[y0:y1, x0:x1] = known[y0:y1, x0:x1]
            r = self.rad
            if cur is None:
                frects = [(0, g.known.shape[0], 0, g.known.shape[1])]
            else:
                frects = [(y0 - r + p, y1 + r + p, x0 - r + p, x1 + r + p) for y0, y1, x0, x1 in cur]
                if sum((y1 - y0 + 2 * r) * (x1 - x0 + 2 * r) for y0, y1, x0, x1 in frects) > g.known.size:
                    frects = [(0, g.known.shape[0], 0, g.known.shape[1])]
            jobs.append(FeatureJob(g.fd[..., self.c_n], g.known, frects, g.fd[..., :self.c_n], self.gvec[lv]))
        run_feature_jobs(jobs, self.kind)
        for g, job in zip(self.grids, jobs, strict=True):
            for rect in job.rects:
                g.refresh_sq(rect)

    # ----------------------------------------------------------------------------------------------- fill
    def run(self) -> np.ndarray:
        # Level searches run side by side (OpenCV releases the GIL); a pool per fill, so that a process forked
        # by the caller never inherits a pool whose threads it does not have.
        with ThreadPoolExecutor(max_workers=2) as self.pool:
            while self.hole.any():
                self._round()
                self.rounds += 1
        return self.depth

    def _round(self) -> None:
        o, hb, b = self.o, self.hb, self.block
        pts = fill_front(self.hole)
        centres = np.stack([np.clip(pts[:, 0], hb, self.h - 1 - hb), np.clip(pts[:, 1], hb, self.w - 1 - hb)], 1)
        normals = front_normals(self.hole, pts)
        n_lv = len(self.grids)
        p_lv = np.zeros((n_lv, len(pts)))
        c_lv = []
        for lv, g in enumerate(self.grids):
            s = 2 ** lv
            hh, ww = self.shapes[lv]
            cl = np.stack([np.clip(np.rint(centres[:, 0] / s), 0, hh - 1),
                           np.clip(np.rint(centres[:, 1] / s), 0, ww - 1)], 1).astype(np.intp)
            pl = np.stack([np.clip(np.rint(pts[:, 0] / s), 0, hh - 1),
                           np.clip(np.rint(pts[:, 1] / s), 0, ww - 1)], 1).astype(np.intp)
            c_lv.append(cl)
            conf = confidence_term(self.lv_conf[lv], cl, 2 * g.t + 1)
            gv = self.gvec[lv][g.pad:g.pad + hh, g.pad:g.pad + ww]
            dat = data_term(gv, self.lv_known[lv], pl, normals, self.alpha)
            p_lv[lv] = conf * dat / s
        p_pre = p_lv.max(axis=0)
        p_pre[self.deferred[pts[:, 0], pts[:, 1]]] = 0.0
        cand = np.flatnonzero(p_pre > 0)
        if cand.size == 0:
            cand = np.arange(len(pts))
        sel = cand[select_blocks(centres[cand], p_pre[cand], b, (self.h, self.w), o.max_blocks)]
        k_n = len(sel)
        e = np.full((k_n, n_lv), np.inf)
        best = np.full((k_n, n_lv, 2), -1, np.intp)
        results = list(self.pool.map(lambda lg: self.search(lg[1], c_lv[lg[0]][sel] + lg[1].pad, o.w_depth),
                                 enumerate(self.grids)))
        for lv, res in enumerate(results):
            best[:, lv] = res.best
            found = res.best[:, 0] >= 0
            e[found, lv] = res.sim[found] / (res.energy[found] + ENERGY_EPS)
        found = best[:, :, 0] >= 0
        match = found & (e < o.match_threshold)
        p_fin = (p_lv[:, sel].T * match).max(axis=1)
        ok = p_fin > 0
        valid = match
        if not ok.any():  # whole round deferred: fall back to every level that found a candidate
            ok = np.ones(k_n, bool)
            valid = found
        self.deferred[pts[sel[~ok], 0], pts[sel[~ok], 1]] = True
        idx = np.flatnonzero(ok)
        self._fill_blocks(centres[sel[idx]], [c[sel[idx]] for c in c_lv], best[idx], e[idx], valid[idx])

    def _fill_blocks(self, centres: np.ndarray, c_lv: list[np.ndarray], best: np.ndarray, e: np.ndarray,
                     valid: np.ndarray) -> None:
        hb, b = self.hb, self.block
        k_n, n_lv = valid.shape
        off = np.arange(-hb, hb + 1)
        ys = centres[:, 0, None, None] + off[None, :, None]  # B×b×1
        xs = centres[:, 1, None, None] + off[None, None, :]  # B×1×b
        ys, xs = np.broadcast_arrays(ys, xs)
        target = self.depth[ys, xs]
        known = ~self.hole[ys, xs]
        cands = np.zeros((k_n, n_lv, b, b), np.float32)
        for lv in range(n_lv):
            g = self.grids[lv]
            s = 2 ** lv
            dy = (best[:, lv, 0] - g.pad - c_lv[lv][:, 0]).astype(np.float64)
            dx = (best[:, lv, 1] - g.pad - c_lv[lv][:, 1]).astype(np.float64)
            cands[:, lv] = sample_bilinear(self.lv_depth[lv], ys / s + dy[:, None, None], xs / s + dx[:, None, None])
        kf = known.astype(np.float32)
        nk = np.maximum(kf.sum(axis=(1, 2)), 1.0)
        mu_t = (target * kf).sum(axis=(1, 2)) / nk
        mu_c = (cands * kf[:, None]).sum(axis=(2, 3)) / nk[:, None]
        cands += (mu_t[:, None] - mu_c)[:, :, None, None]
        none = ~valid.any(axis=1)
        if none.any():  # no candidate at any level (no source nearby): constant extrapolation of the known mean
            cands[none] = mu_t[none, None, None, None]
            valid = valid.copy()
            valid[none, 0] = True
        q = -np.minimum(np.where(np.isfinite(e), e, Q_CLIP), Q_CLIP).astype(np.float32)
        if self.observer is not None:
            self.observer(centres, cands, target, known, q, valid)
        fill = fuse(self.o.fusion, cands, target, known, q, valid, self.o.alpha, self.o.weights)
        np.clip(fill, self.value_range[0], self.value_range[1], out=fill)  # never beyond the measured range
        conf_blk = confidence_term(self.conf, centres, b)
        holes = ~known
        self.depth[ys[holes], xs[holes]] = fill[holes]
        self.conf[ys[holes], xs[holes]] = np.broadcast_to(conf_blk[:, None, None], holes.shape)[holes]
        self.hole[ys[holes], xs[holes]] = False
        rects = []
        for y, x in centres:
            self.deferred[max(0, y - b):y + b + 1, max(0, x - b):x + b + 1] = False
            rects.append((y - hb, y + hb + 1, x - hb, x + hb + 1))
        self._update_levels(rects)
