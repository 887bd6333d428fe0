"""Parts of the paper's method: masks, pyramid, priority terms, fusion network, options and ablation flags."""

import numpy as np
import pytest
import torch

from inpaint import InpaintInputError
from inpaint.fusion import fuse, softmax_weights
from inpaint.fusion_net import FusionNet, normalise
from inpaint.masks import MASK_KINDS, occlusion_mask, random_mask
from inpaint.method import PaperOptions, inpaint_paper
from inpaint.priority import confidence_term, data_term, fill_front, front_normals, select_blocks
from inpaint.pyramid import masked_pyramid, sample_bilinear


@pytest.mark.parametrize("kind", MASK_KINDS)
@pytest.mark.parametrize("ratio", [0.05, 0.2, 0.4])
def test_random_masks_hit_the_ratio_and_are_seeded(kind, ratio):
    m = random_mask((120, 200), ratio, kind, seed=4)
    assert abs(m.mean() - ratio) < 0.04
    assert (m == random_mask((120, 200), ratio, kind, seed=4)).all()
    assert not (m == random_mask((120, 200), ratio, kind, seed=5)).all()


def test_occlusion_mask_marks_band_and_left_of_near_objects():
    d = np.full((40, 100), 10.0, np.float32)
    d[:, 60:80] = 2.0  # a near object: disparity 10 vs 2 px (f·B = 20)
    m = occlusion_mask(d, 20.0, num_disparities=8)
    assert m[:, :8].all()
    assert m[:, 52:60].all() and not m[:, 62:].any() and not m[:, 10:50].any()


def test_masked_pyramid_ignores_hole_values():
    d = np.full((64, 64), 3.0, np.float32)
    known = np.ones((64, 64), bool)
    known[20:40, 20:40] = False
    d[~known] = 1000.0
    pyr = masked_pyramid(d, known, 3)
    for lv, (dl, wl) in enumerate(pyr[1:], 1):
        assert dl.shape == (64 >> lv, 64 >> lv)
        np.testing.assert_allclose(dl[wl > 0.01], 3.0, rtol=1e-5)


def test_bilinear_sampling_of_a_ramp_is_exact():
    y, x = np.mgrid[0:20, 0:30].astype(np.float32)
    img = 2 * x + 3 * y
    ys, xs = np.array([3.25, 10.5]), np.array([7.75, 0.5])
    np.testing.assert_allclose(sample_bilinear(img, ys, xs), 2 * xs + 3 * ys, rtol=1e-6)


def test_front_normals_confidence_and_data_term():
    hole = np.zeros((30, 30), bool)
    hole[10:20, 15:30] = True  # hole open to the right: its left boundary faces −x
    pts = fill_front(hole)
    assert len(pts) and hole[pts[:, 0], pts[:, 1]].all()
    left = pts[(pts[:, 1] == 15) & (pts[:, 0] > 12) & (pts[:, 0] < 17)]
    n = front_normals(hole, left)
    np.testing.assert_allclose(np.abs(n[:, 1]), 1.0, atol=1e-4)  # normal along x
    conf = (~hole).astype(np.float32)
    c = confidence_term(conf, left, 5)
    np.testing.assert_allclose(c, 10 / 25)  # 2 of 5 columns known
    gvec = np.zeros((30, 30, 2), np.float32)
    gvec[..., 1] = 0.5  # gradient along x (gy, gx) = (0, 0.5)
    d_par = data_term(gvec, ~hole, left, n, alpha=1.0)
    d_iso = data_term(gvec, ~hole, left, n, alpha=1.0, isophote=True)
    np.testing.assert_allclose(d_par, 0.5 + 1e-3, rtol=1e-4)  # paper: gradient along the normal
    np.testing.assert_allclose(d_iso, 1e-3, atol=1e-4)  # Criminisi: isophote ⟂ normal here


def test_block_selection_is_greedy_and_non_overlapping():
    pts = np.array([[10, 10], [12, 12], [10, 30], [30, 30], [31, 31]])
    prio = np.array([1.0, 5.0, 2.0, 0.5, 3.0])
    sel = select_blocks(pts, prio, 11, (50, 50), 10)
    assert list(sel) == [1, 4, 2]
    assert list(select_blocks(pts, prio, 11, (50, 50), 2)) == [1, 4]


def test_fusion_modes():
    cands = np.stack([np.full((2, 5, 5), v, np.float32) for v in (1.0, 2.0, 4.0)], axis=1)
    q = np.array([[-0.1, -0.5, -2.0], [-3.0, -0.2, -0.1]], np.float32)
    valid = np.array([[True, True, True], [True, False, True]])
    target = np.zeros((2, 5, 5), np.float32)
    known = np.zeros((2, 5, 5), bool)
    best = fuse("best", cands, target, known, q, valid)
    assert best[0, 0, 0] == 1.0 and best[1, 0, 0] == 4.0  # invalid scale never chosen
    w = softmax_weights(q, valid, 4.0)
    np.testing.assert_allclose(w.sum(1), 1.0)
    assert w[1, 1] == 0.0
    mean = fuse("mean", cands, target, known, q, valid, alpha=4.0)
    np.testing.assert_allclose(mean[:, 0, 0], (w * np.array([1.0, 2.0, 4.0])).sum(1), rtol=1e-6)


def test_fusion_net_shapes_and_plip_fusion_of_equal_scales():
    torch.manual_seed(0)
    net = FusionNet()
    b, s, k = 3, 4, 11
    cands = torch.randn(b, 1, k, k).expand(b, s, k, k).contiguous()
    out = net(cands, torch.randn(b, k, k), torch.zeros(b, k, k), torch.zeros(b, s), torch.ones(b, s, dtype=torch.bool))
    assert out.shape == (b, k, k) and torch.isfinite(out).all()
    # invalid scales get zero weight
    w = net.scale_weights(torch.zeros(1, 4), torch.tensor([[True, False, True, False]]))
    assert w[0, 1] == 0 and w[0, 3] == 0 and torch.allclose(w.sum(), torch.tensor(1.0))


def test_normalise_uses_known_mean_and_floor():
    cands = np.full((1, 2, 5, 5), 4.0, np.float32)
    target = np.full((1, 5, 5), 4.0, np.float32)
    known = np.zeros((1, 5, 5), bool)
    known[0, :2] = True
    cn, tn, mu, sigma = normalise(cands, target, known, np.array([[True, True]]))
    assert mu[0] == pytest.approx(4.0) and sigma[0] == pytest.approx(0.05)
    assert np.abs(cn).max() == 0 and (tn[~known] == 0).all()


def test_options_are_checked_and_ablation_flags_exist():
    assert PaperOptions().levels == 3 and PaperOptions().fusion == "net"
    for bad in ({"gradient": "laplace"}, {"fusion": "max"}, {"block": 4}, {"levels": 9}, {"domain": "log"}):
        with pytest.raises(InpaintInputError):
            PaperOptions.from_kwargs(**bad)
    opts = PaperOptions.from_kwargs(single_scale=True, gradient="sobel", fusion="best", radius=[5, 4])
    assert opts.radius == (5, 4)


def test_single_scale_uses_one_level_and_pyramid_uses_four():
    seen = []
    d = np.tile(np.linspace(2, 4, 96, dtype=np.float32), (64, 1))
    m = np.zeros(d.shape, bool)
    m[20:40, 30:60] = True
    for single in (True, False):
        inpaint_paper(np.where(m, np.nan, d).astype(np.float32), m, fusion="mean", single_scale=single,
                      observer=lambda c, cands, *rest: seen.append(cands.shape[1]))
    assert set(seen) == {1, 4}
