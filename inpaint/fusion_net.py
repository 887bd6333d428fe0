"""The block-fusion network (paper Fig. 6): encoder → PLIP fusion weighted by softmax(α·q) → decoder.

Input, for a batch of B target blocks (b×b, level-0 pixels) and S scales (pyramid levels):

- ``cands``  B×S×b×b — the best block found at each level, upsampled to level 0, shifted to the target's depth and
  normalised (see ``normalise``);
- ``target`` B×b×b — the target block's known pixels (normalised; 0 in the hole); ``hole`` B×b×b — 1 in the hole;
- ``q`` B×S — per-scale quality (−Sim/energy of the match: higher is better); ``valid`` B×S — bool, scales with a
  match (1_match); at least one per block.

Encoder (shared by the scales): conv3×3 (3→F=8) + ReLU → dense block (3 layers, growth 4, each conv3×3 + ReLU on
the concatenation of all earlier maps) → conv1×1 → sigmoid, so every feature lies in (0, γ) with γ = 1 (inputs to
PLIP must lie below γ). Fusion: F_fused = γ − γ·Π_L (1 − F^(L)/γ)^{w^(L)} with w = softmax over valid scales of
α·q (α learnt, initial 4). Decoder: three conv3×3 (16 hidden channels) on [F_fused, target, hole, Σ w·cands] → a
residual added to the softmax-weighted mean of the candidates. Output: B×b×b normalised depth (only hole pixels
are used).

About 5 k parameters (≈ 25 kB of float32 weights) with the default sizes (``paper-greedy``'s weights); the
coarse-to-fine method (``paper``) runs it on every hole block of every level and ships a narrower one (features 4,
one dense layer, 4 hidden channels: 738 parameters, ``weights/fusion_net_c2f.*``), compiled for inference in
``inpaint.fusion_kernels``. The sizes are read from the
JSON record beside the weights.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from torch import nn

from inpaint.plip import plip_weighted_sum

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
WEIGHTS_FILE = WEIGHTS_DIR / "fusion_net.pt"
META_FILE = WEIGHTS_DIR / "fusion_net.json"
SIGMA_MIN = 0.05  # metres: smallest normalisation scale of a block
RUN_CHUNK = 384  # blocks per forward call inside ``run_net``


class DenseBlock(nn.Module):
    """``n_layers`` conv3×3 + ReLU layers, each fed the concatenation of the input and all earlier outputs."""

    def __init__(self, in_ch: int, growth: int, n_layers: int) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            nn.Sequential(nn.Conv2d(in_ch + i * growth, growth, 3, padding=1), nn.ReLU()) for i in range(n_layers))
        self.out_channels = in_ch + n_layers * growth

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = [x]
        for layer in self.layers:
            feats.append(layer(torch.cat(feats, dim=1)))
        return torch.cat(feats, dim=1)


class FusionNet(nn.Module):
    """Encoder / PLIP-softmax fusion / decoder; see the module docstring for shapes."""

    def __init__(self, features: int = 8, growth: int = 4, dense_layers: int = 3, gamma: float = 1.0,
                 alpha_init: float = 4.0, hidden: int = 16) -> None:
        super().__init__()
        self.gamma = gamma
        self.config = dict(features=features, growth=growth, dense_layers=dense_layers, gamma=gamma,
                           alpha_init=alpha_init, hidden=hidden)
        dense = DenseBlock(features, growth, dense_layers)
        self.encoder = nn.Sequential(nn.Conv2d(3, features, 3, padding=1), nn.ReLU(), dense,
                                     nn.Conv2d(dense.out_channels, features, 1))
        self.alpha = nn.Parameter(torch.tensor(float(alpha_init)))
        self.decoder = nn.Sequential(nn.Conv2d(features + 3, hidden, 3, padding=1), nn.ReLU(),
                                     nn.Conv2d(hidden, hidden, 3, padding=1), nn.ReLU(),
                                     nn.Conv2d(hidden, 1, 3, padding=1))

    def scale_weights(self, q: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """w = softmax over valid scales of α·q (B×S)."""
        logits = torch.where(valid, self.alpha * q, torch.full_like(q, -1e9))
        return torch.softmax(logits, dim=1)

    def forward(self, cands: torch.Tensor, target: torch.Tensor, hole: torch.Tensor, q: torch.Tensor,
                valid: torch.Tensor) -> torch.Tensor:
        b_n, s_n, h, w = cands.shape
        x = torch.stack([cands, target[:, None].expand(-1, s_n, -1, -1), hole[:, None].expand(-1, s_n, -1, -1)],
                        dim=2).reshape(b_n * s_n, 3, h, w)
        feats = torch.sigmoid(self.encoder(x)).reshape(b_n, s_n, -1, h, w) * (self.gamma * (1 - 1e-4))
        wts = self.scale_weights(q, valid)
        fused = plip_weighted_sum(feats, wts[:, :, None, None, None], self.gamma, axis=1)
        base = (wts[:, :, None, None] * cands).sum(dim=1)
        res = self.decoder(torch.cat([fused, target[:, None], hole[:, None], base[:, None]], dim=1))
        return base + res[:, 0]

    def forward_valid(self, cands: torch.Tensor, target: torch.Tensor, hole: torch.Tensor, q: torch.Tensor,
                      valid: torch.Tensor) -> torch.Tensor:
        """Inference form of ``forward`` (same inputs and output, equal to it up to float rounding, ~1e-6).

        Two exact rewrites save work: (1) a scale with w^(L) = 0 (not valid) adds nothing to the PLIP sum
        (Π (1 − F/γ)^0 = 1), so the encoder runs only on the valid (block, scale) pairs, and their terms
        w·log(1 − F/γ) are summed per block; (2) the first encoder convolution is linear in its three input
        channels (candidate, target, hole), and the target / hole part is the same for every scale of a block, so
        it is computed once per block instead of once per scale; and the encoder's 1×1 convolution runs as a
        matrix product."""
        b_n, s_n, h, w = cands.shape
        wts = self.scale_weights(q, valid)
        bi, si = torch.nonzero(valid, as_tuple=True)  # valid pairs, block-major
        conv0 = self.encoder[0]
        shared = torch.nn.functional.conv2d(torch.stack([target, hole], dim=1), conv0.weight[:, 1:], conv0.bias,
                                            padding=1)  # B×F×h×w
        own = torch.nn.functional.conv2d(cands[bi, si][:, None], conv0.weight[:, :1], None, padding=1)  # P×F×h×w
        x = self.encoder[2](torch.relu(own + shared[bi]))  # dense block
        conv1 = self.encoder[3]  # 1×1 convolution as one batched matrix product (≈ 15× faster here, measured)
        x = (conv1.weight[:, :, 0, 0] @ x.reshape(len(x), x.shape[1], h * w)).reshape(len(x), -1, h, w)
        x = x + conv1.bias[None, :, None, None]
        feats = torch.sigmoid(x) * (self.gamma * (1 - 1e-4))
        terms = wts[bi, si][:, None, None, None] * torch.log1p(-feats / self.gamma)
        logsum = torch.zeros((b_n,) + terms.shape[1:], dtype=terms.dtype).index_add_(0, bi, terms)
        fused = self.gamma * -torch.expm1(logsum)
        base = (wts[:, :, None, None] * cands).sum(dim=1)
        res = self.decoder(torch.cat([fused, target[:, None], hole[:, None], base[:, None]], dim=1))
        return base + res[:, 0]


def normalise(cands: np.ndarray, target: np.ndarray, known: np.ndarray, valid: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-block normalisation: subtract the target's known-pixel mean μ, divide by σ = max(SIGMA_MIN, std of the
    target's known pixels and of the valid candidates' pixels). Returns (cands_n, target_n (0 in the hole), μ, σ);
    shapes as the inputs (B×S×b×b, B×b×b), μ and σ B."""
    kf = known.astype(np.float32)
    n = kf.sum(axis=(1, 2))
    mu = (target * kf).sum(axis=(1, 2)) / np.maximum(n, 1)
    vf = valid.astype(np.float32)[:, :, None, None]
    dev_t = ((target - mu[:, None, None]) ** 2 * kf).sum(axis=(1, 2))
    dev_c = ((cands - mu[:, None, None, None]) ** 2 * vf).sum(axis=(1, 2, 3))
    cnt = n + vf.sum(axis=(1, 2, 3)) * cands.shape[2] * cands.shape[3]
    sigma = np.maximum(np.sqrt((dev_t + dev_c) / np.maximum(cnt, 1)), SIGMA_MIN).astype(np.float32)
    cn = (cands - mu[:, None, None, None]) / sigma[:, None, None, None]
    tn = np.where(known, (target - mu[:, None, None]) / sigma[:, None, None], 0.0)
    return cn.astype(np.float32), tn.astype(np.float32), mu.astype(np.float32), sigma


