"""Depth stage: known-disparity pairs come back to the expected metres; holes stay holes; LR check."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.depth import (
    DepthParams,
    compute_depth,
    decode_depth_mm,
    depth_from_rectified,
    encode_depth_mm,
    left_right_check,
)
from pipeline.synthetic_scene import StereoRenderer, shifted_pair

FX, BASELINE = 351.06043408538426, 0.1187186478877293  # the Rosario rectified rig


@pytest.mark.parametrize("disparity", [6, 20, 45])
def test_known_disparity_gives_expected_metres(disparity):
    left, right = shifted_pair(disparity_px=disparity, seed=disparity)
    params = DepthParams()
    depth, valid, disp = depth_from_rectified(left, right, FX, BASELINE, params)
    assert depth.dtype == np.float32 and depth.shape == left.shape
    assert np.array_equal(valid, np.isfinite(depth)) and np.array_equal(valid, np.isfinite(disp))
    expected = FX * BASELINE / disparity
    interior = valid[:, params.num_disparities:]
    assert interior.mean() > 0.85
    assert np.abs(disp[valid] - disparity).max() <= 0.5
    np.testing.assert_allclose(np.median(depth[valid]), expected, rtol=2e-3)
    assert np.percentile(np.abs(depth[valid] / expected - 1.0), 99) < 0.02
    assert not valid[:, : params.num_disparities - 1].any()  # SGBM's unmatched left band is a hole, not filled


def test_depth_is_deterministic():
    left, right = shifted_pair(disparity_px=12, seed=1)
    a = depth_from_rectified(left, right, FX, BASELINE)[0]
    b = depth_from_rectified(left, right, FX, BASELINE)[0]
    assert np.array_equal(a, b, equal_nan=True)


def test_left_right_check():
    h, w = 4, 30
    d_left = np.full((h, w), 10.0, np.float32)
    d_right = np.full((h, w), 10.0, np.float32)
    ok = left_right_check(d_left, d_right, 1.0)
    assert ok[:, 10:].all() and not ok[:, :10].any()  # x - d < 0 has no match
    d_right[1, 5] = 12.5  # the right pixel matched by left (1, 15) disagrees by 2.5 px
    d_left[2, 20] = np.nan
    d_right[3, 8] = np.nan  # matched by left (3, 18)
    d_left[0, 25] = 10.9  # rounds to x_r = 14 whose right disparity 10 is within 1 px
    ok = left_right_check(d_left, d_right, 1.0)
    assert not ok[1, 15] and not ok[2, 20] and not ok[3, 18] and ok[0, 25]
    assert ok.sum() == 4 * 20 - 3


def test_lr_check_only_removes_pixels(rosario_rig):
    renderer = StereoRenderer(rosario_rig)
    left, right = renderer.render()
    with_lr = compute_depth(rosario_rig, left, right, DepthParams())
    without = compute_depth(rosario_rig, left, right, DepthParams(lr_check=False))
    assert not (with_lr.valid & ~without.valid).any()
    assert with_lr.valid.sum() < without.valid.sum()
    both = with_lr.valid
    assert np.array_equal(with_lr.depth_m[both], without.depth_m[both])


def test_rendered_scene_depth_through_the_rig(rosario_rig):
    """Raw distorted images of planes at 2.5 m and 6 m: rectify + SGBM recovers their depth."""
    renderer = StereoRenderer(rosario_rig)
    pose = np.eye(4)
    pose[0, 3] = 0.1
    left, right = renderer.render(pose)
    gt = renderer.rectified_depth(pose)
    frame = compute_depth(rosario_rig, left, right, DepthParams(), stamp_ns=5, index=2)
    assert (frame.stamp_ns, frame.index) == (5, 2)
    assert frame.left_rect_grey.shape == (376, 672) and frame.left_rect_grey.dtype == np.uint8
    both = frame.valid & np.isfinite(gt)
    rel = np.abs(frame.depth_m[both] / gt[both] - 1.0)
    assert np.median(rel) < 0.02 and np.percentile(rel, 90) < 0.05
    assert both.sum() > 0.6 * np.isfinite(gt).sum()
    sky = ~np.isfinite(gt)
    assert frame.valid[sky].mean() < 0.05  # untextured sky stays (almost all) holes
    near = np.isfinite(gt) & (gt < 3.0) & frame.valid
    assert np.median(frame.depth_m[near]) == pytest.approx(2.5, rel=0.02)


def test_millimetre_encoding():
    depth = np.array([[0.65, 41.7, np.nan], [65.6, 1.2344, 0.0004]], np.float32)
    mm = encode_depth_mm(depth)
    assert mm.dtype == np.uint16 and mm.tolist() == [[650, 41700, 0], [0, 1234, 0]]
    back, valid = decode_depth_mm(mm)
    assert valid.tolist() == [[True, True, False], [False, True, False]]
    assert np.abs(back[valid] - depth[valid]).max() <= 0.0005 + 1e-6
    assert np.isnan(back[~valid]).all()


def test_params_validation_and_key():
    with pytest.raises(ValueError, match="multiple of 16"):
        DepthParams(num_disparities=50)
    with pytest.raises(ValueError, match="odd"):
        DepthParams(block_size=4)
    with pytest.raises(ValueError, match="mode"):
        DepthParams(mode="bm")
    assert DepthParams().key() == DepthParams().key()
    assert DepthParams().key() != DepthParams(block_size=7).key()
