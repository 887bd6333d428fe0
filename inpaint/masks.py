"""Seeded hole masks for tests, training and the benchmark (bool H×W, True = hole).

Kinds (each grows shapes until the requested hole ratio is reached, then stops; the ratio is met to within one
shape): ``blobs`` — irregular blobs (thresholded smoothed noise inside random ellipses); ``stripes`` — thin
random line segments 2–7 px thick; ``specks`` — many small discs (radius 1–4 px); ``mixed`` — a random mix.
``occlusion_mask`` makes stereo-like holes from a depth map: pixels of the left view that the right view
cannot see (to the left of nearer objects), plus the left band of ``num_disparities`` columns that a block
matcher cannot match.
"""

from __future__ import annotations

import cv2
import numpy as np

from inpaint.errors import InpaintInputError

MASK_KINDS = ("blobs", "stripes", "specks", "mixed")


def random_mask(shape: tuple[int, int], ratio: float, kind: str = "mixed", seed: int = 0) -> np.ndarray:
    """A bool mask of ``shape`` with about ``ratio`` (0–0.9) of its pixels True, deterministic in ``seed``."""
    if kind not in MASK_KINDS:
        raise InpaintInputError(f"unknown mask kind {kind!r}; expected one of {MASK_KINDS}")
    if not 0.0 <= ratio <= 0.9:
        raise InpaintInputError(f"hole ratio must be in [0, 0.9], got {ratio}")
    rng = np.random.default_rng(seed)
    h, w = shape
    m = np.zeros(shape, np.uint8)
    target = ratio * h * w
    scale = np.sqrt(h * w / (376.0 * 672.0))
    guard = 0
    while m.sum() < target and guard < 100000:
        guard += 1
        k = kind if kind != "mixed" else rng.choice(["blobs", "blobs", "stripes", "specks"])
        if k == "blobs":
            _blob(m, rng, scale)
        elif k == "stripes":
            _stripe(m, rng, scale)
        else:
            for _ in range(20):
                cv2.circle(m, (int(rng.integers(0, w)), int(rng.integers(0, h))),
                           int(rng.integers(1, 5)), 1, -1)
    return m.astype(bool)


def _blob(m: np.ndarray, rng: np.random.Generator, scale: float) -> None:
    h, w = m.shape
    a = max(3, int(rng.uniform(6, 45) * scale))
    b = max(3, int(a * rng.uniform(0.4, 1.0)))
    cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
    size = 2 * max(a, b) + 3
    patch = np.zeros((size, size), np.uint8)
    cv2.ellipse(patch, (size // 2, size // 2), (a, b), float(rng.uniform(0, 180)), 0, 360, 1, -1)
    noise = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), max(1.0, a / 4))
    patch &= (noise > np.quantile(noise, 0.25)).astype(np.uint8)
    y0, x0 = cy - size // 2, cx - size // 2
    ys, xs = slice(max(0, y0), min(h, y0 + size)), slice(max(0, x0), min(w, x0 + size))
    m[ys, xs] |= patch[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0]


def _stripe(m: np.ndarray, rng: np.random.Generator, scale: float) -> None:
    h, w = m.shape
    length = rng.uniform(40, 250) * scale
    ang = rng.uniform(0, np.pi)
    x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
    p1 = (int(x0), int(y0))
    p2 = (int(x0 + length * np.cos(ang)), int(y0 + length * np.sin(ang)))
    cv2.line(m, p1, p2, 1, int(rng.integers(2, 8)))


def occlusion_mask(depth: np.ndarray, focal_baseline: float, num_disparities: int = 64) -> np.ndarray:
    """Stereo holes of a rectified pair, from the left-view depth (float32 H×W metres, finite).

    ``focal_baseline``: f·B in pixel·metres (disparity = f·B / depth). A left pixel x is occluded when some
    pixel x + k (0 < k ≤ max disparity) is nearer by enough to land on the same right-image column
    (d(x + k) ≥ d(x) + k). The leftmost ``num_disparities`` columns are holes too (no match range).
    """
    disp = focal_baseline / np.maximum(depth, 1e-3)
    h, w = depth.shape
    occ = np.zeros((h, w), bool)
    kmax = int(min(w - 1, np.ceil(disp.max())))
    for k in range(1, kmax + 1):
        occ[:, :-k] |= disp[:, k:] >= disp[:, :-k] + k
    occ[:, :num_disparities] = True
    return occ
