"""Fusion of the blocks found at the pyramid levels into one level-0 block (the ablation switch).

Modes: ``net`` — the trained encoder/PLIP/decoder network (paper); ``mean`` — the plain softmax(α·q)-weighted
mean of the candidates; ``best`` — the single candidate with the best quality q. All work on a batch of blocks.
"""

from __future__ import annotations

import numpy as np

from inpaint.fusion_net import load_net, normalise, run_net

FUSION_MODES = ("net", "mean", "best")


def softmax_weights(q: np.ndarray, valid: np.ndarray, alpha: float) -> np.ndarray:
    """w = softmax over valid scales of α·q (B×S), 0 on invalid scales."""
    logits = np.where(valid, alpha * q, -np.inf)
    logits = logits - logits.max(axis=1, keepdims=True)
    e = np.where(valid, np.exp(logits), 0.0)
    return e / e.sum(axis=1, keepdims=True)


def fuse(mode: str, cands: np.ndarray, target: np.ndarray, known: np.ndarray, q: np.ndarray, valid: np.ndarray,
         alpha: float = 4.0, weights_path: str | None = None) -> np.ndarray:
    """Fused blocks (B×b×b, metres) from candidates ``cands`` (B×S×b×b metres, already shifted to the target's
    depth), the target block ``target`` (B×b×b; trusted where ``known``), quality ``q`` and ``valid`` (B×S)."""
    if mode == "best":
        qq = np.where(valid, q, -np.inf)
        return cands[np.arange(len(cands)), np.argmax(qq, axis=1)].astype(np.float32)
    if mode == "mean":
        w = softmax_weights(q, valid, alpha)
        return (w[:, :, None, None] * cands).sum(axis=1).astype(np.float32)
    net = load_net(weights_path)
    cn, tn, mu, sigma = normalise(cands, target, known, valid)
    out = run_net(net, cn, tn, ~known, q, valid)
    return (out * sigma[:, None, None] + mu[:, None, None]).astype(np.float32)
