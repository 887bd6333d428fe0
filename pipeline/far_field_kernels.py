"""Compiled (numba) geodesic reach on a pixel grid, for :meth:`pipeline.depth_sigma.DepthSigmaModel.far_open`.

Compiled once per machine and cached next to the source (``__pycache__``), with the simulator's options
(:data:`pipeline.sim.jit.NJIT`: no fastmath, integer work only here).
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.sim.jit import NJIT

__all__ = ["geodesic_reach"]

_FREE, _BLOCKED, _REACHED = np.uint8(1), np.uint8(0), np.uint8(2)

@numba.njit(**NJIT)
def geodesic_reach(seed: np.ndarray, allowed: np.ndarray, max_steps: int) -> np.ndarray:
    """(H, W) bool: the pixels joined to a ``seed`` pixel by an 8-connected path of at most ``max_steps`` steps
    whose pixels after the seed are all ``allowed``.

    A multi-source breadth-first search, one round per step: the same set as ``max_steps`` rounds of a 3 × 3
    dilation intersected with ``allowed`` (seed pixels must be allowed). seed, allowed: (H, W) bool.

    The grid is held flat with a one-pixel blocked border (no bounds tests, neighbours at fixed offsets) and
    each round expands only the previous round's new pixels (≈ 4× faster than a queue of (y, x) with a
    distance map, measured on 672×376 SGBM masks).
    """
    h, w = seed.shape
    wp = w + 2
    state = np.zeros((h + 2) * wp, np.uint8)  # border and not-allowed pixels stay blocked (0)
    front = np.empty(h * w, np.int32)
    n = 0
    for y in range(h):
        row = (y + 1) * wp + 1
        for x in range(w):
            if seed[y, x]:
                state[row + x] = 2
                front[n] = row + x
                n += 1
            elif allowed[y, x]:
                state[row + x] = 1
    offsets = np.array([-wp - 1, -wp, -wp + 1, -1, 1, wp - 1, wp, wp + 1], np.int32)
    nxt = np.empty(h * w, np.int32)
    for _ in range(max_steps):
        if n == 0:
            break
        m = 0
        for i in range(n):
            p = front[i]
            for k in range(8):
                q = p + offsets[k]
                if state[q] == 1:
                    state[q] = 2
                    nxt[m] = q
                    m += 1
        front, nxt = nxt, front
        n = m
    out = np.empty((h, w), np.bool_)
    for y in range(h):
        row = (y + 1) * wp + 1
        for x in range(w):
            out[y, x] = state[row + x] == 2
    return out
