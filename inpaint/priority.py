"""Fill front, front normals, Criminisi confidence and the data term, and batched block selection.

Priority of a front pixel p at level L (paper §2): P^(L)(p) = C^(L)(p) · D^(L)(p), where

- C^(L)(p) = Σ_{q ∈ Ψ_p} C^(L)(q) / |Ψ_p| — the Criminisi confidence: mean confidence over the s_L×s_L template
  around p's position at level L (C = 1 on original known pixels, 0 in holes, and a filled pixel inherits the
  confidence of the block that filled it);
- D^(L)(p) = |∇^(L) I(p) · n(p)| / α + ε — the gradient along the front normal n (the paper's form; Criminisi's
  EBM uses the isophote ∇I⊥ instead), with ∇ the anisotropic (or Sobel) gradient vector taken, as in Criminisi,
  from the known pixel of largest gradient in p's 3×3 neighbourhood at that level; α normalises depth gradients
  (a robust maximum of |∇I| over known pixels of level 0) and ε = 0.001 keeps flat fronts fillable.

The overall priority is P(p) = max_L λ^(L) P^(L)(p) 1_match(L)(p) with λ^(L) = 2^−L. Gradients at level L are
per level-L pixel, i.e. 2^L times those at level 0 on a ramp, so λ^(L) also puts D on one scale.
"""

from __future__ import annotations

import cv2
import numpy as np

_NEIGH = np.array([(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], np.intp)


def fill_front(hole: np.ndarray) -> np.ndarray:
    """Front pixels (N×2 int (y, x), row-major order): hole pixels with a known 8-neighbour."""
    known = (~hole).astype(np.uint8)
    near = cv2.dilate(known, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.argwhere(hole & (near > 0))


def front_normals(hole: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Unit normals (N×2, (ny, nx)) of the hole boundary at ``pts``: the gradient of the Gaussian-smoothed
    known mask (points from the hole into the known region)."""
    k = cv2.GaussianBlur((~hole).astype(np.float32), (5, 5), 1.0)
    gy = cv2.Sobel(k, cv2.CV_32F, 0, 1, ksize=3)[pts[:, 0], pts[:, 1]]
    gx = cv2.Sobel(k, cv2.CV_32F, 1, 0, ksize=3)[pts[:, 0], pts[:, 1]]
    nrm = np.hypot(gx, gy)
    nrm[nrm < 1e-9] = 1.0
    return np.stack([gy / nrm, gx / nrm], axis=1)


def confidence_term(conf: np.ndarray, pts: np.ndarray, size: int) -> np.ndarray:
    """C(p) = mean of ``conf`` over the size×size block around each of ``pts`` (outside the image counts 0)."""
    box = cv2.boxFilter(conf.astype(np.float32), -1, (size, size), normalize=True, borderType=cv2.BORDER_CONSTANT)
    return box[pts[:, 0], pts[:, 1]]


def neighbourhood_gradient(gvec: np.ndarray, known: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """For each point, the gradient vector (N×2, (gy, gx), depth units per pixel) of largest magnitude among the
    known pixels of its 3×3 neighbourhood (zero if none). ``gvec``: H×W×2 gradient vectors (gy, gx) (see
    ``gradient.vector_from_channels``); ``known``: bool H×W."""
    h, w = known.shape
    ys = np.clip(pts[:, None, 0] + _NEIGH[None, :, 0], 0, h - 1)
    xs = np.clip(pts[:, None, 1] + _NEIGH[None, :, 1], 0, w - 1)
    g = gvec[ys, xs]  # N×9×2
    mag = np.where(known[ys, xs], g[..., 0] ** 2 + g[..., 1] ** 2, -1.0)
    j = np.argmax(mag, axis=1)
    rows = np.arange(len(pts))
    out = g[rows, j].astype(np.float64)
    out[mag[rows, j] < 0] = 0.0
    return out


def data_term(gvec: np.ndarray, known: np.ndarray, pts: np.ndarray, normals: np.ndarray, alpha: float,
              isophote: bool = False, eps: float = 1e-3) -> np.ndarray:
    """D(p) = |g·n|/α + ε (paper), or |g⊥·n|/α + ε with the isophote g⊥ (Criminisi). ``normals`` N×2 (ny, nx)."""
    g = neighbourhood_gradient(gvec, known, pts)
    if isophote:
        g = np.stack([g[:, 1], -g[:, 0]], axis=1)  # (gy, gx) rotated by 90°: (gx, −gy) in (y, x) order
    return np.abs((g * normals).sum(axis=1)) / alpha + eps


def select_blocks(pts: np.ndarray, priority: np.ndarray, block: int, shape: tuple[int, int],
                  max_blocks: int) -> np.ndarray:
    """Greedy, in decreasing priority: indices of front points whose block×block blocks do not overlap the
    blocks already chosen (Chebyshev distance ≥ ``block``), at most ``max_blocks``. Ties keep row-major order."""
    order = np.argsort(-priority, kind="stable")
    taken = np.zeros(shape, bool)
    chosen: list[int] = []
    h, w = shape
    for i in order:
        y, x = pts[i]
        if taken[y, x]:
            continue
        chosen.append(int(i))
        if len(chosen) >= max_blocks:
            break
        taken[max(0, y - block + 1):min(h, y + block), max(0, x - block + 1):min(w, x + block)] = True
    return np.array(chosen, np.intp)
