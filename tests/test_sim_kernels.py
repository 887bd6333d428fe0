"""The simulator's compiled kernels against independent references (OpenCV, numpy, more Newton steps)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.sim.noise import MipTexture
from pipeline.sim.presets import get_preset
from pipeline.sim.terrain import Terrain
from pipeline.sim.trace_kernels import raster_polygons


def test_polygon_raster_matches_opencv_and_is_unbiased() -> None:
    """Filled like cv2.fillPoly (centre-inside pixels plus the outline): nearly the same pixels, and the centroid
    of the filled pixels is unbiased over random sub-pixel placements."""
    rng = np.random.default_rng(3)
    bias, differ, total = [], 0, 0
    for _ in range(200):
        c = rng.uniform(20, 40, 2)
        half = rng.uniform(0.5, 8.0)
        ang = rng.uniform(0, np.pi)
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        quad = (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [half, 0.4 * half]) @ rot.T + c
        uv = np.concatenate([quad, np.repeat(quad[-1:], 4, 0)])[None]  # repeated last vertex, as in PolySet
        ref = np.zeros((64, 64), np.uint8)
        cv2.fillPoly(ref, [np.round(quad * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        buf = np.zeros((64, 64), np.int32)
        raster_polygons(uv.astype(np.float64), np.array([0]), buf)
        got = buf > 0
        differ += int(np.sum(got != (ref > 0)))
        total += int(ref.sum())
        ys, xs = np.nonzero(got)
        bias.append([xs.mean() - c[0], ys.mean() - c[1]])
    assert differ / total < 0.06
    assert np.all(np.abs(np.mean(bias, axis=0)) < 0.05)


def test_painter_order_nearer_polygon_wins() -> None:
    far = np.array([[[5, 5], [30, 5], [30, 30], [5, 30]]], np.float64)
    near = np.array([[[10, 10], [20, 10], [20, 20], [10, 20]]], np.float64)
    uv = np.concatenate([far, near])
    buf = np.zeros((40, 40), np.int32)
    raster_polygons(uv, np.array([0, 1]), buf)
    assert buf[15, 15] == 2 and buf[25, 25] == 1 and buf[2, 2] == 0


def test_mip_sampling_matches_bilinear_and_blends_levels() -> None:
    rng = np.random.default_rng(5)
    img = rng.random((64, 32, 3)).astype(np.float32)
    tex = MipTexture.from_image(img, 0.01)
    x = rng.uniform(-3.0, 3.0, 500)
    y = rng.uniform(-3.0, 3.0, 500)
    # level 0: bilinear, periodic, texel centres at (j + 0.5) · texel
    u = np.mod(x / 0.01, 32) - 0.5
    v = np.mod(y / 0.01, 64) - 0.5
    ref = cv2.remap(img, u.astype(np.float32)[None], v.astype(np.float32)[None], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_WRAP)[0]
    got = tex.sample_lod(x, y, 0.0)
    assert np.abs(got - ref).max() < 2e-3  # OpenCV's bilinear weights are fixed point (1/32 texel)
    # a fractional level is the linear blend of the two levels around it
    a = tex.sample_lod(x, y, 1.0)
    b = tex.sample_lod(x, y, 2.0)
    assert tex.sample_lod(x, y, 1.25) == pytest.approx(0.75 * a + 0.25 * b, abs=1e-5)
    # validity mask and the constant beyond max_level
    valid = np.arange(500) % 2 == 0
    masked = tex.sample_lod(x, y, np.where(valid, 0.0, 3.0), valid=valid, max_level=2, beyond=7.0)
    assert np.all(masked[~valid] == 0) and masked[valid] == pytest.approx(got[valid], abs=1e-6)
    assert np.all(tex.sample_lod(x, y, 2.5, max_level=2, beyond=7.0) == 7.0)


@pytest.fixture(scope="module")
def terrain() -> Terrain:
    return Terrain(get_preset("rosario-like-03").field, seed=1, centre=(10.0, 50.0))


def test_terrain_lookup_matches_bilinear_reference(terrain: Terrain) -> None:
    """The terrain is the bilinear interpolation of its two grids (reference: OpenCV's remap)."""
    rng = np.random.default_rng(7)
    x = rng.uniform(-20, 40, 2000)
    y = rng.uniform(0, 100, 2000)
    h, hx, hy = terrain.height_grad(x, y)
    from pipeline.sim import terrain as tmod

    ul = ((x - terrain._long_origin[0]) / tmod._LONG_STEP_M).astype(np.float32)[None]
    vl = ((y - terrain._long_origin[1]) / tmod._LONG_STEP_M).astype(np.float32)[None]
    period = tmod._RELIEF_SIZE * tmod._RELIEF_TEXEL_M
    ur = (np.mod(x, period) / tmod._RELIEF_TEXEL_M - 0.5).astype(np.float32)[None]
    vr = (np.mod(y, period) / tmod._RELIEF_TEXEL_M - 0.5).astype(np.float32)[None]
    ref = cv2.remap(terrain._long, ul, vl, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)[0] + \
        cv2.remap(terrain._relief, ur, vr, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)[0]
    assert np.abs(h - ref[:, 0]).max() < 2e-3  # fixed-point weights of the reference
    assert np.median(np.abs(h - ref[:, 0])) < 2e-4
    assert np.corrcoef(hx, ref[:, 1])[0, 1] > 0.999 and np.corrcoef(hy, ref[:, 2])[0, 1] > 0.999


def test_image_intersection_converges_like_many_newton_steps(terrain: Terrain) -> None:
    """The coarse-grid guess plus early stop reaches what six Newton steps from the plane reach."""
    h, w = 120, 200
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    cam = np.stack([(uu - 100) / 160.0, (vv - 30) / 160.0, np.ones_like(uu, float)], -1)
    pitch = np.radians(7.0)  # a low camera looking far, as preset 03
    r_fc = np.array([[1, 0, 0], [0, -np.sin(pitch), np.cos(pitch)], [0, -np.cos(pitch), -np.sin(pitch)]])
    dirs = (cam @ r_fc.T).astype(np.float32)
    origin = np.array([10.0, 40.0, 1.0])
    ref = terrain.intersect(origin, dirs, 4000.0, iterations=6, ref_xy=origin[:2])[0]
    got = terrain.intersect_image(origin, dirs, 4000.0, ref_xy=origin[:2])[0]
    assert np.array_equal(np.isfinite(ref), np.isfinite(got))
    ok = np.isfinite(ref)
    assert ok.mean() > 0.5
    err = np.abs(got[ok] - ref[ok])
    assert np.mean(err > 1e-3) < 0.005


def test_leaf_shadow_lookup_is_exact_bilinear_with_soft_edge() -> None:
    """The shadow-map lookup against scipy's bilinear interpolation: blocked where the leaf above casts the
    shadow, free below it and outside the map, a 1 cm soft edge in height."""
    from scipy.ndimage import map_coordinates

    from pipeline.sim.ground_kernels import atlas_occlusion

    rng = np.random.default_rng(5)
    amap = rng.uniform(0.0, 0.6, (40, 50)).astype(np.float32)
    corner, texel = np.array([3.0, -2.0]), 0.01
    disp = np.array([0.3, -0.2])
    n = 4000
    px = rng.uniform(2.9, 3.6, n)
    py = rng.uniform(-2.1, -1.5, n)
    hz = rng.uniform(0.0, 0.2, n)
    pz = rng.uniform(0.0, 0.6, n)
    out = np.empty(n, np.float32)
    atlas_occlusion(amap, corner, disp, texel, px, py, pz, hz, 0.0, out)
    u = (px + hz * disp[0] - corner[0]) / texel - 0.5
    v = (py + hz * disp[1] - corner[1]) / texel - 0.5
    inside = (u >= 0) & (v >= 0) & (u < amap.shape[1] - 1) & (v < amap.shape[0] - 1)
    occ = map_coordinates(amap.astype(np.float64), [v, u], order=1)
    ref = np.where(inside, np.clip((occ - pz) / 0.01, 0, 1), 0.0)
    assert 0.1 < inside.mean() < 0.9 and 0.05 < (ref == 1).mean() and 0.05 < (ref == 0).mean()
    np.testing.assert_allclose(out, ref, atol=1e-5)


def test_soil_under_the_rows_is_shaded_with_the_sun_overhead() -> None:
    """Sun straight overhead: soil under a canopy row gets no sun (row shadow, beyond the shadow-map range) and
    the ambient light of the occluded strip; soil halfway between rows gets the full sun on flat ground."""
    from pipeline.sim.ground_kernels import soil_radiance

    s, hc, w = 0.52, 0.4, 0.15
    rows = np.array([s, hc, w, -0.26, 10 * s, 0.0, 30.0])
    x = np.array([2 * s, 2.5 * s, 3 * s])  # under row 2, between rows 2 and 3, under row 3
    n = x.size
    idx = np.arange(n)
    out = np.zeros((n, 3), np.float32)
    soil_radiance(idx, x, np.full(n, 10.0), np.full(n, 30.0, np.float32), np.zeros(n, np.float32),
                  np.zeros(n, np.float32), np.tile(np.array([[0.2, 0.3, 0.4, 0.0, 0.0]], np.float32), (n, 1)),
                  np.ones(n, np.float32), np.ones(n, np.float32), np.zeros((1, 1), np.float32), np.zeros(2), 0.01,
                  7.0, rows, np.array([0.0, 0.0, 1.0]), 3.0, out)
    ambient_under = 1.0 * (1.0 - 0.45)  # (0.55 + 0.45 · 1) · ao, ao at the row centre
    np.testing.assert_allclose(out[[0, 2], 1] / 0.3, ambient_under, rtol=1e-5)
    ao_between = 1.0 - 0.45 * np.exp(-(0.5 * s / (0.8 * w)) ** 2)
    np.testing.assert_allclose(out[1, 1] / 0.3, ao_between + 3.0, rtol=1e-5)


def test_glare_peaks_at_the_sun_and_haze_fades_far_surfaces_to_the_horizon() -> None:
    """Glare: (0.35 + 0.06) · strength towards the sun, decreasing away from it, plus a ghost where placed. Haze:
    none within 20 m and on the sky; beyond, the radiance tends to 1.1 × the horizon colour."""
    from pipeline.sim.optics_kernels import glare_field, haze_and_glare

    sun = np.array([0.0, 0.6, 0.8])
    ang = np.radians([0.0, 2.0, 10.0, 60.0])
    dirs = np.stack([np.zeros_like(ang), np.sin(np.arctan2(0.6, 0.8) + ang), np.cos(np.arctan2(0.6, 0.8) + ang)], 1)
    dirs = (dirs * 2.0).astype(np.float32)  # any length: the kernel divides by it
    norm = np.linalg.norm(dirs, axis=1).astype(np.float32)
    cam = np.zeros((4, 3), np.float32)
    cam[3, :2] = (0.5, -0.2)
    g = np.empty(4, np.float32)
    glare_field(dirs, norm, cam, sun, 2.0, np.zeros((0, 4)), g)
    assert g[0] == pytest.approx(0.41 * 2.0, rel=1e-5) and np.all(np.diff(g) < 0)
    g2 = np.empty(4, np.float32)
    glare_field(dirs, norm, cam, sun, 2.0, np.array([[0.5, -0.2, 0.05, 0.7]]), g2)
    np.testing.assert_allclose(g2 - g, [0, 0, 0, 0.7], atol=1e-6)

    horizon = np.array([1.0, 1.1, 1.2], np.float32)
    t = np.array([10.0, 100.0, 1e5, np.inf], np.float32)
    rad = np.full((4, 3), 0.3, np.float32)
    glare_rad = np.zeros(4, np.float32)
    haze_and_glare(np.array([False, False, False, True]), t, np.ones(4, np.float32), 0.01, horizon,
                   np.zeros(1, np.float32), False, rad, glare_rad)
    e = np.exp(-1.0)
    np.testing.assert_allclose(rad[[0, 3]], 0.3, rtol=1e-6)
    np.testing.assert_allclose(rad[1], 0.3 * e + 1.1 * horizon * (1 - e), rtol=1e-5)
    np.testing.assert_allclose(rad[2], 1.1 * horizon, rtol=1e-5)
    haze_and_glare(np.ones(4, bool), t, np.ones(4, np.float32), 0.01, horizon, np.full(4, 0.5, np.float32), True,
                   rad, glare_rad)
    np.testing.assert_allclose(glare_rad, 0.5)
    np.testing.assert_allclose(rad[0], 0.3 + 0.5 * np.array([1.0, 0.97, 0.9]), rtol=1e-6)
