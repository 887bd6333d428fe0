"""Counter-based random numbers: a deterministic uniform value for every integer key tuple, vectorised.

Used where a world property must be available for any place without generating its neighbourhood first (e.g.
the height of a far canopy segment), and must not depend on the order in which places are visited.
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)


def _mix(z: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 arrays."""
    with np.errstate(over="ignore"):
        z = (z ^ (z >> np.uint64(30))) * _M1
        z = (z ^ (z >> np.uint64(27))) * _M2
        return z ^ (z >> np.uint64(31))


def hash_u64(*keys: np.ndarray | int) -> np.ndarray:
    """uint64 hash of broadcast integer key arrays (negative integers allowed)."""
    arrays = np.broadcast_arrays(*[np.asarray(k, dtype=np.int64) for k in keys])
    h = np.full(arrays[0].shape, 0x243F6A8885A308D3, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for a in arrays:
            h = _mix(h ^ (a.astype(np.uint64) + _GOLD + (h << np.uint64(6)) + (h >> np.uint64(2))))
    return h


def hash_uniform(*keys: np.ndarray | int) -> np.ndarray:
    """Uniform floats in [0, 1) (float64), one per broadcast key tuple."""
    return (hash_u64(*keys) >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


def hash_normal(*keys: np.ndarray | int) -> np.ndarray:
    """Standard normal floats (Box-Muller on two hashed uniforms), one per broadcast key tuple."""
    u1 = hash_uniform(*keys, 1)
    u2 = hash_uniform(*keys, 2)
    return np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2.0 * np.pi * u2)
