"""The compiled fusion network (``inpaint.fusion_kernels``, issue 12) against the torch network it replaces."""

import numpy as np
import pytest
import torch

import inpaint.c2f as c2f
from inpaint.c2f import C2FOptions, _fuse
from inpaint.fusion_kernels import _exp_inplace, _log_inplace, net_arrays, run_net_compiled
from inpaint.fusion_net import FusionNet
from inpaint.gradient import gradient_channels, gradient_channels_reference
from inpaint.masks import random_mask
from inpaint.synthetic import field_depth

# Stated tolerance: the compiled network equals FusionNet.forward_valid to 1e-5 in normalised units (float32
# rounding in another order, and exp/log polynomials with < 1e-6 error; measured ≈ 2e-6).
TOL = 1e-5


def _blocks(seed: int, b_n: int = 40, s_n: int = 4, k: int = 11):
    g = np.random.default_rng(seed)
    cands = g.normal(0, 1, (b_n, s_n, k, k)).astype(np.float32)
    hole = g.random((b_n, k, k)) < 0.6
    target = np.where(hole, 0, g.normal(0, 1, (b_n, k, k))).astype(np.float32)
    q = (-g.random((b_n, s_n)) * 3).astype(np.float32)
    valid = g.random((b_n, s_n)) < 0.6
    valid[:, 0] |= ~valid.any(axis=1)
    return cands, target, hole, q, valid


@pytest.mark.parametrize("config", [dict(features=4, growth=4, dense_layers=1, hidden=8),
                                    dict(features=4, growth=4, dense_layers=1, hidden=4),
                                    dict(features=8, growth=4, dense_layers=3, hidden=16),
                                    dict(features=5, growth=3, dense_layers=2, hidden=6)])
def test_compiled_net_equals_forward_valid(config):
    torch.manual_seed(3)
    net = FusionNet(**config).eval()
    for p in net.parameters():  # livelier weights than the initialisation
        p.data += 0.1 * torch.randn_like(p)
    cands, target, hole, q, valid = _blocks(1, k=9 if config["hidden"] == 6 else 11)
    with torch.inference_mode():
        ref = net.forward_valid(torch.from_numpy(cands), torch.from_numpy(target),
                                torch.from_numpy(hole.astype(np.float32)), torch.from_numpy(q),
                                torch.from_numpy(valid)).numpy()
    out = run_net_compiled(net_arrays(net), cands, target, hole, q, valid)
    np.testing.assert_allclose(out, ref, rtol=TOL, atol=TOL)
    assert out.tobytes() == run_net_compiled(net_arrays(net), cands, target, hole, q, valid).tobytes()


def test_vectorisable_exp_and_log():
    x = np.linspace(-80, 80, 20001).astype(np.float32)
    e = x.copy()
    _exp_inplace(e, len(e), np.empty(len(e), np.int32))
    ref = np.exp(x.astype(np.float64))
    assert np.max(np.abs(e - ref) / ref) < 3e-7
    y = np.geomspace(1e-6, 10, 20001).astype(np.float32)
    lg = y.copy()
    _log_inplace(lg, len(lg), np.empty(len(lg), np.int32))
    assert np.max(np.abs(lg - np.log(y.astype(np.float64)))) < 2e-6


def test_compiled_fusion_equals_the_torch_path_and_keeps_the_skip_rule(monkeypatch):
    cands, target, hole, q, valid = _blocks(5, b_n=60)
    cands = (3.0 + 0.3 * cands).astype(np.float32)
    cands[1, 1:] = cands[1, 0]  # candidates agree: the softmax mean, no network
    est = cands[:, 0].copy()
    known = ~hole
    o = C2FOptions()
    fast = _fuse(o, cands, est, known, q, valid)
    monkeypatch.setattr(c2f, "COMPILED_NET", False)
    ref = _fuse(o, cands, est, known, q, valid)
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-4)  # working units (inverse depth ≈ 3): ≤ 3e-5 relative
    np.testing.assert_array_equal(fast[1][hole[1]], cands[1, 0][hole[1]])
    vm = valid[:, :, None, None]
    assert (fast >= np.where(vm, cands, np.inf).min(1) - 1e-6).all()
    assert (fast <= np.where(vm, cands, -np.inf).max(1) + 1e-6).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_masked_anisotropic_features_are_bit_identical(seed):
    f = field_depth(50, 70, seed=seed).depth
    known = ~random_mask(f.shape, 0.4, "mixed" if seed % 2 else "blobs", seed=seed)
    assert gradient_channels(f, known).tobytes() == gradient_channels_reference(f, known).tobytes()
    assert gradient_channels(f).tobytes() == gradient_channels_reference(f).tobytes()
    assert gradient_channels(f, known, "sobel").tobytes() == gradient_channels_reference(f, known, "sobel").tobytes()
