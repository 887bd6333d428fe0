"""Masked Gaussian pyramid of a depth map and sampling between levels.

Level L has resolution 2^-L (L = 0 is the input). Downsampling is ``cv2.pyrDown`` applied as a normalised
convolution: depth_{L+1} = pyrDown(depth_L · K_L) / pyrDown(K_L), so hole pixels (K = 0) never leak zeros into
the average. ``weight`` is pyrDown(K_L) ∈ [0, 1], the fraction of the Gaussian support that was known.

Coordinates: ``cv2.pyrDown`` centres output pixel j on input pixel 2j, so level-L pixel (y, x) sits at level-0
pixel (2^L·y, 2^L·x); a level-0 point p maps to the (sub-pixel) level-L point p / 2^L.
"""

from __future__ import annotations

import cv2
import numpy as np


def masked_pyrdown(depth: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One masked pyramid step. ``depth`` float32 H×W (metres; values where weight = 0 ignored),
    ``weight`` float32 H×W in [0, 1] (1 = known). Returns (depth, weight) at half resolution (⌈H/2⌉×⌈W/2⌉)."""
    num = cv2.pyrDown(np.where(weight > 0, depth * weight, 0).astype(np.float32))
    den = cv2.pyrDown(weight.astype(np.float32))
    out = np.divide(num, den, out=np.zeros_like(num), where=den > 1e-6)
    return out, den


def masked_pyramid(depth: np.ndarray, known: np.ndarray, levels: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(depth_L, weight_L) for L = 0..levels]; weight_0 = known as float32."""
    out = [(depth.astype(np.float32), known.astype(np.float32))]
    for _ in range(levels):
        d, w = masked_pyrdown(*out[-1])
        out.append((d, w))
    return out


def sample_bilinear(image: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` (H×W) at float coordinates (any shape, pixels); coordinates are clamped to
    the image. Vectorised gather of the four neighbours."""
    h, w = image.shape
    ys = np.clip(ys, 0, h - 1)
    xs = np.clip(xs, 0, w - 1)
    y0 = np.minimum(np.floor(ys).astype(np.intp), h - 2 if h > 1 else 0)
    x0 = np.minimum(np.floor(xs).astype(np.intp), w - 2 if w > 1 else 0)
    fy = (ys - y0).astype(np.float32)
    fx = (xs - x0).astype(np.float32)
    y1 = np.minimum(y0 + 1, h - 1)
    x1 = np.minimum(x0 + 1, w - 1)
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bot = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32)
