"""The fast parts of ``paper`` (issue 12) against the references they replace, each on tiny data."""

import numpy as np
import pytest
import torch

import inpaint.method as method
from inpaint.block_search import search_level
from inpaint.c2f import FUSE_TOL, C2FOptions, _fuse, _nearest, _search_compiled
from inpaint.fusion_net import FusionNet, normalise, run_net
from inpaint.gradient import anisotropic_channels_fast, gradient_channels
from inpaint.masks import random_mask
from inpaint.synthetic import field_depth, room_depth, stereo_noise


@pytest.mark.parametrize("seed", [0, 1])
def test_compiled_anisotropic_features_are_bit_identical(seed):
    rng = np.random.default_rng(seed)
    img = (rng.random((37, 53)) * 5).astype(np.float32)
    img[10:20, 5:30] = 2.5  # flat patch and edges
    assert anisotropic_channels_fast(img).tobytes() == gradient_channels(img, None, "anisotropic").tobytes()
    f = field_depth(40, 64, seed=seed).depth
    assert anisotropic_channels_fast(f).tobytes() == gradient_channels(f, None).tobytes()


def test_compiled_coarse_search_finds_the_same_blocks(monkeypatch):
    seen = []

    def both(grid, centres, w_depth):
        ref = search_level(grid, centres, w_depth)
        new = _search_compiled(grid, centres, w_depth)
        seen.append(len(centres))
        np.testing.assert_array_equal(new.best, ref.best)
        found = ref.best[:, 0] >= 0
        np.testing.assert_allclose(new.sim[found], ref.sim[found], rtol=1e-3, atol=1e-4)
        np.testing.assert_allclose(new.energy, ref.energy, rtol=1e-4, atol=1e-5)
        return ref

    monkeypatch.setattr(method._Filler, "search", staticmethod(both))
    f = field_depth(48, 80, seed=3)
    m = random_mask(f.depth.shape, 0.35, "blobs", seed=2)
    method.inpaint_paper(np.where(m, np.nan, f.depth).astype(np.float32), m, fusion="best")
    assert sum(seen) > 20


def test_forward_valid_equals_forward():
    torch.manual_seed(1)
    net = FusionNet(features=4, growth=4, dense_layers=1, hidden=4).eval()
    b, s, k = 9, 4, 11
    g = torch.Generator().manual_seed(2)
    cands, target = torch.randn(b, s, k, k, generator=g), torch.randn(b, k, k, generator=g)
    hole = (torch.rand(b, k, k, generator=g) < 0.5).float()
    q = -torch.rand(b, s, generator=g) * 3
    valid = torch.rand(b, s, generator=g) < 0.6
    valid[:, 0] = True
    valid[3] = torch.tensor([False, False, True, False])
    with torch.inference_mode():
        a, f = net(cands, target, hole, q, valid), net.forward_valid(cands, target, hole, q, valid)
    torch.testing.assert_close(f, a, rtol=1e-5, atol=1e-5)
    with torch.inference_mode():  # an invalid scale does not matter, whatever it holds
        cands2 = cands.clone()
        cands2[~valid] = 1e3
        torch.testing.assert_close(net.forward_valid(cands2, target, hole, q, valid), f)


def test_fusion_without_the_net_only_where_candidates_agree():
    rng = np.random.default_rng(0)
    k, s, b = 6, 3, 7
    cands = (2.0 + rng.normal(0, 0.3, (k, s, b, b))).astype(np.float32)
    cands[1, 1:] = cands[1, 0]  # all agree exactly
    cands[2, 1] = cands[2, 0] * (1 + 0.5 * FUSE_TOL)  # agree within the tolerance
    cands[2, 2] = 50.0  # … the invalid scale does not count
    est = cands[:, 0].copy()
    known = rng.random((k, b, b)) < 0.4
    q = -rng.random((k, s)).astype(np.float32)
    valid = np.ones((k, s), bool)
    valid[0, 1:] = False  # one valid candidate
    valid[2, 2] = False
    o = C2FOptions()
    out = _fuse(o, cands, est, known, q, valid)
    np.testing.assert_array_equal(out[0][~known[0]], cands[0, 0][~known[0]])
    np.testing.assert_array_equal(out[1][~known[1]], cands[1, 0][~known[1]])
    assert np.abs(out[2] - cands[2, 0])[~known[2]].max() <= FUSE_TOL * 2.0 * 1.01
    # the other blocks are the network's clamped fusion
    from inpaint.c2f import C2F_WEIGHTS_FILE
    from inpaint.fusion_net import load_net
    net = load_net(str(C2F_WEIGHTS_FILE))
    cn, tn, mu, sg = normalise(cands, est, np.ones(est.shape, bool), valid)
    ref = run_net(net, cn, tn, ~known, q, valid) * sg[:, None, None] + mu[:, None, None]
    vm = valid[:, :, None, None]
    ref = np.clip(ref, np.where(vm, cands, np.inf).min(1), np.where(vm, cands, -np.inf).max(1))
    np.testing.assert_allclose(out[3:], ref[3:], rtol=1e-5, atol=1e-5)


def test_nearest_source_pixel():
    src = np.zeros((20, 30), bool)
    src[2, 3] = src[15, 25] = True
    pts = np.array([[0, 0], [3, 4], [19, 29], [14, 20]], np.intp)
    assert _nearest(src, pts).tolist() == [[2, 3], [2, 3], [15, 25], [15, 25]]


def test_room_scenes_and_stereo_noise_are_deterministic():
    a, b = room_depth(60, 100, seed=4), room_depth(60, 100, seed=4)
    assert a.depth.tobytes() == b.depth.tobytes() and a.valid.all()
    assert np.isfinite(a.depth).all() and a.depth.min() > 0
    assert not np.array_equal(a.depth, room_depth(60, 100, seed=5).depth)
    n = stereo_noise(a.depth, seed=1)
    assert n.tobytes() == stereo_noise(a.depth, seed=1).tobytes()
    rel = np.abs(n - a.depth) / a.depth
    assert 0 < np.median(rel) < 0.05  # sub-pixel disparity noise: a few per cent at most


def test_c2f_training_examples_with_stereo_noise_keep_exact_ground_truth():
    from inpaint.train import TrainConfig, TrainingFrame, collect_examples

    f = field_depth(64, 96, seed=2)
    frames = [TrainingFrame(f.depth, f.valid)]
    clean = collect_examples(frames, TrainConfig(formulation="c2f", masks_per_frame=1, seed=3))
    noisy = collect_examples(frames, TrainConfig(formulation="c2f", masks_per_frame=1, seed=3, noise_fraction=1.0))
    again = collect_examples(frames, TrainConfig(formulation="c2f", masks_per_frame=1, seed=3, noise_fraction=1.0))
    assert len(clean) > 0 and len(noisy) > 0
    assert noisy.target.tobytes() == again.target.tobytes()  # deterministic
    # same mask and blocks: the ground truth (exact depth) is the same, the measured inputs are not
    assert noisy.gt.tobytes() == clean.gt.tobytes()
    assert not np.array_equal(noisy.target[noisy.known], clean.target[clean.known])
