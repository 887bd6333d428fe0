"""Every inpainting method: the common contract, and the paper's method on planes, steps and repeat runs."""

import numpy as np
import pytest

from inpaint import METHODS, InpaintInputError, inpaint
from inpaint.masks import random_mask
from inpaint.synthetic import field_depth

H, W = 64, 96
FAST = {"paper": {"fusion": "mean"}}  # the network variant is tested separately below


def _plane(h=H, w=W):
    """A tilted 3-D plane seen by a pinhole camera: inverse depth is affine in (x, y); depth 2.3–4.6 m."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return (1.0 / (0.25 + 0.0012 * x + 0.0015 * y)).astype(np.float32)


def _disc_mask(h=H, w=W):
    y, x = np.mgrid[0:h, 0:w]
    return ((y - h / 2) ** 2 + (x - w / 2) ** 2) < 12 ** 2


@pytest.mark.parametrize("method", sorted(METHODS))
def test_known_pixels_untouched_and_output_finite(method):
    f = field_depth(H, W, seed=4)
    mask = random_mask((H, W), 0.2, "mixed", seed=2)
    depth = np.where(mask, np.nan, f.depth).astype(np.float32)
    out = inpaint(depth, mask, method=method, **FAST.get(method, {}))
    assert out.dtype == np.float32 and out.shape == depth.shape
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[~mask], depth[~mask])
    assert out[mask].min() > 0


@pytest.mark.parametrize("method", sorted(METHODS))
def test_empty_mask_returns_a_copy(method):
    d = _plane()
    out = inpaint(d, np.zeros(d.shape, bool), method=method)
    np.testing.assert_array_equal(out, d)
    assert out is not d


@pytest.mark.parametrize("method", sorted(METHODS))
def test_bad_inputs_raise_clear_errors(method):
    d = _plane()
    m = _disc_mask()
    with pytest.raises(InpaintInputError, match="every pixel is a hole"):
        inpaint(d, np.ones(d.shape, bool), method=method)
    with pytest.raises(InpaintInputError, match="all NaN"):
        inpaint(np.full(d.shape, np.nan, np.float32), m, method=method)
    with pytest.raises(InpaintInputError, match="float32"):
        inpaint(d.astype(np.float64), m, method=method)
    with pytest.raises(InpaintInputError, match="does not match"):
        inpaint(d, m[:-1], method=method)
    with pytest.raises(InpaintInputError, match="bool"):
        inpaint(d, m.astype(np.uint8), method=method)


def test_unknown_method_and_option():
    d, m = _plane(), _disc_mask()
    with pytest.raises(InpaintInputError, match="unknown inpainting method"):
        inpaint(d, m, method="deepfill")
    with pytest.raises(InpaintInputError, match="unknown option"):
        inpaint(d, m, method="paper", blok=3)


@pytest.mark.parametrize("fusion", ["net", "mean", "best"])
def test_paper_fills_a_planar_hole_near_exactly(fusion):
    d = _plane()
    m = _disc_mask()
    out = inpaint(np.where(m, np.nan, d).astype(np.float32), m, method="paper", fusion=fusion)
    err = np.abs(out[m] - d[m])
    assert err.mean() < 0.01, err.mean()  # metres, on a 2.3–4.6 m plane
    assert err.max() < (0.1 if fusion == "net" else 0.01), err.max()  # copies are exact; the net adds a residual


@pytest.mark.parametrize("options", [{}, {"fusion": "best"}, {"single_scale": True}, {"gradient": "sobel"}])
def test_paper_keeps_a_step_edge_sharp(options):
    y, x = np.mgrid[0:H, 0:W]
    d = np.where(x < 50, 2.0, 5.0).astype(np.float32)
    m = (y >= 22) & (y < 42) & (x >= 38) & (x < 62)  # hole straddling the edge
    raw = np.where(m, np.nan, d).astype(np.float32)
    out = inpaint(raw, m, method="paper", **options)
    smooth = inpaint(raw, m, method="biharmonic")  # a smooth filler, for scale: ramps over ~1/3 of the hole
    intermediate = (out[m] > 2.3) & (out[m] < 4.7)
    assert intermediate.mean() < 0.15  # the transition is at most ~3 of the hole's 24 columns wide
    assert intermediate.mean() < 0.5 * ((smooth[m] > 2.3) & (smooth[m] < 4.7)).mean()
    wrong_side = np.abs(out[m] - d[m]) > 1.0
    assert wrong_side.mean() < 0.10  # the edge stays near its place


@pytest.mark.parametrize("method,options", [("paper", {}), ("paper", {"fusion": "mean"}), ("paper-greedy", {}),
                                            ("ebm", {}),
                                            ("biharmonic", {}), ("ipbasic", {}), ("telea", {}), ("ns", {})])
def test_deterministic_bit_identical(method, options):
    f = field_depth(H, W, seed=9)
    mask = random_mask((H, W), 0.25, "blobs", seed=3)
    depth = np.where(mask, np.nan, f.depth).astype(np.float32)
    a = inpaint(depth, mask, method=method, **options)
    b = inpaint(depth.copy(), mask.copy(), method=method, **options)
    assert a.tobytes() == b.tobytes()


def test_nan_outside_mask_is_filled_and_guide_is_validated():
    d = _plane()
    m = _disc_mask()
    d2 = d.copy()
    d2[5, 5] = np.nan  # not in the mask, but not usable either
    out = inpaint(d2, m, method="ns")
    assert np.isfinite(out[5, 5])
    with pytest.raises(InpaintInputError, match="guide"):
        inpaint(d, m, guide=np.zeros((3, 3)), method="paper")


@pytest.mark.parametrize("method", sorted(METHODS))
def test_zero_depth_outside_the_mask_counts_as_a_hole(method):
    d = _plane()
    m = _disc_mask()
    d0 = d.copy()
    d0[3:6, 70:74] = 0.0  # "no depth" code, not in the mask
    out = inpaint(d0, m, method=method, **FAST.get(method, {}))
    assert (out[3:6, 70:74] > 1.0).all() and np.isfinite(out).all()
    keep = ~m
    keep[3:6, 70:74] = False
    np.testing.assert_array_equal(out[keep], d0[keep])
