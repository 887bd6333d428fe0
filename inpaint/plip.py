"""PLIP — Parameterized Logarithmic Image Processing (Panetta, Wharton, Agaian 2008).

Grey-tone values g must lie in [0, γ). Operators (γ = k in this module):

- addition        a ⊕ b = a + b − a·b/γ
- subtraction     a ⊖ b = γ·(a − b)/(γ − b)
- scalar multiply c ⊗ a = γ − γ·(1 − a/γ)^c
- weighted sum    ⊕_i (w_i ⊗ g_i) = γ − γ·Π_i (1 − g_i/γ)^{w_i}   (closed form; a weighted geometric mean of
  1 − g/γ; it tends to the ordinary weighted sum Σ w_i g_i as γ → ∞)

Every function works on numpy arrays and on torch tensors (the fusion network uses the torch path). The closed
form is evaluated in the log domain, γ·(1 − exp(Σ_i w_i·log1p(−g_i/γ))), which is stable near 0 and near γ.
"""

from __future__ import annotations

from typing import Any

import numpy as np

try:  # torch is optional for the numpy path
    import torch
except ImportError:  # pragma: no cover
    torch = None  # type: ignore[assignment]

DEFAULT_GAMMA = 1026.0  # the value in circulation for 8-bit images (UIQM code); the network uses γ = 1


def _is_torch(x: Any) -> bool:
    return torch is not None and isinstance(x, torch.Tensor)


def plip_add(a: Any, b: Any, gamma: float = DEFAULT_GAMMA) -> Any:
    """a ⊕ b = a + b − a·b/γ."""
    return a + b - a * b / gamma


def plip_sub(a: Any, b: Any, gamma: float = DEFAULT_GAMMA) -> Any:
    """a ⊖ b = γ·(a − b)/(γ − b); inverse of ⊕: (a ⊕ b) ⊖ b = a."""
    return gamma * (a - b) / (gamma - b)


def plip_scalar_mul(c: Any, a: Any, gamma: float = DEFAULT_GAMMA) -> Any:
    """c ⊗ a = γ − γ·(1 − a/γ)^c."""
    if _is_torch(a) or _is_torch(c):
        return gamma - gamma * torch.exp(c * torch.log1p(-a / gamma))
    return gamma - gamma * np.exp(c * np.log1p(-np.asarray(a) / gamma))


def plip_weighted_sum(g: Any, w: Any, gamma: float = DEFAULT_GAMMA, axis: int = 0) -> Any:
    """Closed form of ⊕_i (w_i ⊗ g_i) along ``axis``: γ − γ·Π_i (1 − g_i/γ)^{w_i}.

    ``g`` and ``w`` broadcast against each other; values of ``g`` must be in [0, γ).
    """
    if _is_torch(g) or _is_torch(w):
        return gamma * -torch.expm1((w * torch.log1p(-g / gamma)).sum(dim=axis))
    g = np.asarray(g, dtype=np.float64)
    return gamma * -np.expm1(np.sum(np.asarray(w) * np.log1p(-g / gamma), axis=axis))


def plip_weighted_sum_iterated(g: Any, w: Any, gamma: float = DEFAULT_GAMMA) -> Any:
    """Reference form: (w_0 ⊗ g_0) ⊕ (w_1 ⊗ g_1) ⊕ … evaluated term by term along axis 0 (numpy only)."""
    g = np.asarray(g, dtype=np.float64)
    w = np.broadcast_to(np.asarray(w, dtype=np.float64), g.shape)
    acc = np.zeros(g.shape[1:])
    for gi, wi in zip(g, w, strict=True):
        acc = plip_add(acc, plip_scalar_mul(wi, gi, gamma), gamma)
    return acc
