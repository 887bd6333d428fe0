"""Anisotropic gradient: direction and magnitude on synthetic ramps and steps; masks; tiled updates."""

import numpy as np
import pytest

from inpaint.gradient import (
    FeatureJob,
    gradient_channels,
    gradient_channels_in_rects,
    gradient_field,
    run_feature_jobs,
    template_radius,
    templates,
    vector_from_channels,
)

H, W = 48, 64


def _grid():
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    return y, x


@pytest.mark.parametrize("kind", ["anisotropic", "sobel"])
@pytest.mark.parametrize("a,b", [(0.3, 0.0), (0.0, -0.2), (0.25, 0.4), (-0.1, 0.07)])
def test_ramp_gives_exact_gradient(kind, a, b):
    y, x = _grid()
    f = gradient_field((a * x + b * y + 5.0).astype(np.float32), kind=kind)
    r = template_radius(kind)
    inner = (slice(r, H - r), slice(r, W - r))
    np.testing.assert_allclose(f.gx[inner], a, atol=1e-4)
    np.testing.assert_allclose(f.gy[inner], b, atol=1e-4)


def test_three_templates_of_eight_directions():
    tpls = templates("anisotropic")
    assert len(tpls) == 3 and all(len(t) == 9 for t in tpls)
    shapes = {tuple(tuple(r.weights.shape) for r in t) for t in tpls}
    assert len(shapes) == 3  # three different structures


@pytest.mark.parametrize("angle_deg", [0, 30, 90, 135, 200, 300])
def test_step_edge_direction_points_to_higher_side(angle_deg):
    y, x = _grid()
    th = np.deg2rad(angle_deg)
    n = np.array([np.cos(th), np.sin(th)])  # unit normal in (x, y), image axes
    s = (x - W / 2) * n[0] + (y - H / 2) * n[1]
    img = np.where(s > 0, 3.0, 1.0).astype(np.float32)  # step of height 2 towards +n
    f = gradient_field(img)
    near = (np.abs(s) < 1.0)
    near[:8], near[-8:], near[:, :8], near[:, -8:] = False, False, False, False
    g = np.stack([f.gx[near], f.gy[near]], axis=1)
    cosang = (g @ n) / np.linalg.norm(g, axis=1)
    assert np.median(cosang) > 0.97
    # edge strength: about the step height at the edge, zero far from it
    assert 1.0 <= f.strength[near].max() <= 2.0 + 1e-5
    far = np.abs(s) > 10
    far[:8], far[-8:], far[:, :8], far[:, -8:] = False, False, False, False
    assert np.abs(f.strength[far]).max() < 1e-5


def test_known_mask_excludes_hole_values():
    y, x = _grid()
    ramp = (0.2 * x + 1.0).astype(np.float32)
    known = np.ones((H, W), bool)
    known[20:28, 30:38] = False
    garbage = ramp.copy()
    garbage[~known] = 1e6  # must not leak into the gradient of known pixels
    f = gradient_field(garbage, known)
    # on known pixels whose every region keeps known pixels the slope is unbiased in sign and near 0.2
    kn = known.copy()
    kn[:6], kn[-6:], kn[:, :6], kn[:, -6:] = False, False, False, False
    assert np.all(f.gx[kn] > 0.05) and np.all(f.gx[kn] < 0.4)
    assert np.abs(f.channels).max() < 10


@pytest.mark.parametrize("kind", ["anisotropic", "sobel"])
def test_tiled_update_equals_full_computation(kind):
    rng = np.random.default_rng(3)
    img = rng.standard_normal((H, W)).astype(np.float32)
    known = rng.random((H, W)) > 0.25
    full = gradient_channels(img, known, kind)
    out = np.zeros_like(full)
    rects = [(0, 10, 0, 12), (20, 31, 40, 51), (40, 48, 55, 64)]
    gradient_channels_in_rects(img, known, rects, out, kind)
    for y0, y1, x0, x1 in rects:
        np.testing.assert_array_equal(out[y0:y1, x0:x1], full[y0:y1, x0:x1])


@pytest.mark.parametrize("kind", ["anisotropic", "sobel"])
def test_batched_update_of_many_rects_and_images_equals_full_computation(kind):
    """Rects of every size (narrow ones stacked, wide ones alone, some at the borders) of two images of different
    shapes in one pass: features and gradient vectors equal the whole-image computation."""
    rng = np.random.default_rng(11)
    imgs = [rng.standard_normal(shape).astype(np.float32) for shape in ((70, 120), (40, 50))]
    knowns = [rng.random(im.shape) > 0.3 for im in imgs]
    rect_sets = [[(0, 9, 0, 11), (5, 20, 100, 120), (30, 41, 2, 112), (60, 70, 50, 61), (44, 47, 70, 79),
                  (10, 30, 30, 40)],
                 [(0, 40, 0, 6), (12, 23, 20, 31), (35, 40, 44, 50)]]
    jobs, fulls = [], []
    for im, kn, rects in zip(imgs, knowns, rect_sets):
        full = gradient_channels(im, kn, kind)
        fulls.append((full, *vector_from_channels(full, kind)))
        jobs.append(FeatureJob(im, kn, rects, np.zeros_like(full), np.zeros(im.shape + (2,), np.float32)))
    run_feature_jobs(jobs, kind)
    for job, (full, gx, gy), rects in zip(jobs, fulls, rect_sets):
        for y0, y1, x0, x1 in rects:
            np.testing.assert_array_equal(job.out[y0:y1, x0:x1], full[y0:y1, x0:x1])
            np.testing.assert_array_equal(job.gvec_out[y0:y1, x0:x1, 0], gy[y0:y1, x0:x1])
            np.testing.assert_array_equal(job.gvec_out[y0:y1, x0:x1, 1], gx[y0:y1, x0:x1])
