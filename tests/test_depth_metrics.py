"""Depth metrics on hole pixels and whole images."""

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from eval.depth_metrics import depth_metrics, psnr, ssim_map


@pytest.fixture
def scene():
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:60, 0:80]
    gt = (3.0 + 0.05 * x + 0.02 * y + 0.3 * np.sin(x / 5.0)).astype(np.float32)
    hole = np.zeros(gt.shape, bool)
    hole[20:35, 30:55] = True
    return gt, hole, rng


def test_perfect_reconstruction(scene):
    gt, hole, _ = scene
    m = depth_metrics(gt.copy(), gt, hole)
    assert m.rmse_hole == 0 and m.mae_hole == 0 and m.psnr_hole == float("inf")
    assert m.ssim_hole == pytest.approx(1.0) and m.ssim_whole == pytest.approx(1.0)


def test_known_error_values(scene):
    gt, hole, _ = scene
    pred = gt.copy()
    pred[hole] += 0.5
    m = depth_metrics(pred, gt, hole, peak=20.0)
    assert m.rmse_hole == pytest.approx(0.5, rel=1e-6) and m.mae_hole == pytest.approx(0.5, rel=1e-6)
    assert m.psnr_hole == pytest.approx(10 * np.log10(400 / 0.25), rel=1e-9)
    rho = hole.sum() / hole.size
    # known pixels untouched → PSNR_whole = PSNR_hole + 10·log10(1/ρ)
    assert m.psnr_whole == pytest.approx(m.psnr_hole + 10 * np.log10(1 / rho), rel=1e-6)
    assert m.rmse_whole == pytest.approx(0.5 * np.sqrt(rho), rel=1e-6)
    assert m.n_hole == hole.sum()


def test_ssim_matches_wang_reference_implementation(scene):
    gt, _, rng = scene
    pred = (gt + rng.normal(0, 0.2, gt.shape)).astype(np.float64)
    ours = ssim_map(pred, gt.astype(np.float64), 20.0)
    _, ref = structural_similarity(pred, gt.astype(np.float64), data_range=20.0, gaussian_weights=True, sigma=1.5,
                                   use_sample_covariance=False, full=True)
    inner = (slice(6, -6), slice(6, -6))  # borders differ only by padding mode
    np.testing.assert_allclose(ours[inner], ref[inner], atol=1e-6)


def test_invalid_ground_truth_is_excluded(scene):
    gt, hole, _ = scene
    gt = gt.copy()
    gt[25, 40] = np.nan
    pred = np.where(np.isnan(gt), 0.0, gt).astype(np.float32)
    m = depth_metrics(pred, gt, hole)
    assert m.rmse_hole == 0 and m.n_hole == hole.sum() - 1
    valid = np.ones(gt.shape, bool)
    valid[20:35, 30:42] = False
    m2 = depth_metrics(pred, np.nan_to_num(gt), hole, valid=valid)
    assert m2.n_hole == hole.sum() - 12 * 15


def test_bad_input_is_reported(scene):
    from eval.depth_metrics import EvalInputError

    gt, hole, _ = scene
    with pytest.raises(EvalInputError, match="shapes"):
        depth_metrics(gt[:10], gt, hole)
    with pytest.raises(EvalInputError, match="no hole pixel"):
        depth_metrics(gt, gt, np.zeros_like(hole))
    assert psnr(0.0) == float("inf")