@lru_cache(maxsize=4)
def load_net(path: str | None = None) -> FusionNet:
    """The shipped (or given) trained network, in eval mode. Never downloads anything."""
    p = Path(path) if path else WEIGHTS_FILE
    if not p.is_file():
        raise FileNotFoundError(f"{p}: fusion-network weights not found; train them with `agrivio train-fusion` "
                                "or use fusion='mean' / 'best'")
    blob = torch.load(p, map_location="cpu", weights_only=True)
    meta_path = p.with_suffix(".json")
    config = json.loads(meta_path.read_text()).get("config", {}) if meta_path.is_file() else {}
    net = FusionNet(**config)
    net.load_state_dict(blob)
    net.eval()
    return net


def run_net(net: FusionNet, cands: np.ndarray, target: np.ndarray, hole: np.ndarray, q: np.ndarray,
            valid: np.ndarray, native_conv: bool = False, chunk: int | None = None, fast: bool = False
            ) -> np.ndarray:
    """Apply the network to normalised numpy blocks (shapes as ``FusionNet.forward``); returns B×b×b float32.

    ``native_conv``: run the convolutions with torch's native CPU kernels instead of oneDNN (mkldnn) (once ≈ 2×
    faster for the narrow c2f network's ``forward``; with ``forward_valid`` oneDNN is a few per cent faster,
    measured; results equal to ~1e-5), in chunks of ``chunk``
    blocks (default ``RUN_CHUNK``). ``fast``: use ``FusionNet.forward_valid`` (same result up to rounding)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: one thread is faster than two (and deterministic), restored below
    c_t, t_t = torch.from_numpy(np.ascontiguousarray(cands)), torch.from_numpy(np.ascontiguousarray(target))
    h_t = torch.from_numpy(hole.astype(np.float32))
    q_t, v_t = torch.from_numpy(q.astype(np.float32)), torch.from_numpy(np.ascontiguousarray(valid))
    out = np.empty(target.shape, np.float32)
    step = chunk or RUN_CHUNK
    fwd = net.forward_valid if fast else net
    mkldnn = torch.backends.mkldnn.enabled
    try:
        torch.backends.mkldnn.enabled = mkldnn and not native_conv  # restored below
        with torch.inference_mode():
            # Fixed-size chunks: the convolutions on many tiny maps are memory-bound, and a chunk of RUN_CHUNK
            # blocks is 2-3× faster per block than one huge batch (measured); the result does not depend on it.
            for i in range(0, len(target), step):
                sl = slice(i, i + step)
                out[sl] = fwd(c_t[sl], t_t[sl], h_t[sl], q_t[sl], v_t[sl]).numpy()
    finally:
        torch.set_num_threads(threads)
        torch.backends.mkldnn.enabled = mkldnn
    return out
