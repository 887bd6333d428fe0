"""Block search at one pyramid level: masked mean-squared difference of gradient structure (+ depth).

For a target block B_t (s×s, centred on a fill-front point) with known-pixel mask M and n = Σ M known pixels,
the dissimilarity of a candidate block B_c is

    Sim(B_t, B_c) = 1/(n·C) Σ_u M(u) Σ_c (G_c^t(u) − G_c^c(u))²                (gradient structure, paper §2)
                  + w_d · 1/n Σ_u M(u) ((D^t(u) − μ^t) − (D^c(u) − μ^c))²      (depth shape, our addition)

with G the C feature channels (8 anisotropic directional gradients, or Sobel gx, gy), D depth in metres, μ the
mean over the known pixels. Both terms are offset-invariant: a block may be copied from a place at another
distance and is shifted to the target's depth when pasted. The depth term (weight ``w_depth``, default 1) adds
the low-frequency shape that differences of local means see only weakly; with w_d = 0 the similarity is the
paper's pure gradient-structure MSD.

Vectorised: all terms are cross-correlations of the search window with small templates, so one masked search
is three ``cv2.matchTemplate(TM_CCORR)`` calls (one with C+1 channels, two with one channel):
Σ M (T − I)² = Σ M T² − 2 Σ (M T) ⋆ I + M ⋆ I², and the depth mean removal adds −(M ⋆ D)²/n.
Candidates are restricted to centres whose whole template lies in the source region (originally known
pixels at that level) and to a bounded window (± ``radius`` pixels at that level).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class LevelGrid:
    """Search data of one level, padded by ``pad`` = t + r pixels on every side (pad pixels are unknown).

    ``fd``: (h+2p)×(w+2p)×(C+1) float32 — C feature channels then depth (metres). ``known``: bool, current
    known-or-filled pixels. ``sq``: Σ_c G_c² per pixel (call ``refresh_sq`` after changing features).
    ``source_ok``: bool, True where a template centred there lies entirely in the
    source region. ``t``: template half-size (template is (2t+1)²); ``r``: search radius (pixels at this level).
    """

    level: int
    pad: int
    t: int
    r: int
    fd: np.ndarray
    known: np.ndarray
    source_ok: np.ndarray
    sq: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.sq is None:
            self.refresh_sq()

    def refresh_sq(self, rect: tuple[int, int, int, int] | None = None) -> None:
        """Recompute ``sq`` = Σ_c G_c² (the feature energy per pixel) everywhere or inside ``rect``."""
        if rect is None or self.sq is None:
            self.sq = np.einsum("hwc,hwc->hw", self.fd[..., :-1], self.fd[..., :-1])
            return
        y0, y1, x0, x1 = rect
        f = self.fd[y0:y1, x0:x1, :-1]
        self.sq[y0:y1, x0:x1] = np.einsum("hwc,hwc->hw", f, f)

    @property
    def channels(self) -> int:
        return self.fd.shape[2] - 1


@dataclass(frozen=True)
class SearchResult:
    """Per target k: ``best`` (K×2 int, padded (y, x) of the best candidate centre, −1 if none),
    ``sim`` (K, the Sim value of the best), ``energy`` (K, Sim of a flat/constant candidate, i.e. the target's own
    structure energy; sim/energy ≪ 1 means a good match)."""

    best: np.ndarray
    sim: np.ndarray
    energy: np.ndarray


def search_level(grid: LevelGrid, centres: np.ndarray, w_depth: float = 1.0) -> SearchResult:
    """Best candidate for each target centre (K×2 int, padded coordinates) at one level."""
    k_n = len(centres)
    best = np.full((k_n, 2), -1, np.intp)
    sim = np.full(k_n, np.inf)
    energy = np.zeros(k_n)
    if k_n == 0:
        return SearchResult(best, sim, energy)
    t, r, c_n = grid.t, grid.r, grid.channels
    fd, known, ok = grid.fd, grid.known, grid.source_ok
    # Templates of all targets at once (K×s×s), vectorised.
    off = np.arange(-t, t + 1)
    ys = centres[:, 0, None, None] + off[None, :, None]
    xs = centres[:, 1, None, None] + off[None, None, :]
    tpl = fd[ys, xs]  # K×s×s×(C+1)
    m = known[ys, xs].astype(np.float32)  # K×s×s
    n = m.sum(axis=(1, 2))
    n_safe = np.maximum(n, 1.0)
    a = 1.0 / (n_safe * c_n)
    b = w_depth / n_safe
    mu = (tpl[..., c_n] * m).sum(axis=(1, 2)) / n_safe
    td0 = (tpl[..., c_n] - mu[:, None, None]) * m
    tm = np.empty(tpl.shape, np.float32)
    tm[..., :c_n] = tpl[..., :c_n] * (m * a[:, None, None])[..., None]
    tm[..., c_n] = td0 * b[:, None, None]
    const = a * (tpl[..., :c_n] ** 2 * m[..., None]).sum(axis=(1, 2, 3)) + b * (td0 ** 2).sum(axis=(1, 2))
    for k in range(k_n):
        cy, cx = int(centres[k, 0]), int(centres[k, 1])
        valid = ok[cy - r:cy + r + 1, cx - r:cx + r + 1]
        if n[k] < 1.0 or not valid.any():
            continue
        win = fd[cy - r - t:cy + r + t + 1, cx - r - t:cx + r + t + 1]
        cross = cv2.matchTemplate(win, tm[k], cv2.TM_CCORR)
        dc = win[..., c_n] - np.float32(mu[k])
        quad = grid.sq[cy - r - t:cy + r + t + 1, cx - r - t:cx + r + t + 1] * np.float32(a[k]) + \
            dc * dc * np.float32(b[k])
        sq = cv2.matchTemplate(quad, m[k], cv2.TM_CCORR)
        sd = cv2.matchTemplate(dc, m[k], cv2.TM_CCORR)
        sc = np.float32(const[k]) - 2.0 * cross + sq - np.float32(b[k] / n[k]) * sd * sd
        sc[~valid] = np.inf
        j = int(np.argmin(sc))
        best[k] = (cy - r + j // sc.shape[1], cx - r + j % sc.shape[1])
        sim[k] = max(float(sc.flat[j]), 0.0)
        energy[k] = const[k]
    return SearchResult(best, sim, energy)
