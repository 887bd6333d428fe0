"""Compiled (numba) geodesic reach on a pixel grid, for :meth:`pipeline.depth_sigma.DepthSigmaModel.far_open`.

Compiled once per machine and cached next to the source (``__pycache__``), with the simulator's options
(:data:`pipeline.sim.jit.NJIT`: no fastmath, integer work only here).
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.sim.jit import NJIT

__all__ = ["geodesic_reach"]


@numba.njit(**NJIT)
def geodesic_reach(seed: np.ndarray, allowed: np.ndarray, max_steps: int) -> np.ndarray:
    """(H, W) bool: the pixels joined to a ``seed`` pixel by an 8-connected path of at most ``max_steps`` steps
    whose pixels after the seed are all ``allowed``.

    A multi-source breadth-first search; the same set as ``max_steps`` rounds of a 3 × 3 dilation intersected with
    ``allowed`` (seed pixels must be allowed). seed, allowed: (H, W) bool.
    """
    h, w = seed.shape
    dist = np.full((h, w), -1, np.int32)
    queue = np.empty(h * w, np.int64)
    tail = 0
    for y in range(h):
        for x in range(w):
            if seed[y, x]:
                dist[y, x] = 0
                queue[tail] = y * w + x
                tail += 1
    head = 0
    while head < tail:
        p = queue[head]
        head += 1
        y, x = p // w, p % w
        d = dist[y, x]
        if d >= max_steps:
            continue
        for dy in range(-1, 2):
            yy = y + dy
            if yy < 0 or yy >= h:
                continue
            for dx in range(-1, 2):
                xx = x + dx
                if xx < 0 or xx >= w or dist[yy, xx] >= 0 or not allowed[yy, xx]:
                    continue
                dist[yy, xx] = d + 1
                queue[tail] = yy * w + xx
                tail += 1
    return dist >= 0
