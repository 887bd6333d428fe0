"""Per-observation depth σ: the σ model of the depth stage, its use in the triangulation and in the update.

The property that matters (issue: a depth-aided VIO must not get worse from a fill it is told is poor): grossly
wrong depths that come with an honest, large σ do (almost) no harm, while the same depths trusted at the
measured-depth σ do.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from msckf.config import MsckfConfig
from msckf.filter import MsckfFilter
from msckf.synthetic import iterate, make_world, matched_config
from msckf.triangulation import TriangulationParams, triangulate_batch
from msckf.types import DepthSource, FeatureObservations
from msckf.update import inverse_depth_sigma
from pipeline.depth_sigma import DepthSigmaModel, fill_distance_px, fit_fill_model


def test_inverse_depth_sigma_uses_a_stated_sigma_else_the_model():
    z = np.array([1.0, 2.0, 4.0, np.nan])
    stated = np.array([0.01, np.nan, 0.4, 0.1])
    s = inverse_depth_sigma(z, stated, inv_sigma=0.01, rel_sigma=0.05)
    assert s[0] == pytest.approx(0.01 / 1.0)                           # σ_Z / Z²
    assert s[1] == pytest.approx(np.sqrt(0.01 ** 2 + (0.05 / 2.0) ** 2))  # no stated σ: the configured model
    assert s[2] == pytest.approx(0.4 / 16.0)
    assert np.isnan(s[3])                                              # no depth, no σ


def test_raw_sigma_follows_the_disparity_model_and_fills_are_less_certain():
    model = DepthSigmaModel(fx_baseline=40.0, disparity_sigma_px=0.5, fill={"m": (0.1, 0.01, 0.5)})
    depth = np.full((20, 30), 2.0, np.float32)
    valid = np.ones((20, 30), bool)
    valid[5:15, 10:20] = False
    raw = model.raw_sigma(depth, valid)
    assert raw[0, 0] == pytest.approx(2.0 ** 2 * 0.5 / 40.0)
    assert np.isnan(raw[10, 15])
    filled = model.filled_sigma(depth, valid, "m")
    assert filled[0, 0] == pytest.approx(raw[0, 0])                    # measured pixels keep the raw σ
    dist = fill_distance_px(valid)
    assert dist[10, 10] == pytest.approx(1.0, abs=0.05) and dist[10, 14] > dist[10, 11]
    assert filled[10, 14] == pytest.approx(2.0 * (0.1 + 0.01 * dist[10, 14]), rel=1e-5)
    assert filled[10, 14] > filled[10, 10] > raw[0, 0]                 # farther into the hole: less certain


def test_disparity_span_is_the_measured_disparity_range_around_a_pixel():
    """A step from 2 m to 4 m (disparity 20 → 10 px at f·B = 40): the span is 10 px within r = 3 of the step, 0 on
    either plane away from it and where no measured pixel is near (an unmeasured block)."""
    depth = np.full((20, 40), 2.0, np.float32)
    depth[:, 20:] = 4.0
    valid = np.ones(depth.shape, bool)
    valid[5:15, 28:38] = False
    span = DepthSigmaModel(fx_baseline=40.0, edge_radius_px=3).disparity_span(depth, valid)
    assert span[5, 17] == pytest.approx(10.0) and span[5, 22] == pytest.approx(10.0)
    assert span[5, 16] == 0.0 and span[5, 23] == 0.0 and span[10, 33] == 0.0


def _numpy_sigma_maps(model: DepthSigmaModel, depth: np.ndarray, raw_valid: np.ndarray, method: str):
    """The σ maps as numpy expressions (what the compiled kernels replace): raw σ, filled σ."""
    rel0, per_px, rel_max = model.fill[method]
    z = depth.astype(np.float32)
    k = np.float32(model.disparity_sigma_px / model.fx_baseline)
    raw = np.where(raw_valid, z * z * k, np.nan).astype(np.float32)
    rel = np.minimum(np.float32(rel_max), np.float32(rel0) + np.float32(per_px) * fill_distance_px(raw_valid))
    s = np.where(raw_valid, z * z * k, np.maximum(z * rel, z * z * k))
    return raw, np.where(np.isfinite(z) & (z > 0), s, np.nan).astype(np.float32)


@pytest.mark.parametrize("per_px", [0.0, 0.0031])
def test_compiled_sigma_maps_equal_the_numpy_expressions_bit_for_bit(per_px):
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.3, 25.0, (37, 53)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[0, :4] = [0.0, -1.0, np.inf, 7.0]
    raw_valid = (rng.random(depth.shape) < 0.6) & np.isfinite(depth) & (depth > 0)
    raw_valid[10:25, 20:40] = False                                    # one large hole: distances up to ~8 px
    depth[15, 30] = 3.0                                                # a fill where the fill σ beats the raw σ
    model = DepthSigmaModel(fx_baseline=41.7, disparity_sigma_px=0.545, fill={"m": (0.146, per_px, 0.2)})
    want_raw, want_filled = _numpy_sigma_maps(model, depth, raw_valid, "m")
    assert np.array_equal(model.raw_sigma(depth, raw_valid), want_raw, equal_nan=True)
    got = model.filled_sigma(depth, raw_valid, "m")
    assert np.array_equal(got, want_filled, equal_nan=True)
    assert np.isfinite(got[15, 30]) and (per_px == 0) == (got[15, 30] == np.float32(0.146) * depth[15, 30])
    keep = rng.random(depth.shape) < 0.5
    assert np.array_equal(model.filled_sigma(depth, raw_valid, "m", keep=keep),
                          np.where(keep, want_filled, np.nan), equal_nan=True)
    with pytest.raises(ValueError, match="one shape"):                # never index past a smaller map
        model.filled_sigma(depth, raw_valid[:-1], "m")
    with pytest.raises(ValueError, match="one shape"):
        model.raw_sigma(depth, raw_valid[:, :-1])


def test_fills_open_to_the_far_field_carry_no_depth():
    # f·B = 40 px·m, σ_d = 0.5 px, 5 σ → a measured depth ≥ 40 / 2.5 = 16 m is compatible with infinity
    model = DepthSigmaModel(fx_baseline=40.0, disparity_sigma_px=0.5, fill={"m": (0.1, 0.0, 0.5)},
                            far_open_sigmas=5.0, far_open_radius_px=3, edge_disparity_sigmas=0.0)
    raw = np.full((12, 40), 4.0, np.float32)
    raw_valid = np.ones(raw.shape, bool)
    raw[:, 30:] = 18.0                                                 # the far field on the right
    raw_valid[4:8, 5:9] = False                                        # a hole among 4 m surfaces
    raw_valid[4:8, 24:30] = False                                      # a hole that borders the far field
    raw_valid[0:3, 25:29] = False                                      # a hole behind a 4 m wall (row 3)
    inpainted = np.where(raw_valid, raw, 5.0).astype(np.float32)
    all_valid = np.ones(raw.shape, bool)
    valid, sigma = model.filled(inpainted, all_valid, raw, raw_valid, "m")
    assert valid[5, 6] and sigma[5, 6] == pytest.approx(0.5, rel=1e-5)  # an enclosed fill: the fill model's σ
    assert not valid[5, 29] and not valid[5, 27] and np.isnan(sigma[5, 27])  # ≤ 3 steps from the 18 m pixels
    assert valid[5, 26] and valid[5, 24]                               # 4 and 6 steps: beyond the stated reach
    assert valid[1, 28]                                                # 2 px away, but across a measured wall
    assert valid[raw_valid].all()                                      # measured pixels are never dropped
    off = dataclasses.replace(model, far_open_sigmas=0.0)
    assert off.filled(inpainted, all_valid, raw, raw_valid, "m")[0].all()
    near = np.where(raw > 10, 12.0, raw).astype(np.float32)            # 12 m is not compatible with infinity
    assert model.filled(inpainted, all_valid, near, raw_valid, "m")[0].all()


def test_fills_at_an_occlusion_edge_carry_no_depth():
    # a 2 m plant in front of 5 m soil (disparity 20 vs 8 px at f·B = 40 px·m); SGBM's occlusion hole between them,
    # and a hole inside the flat soil
    model = DepthSigmaModel(fx_baseline=40.0, disparity_sigma_px=0.5, fill={"m": (0.1, 0.0, 0.5)},
                            far_open_sigmas=0.0, edge_disparity_sigmas=3.0, edge_radius_px=3)
    raw = np.full((20, 40), 5.0, np.float32)
    raw[:, :12] = 2.0
    raw_valid = np.ones(raw.shape, bool)
    raw_valid[:, 12:15] = False                                        # the occlusion hole right of the plant
    raw_valid[8:12, 28:32] = False                                     # a hole in flat soil
    inpainted = np.where(raw_valid, raw, 4.0).astype(np.float32)
    all_valid = np.ones(raw.shape, bool)
    valid, sigma = model.filled(inpainted, all_valid, raw, raw_valid, "m")
    assert not valid[:, 12:15].any() and np.isnan(sigma[:, 12:15]).all()  # 20 and 8 px within 3 px: 12 px > 2.1 px
    assert valid[8:12, 28:32].all()                                    # only 5 m around it: kept
    assert valid[raw_valid].all()                                      # measured pixels are never dropped
    v2, s2, far, edge = model.filled_detail(inpainted, all_valid, raw, raw_valid, "m")   # and why
    assert np.array_equal(v2, valid) and np.array_equal(s2, sigma, equal_nan=True)
    assert edge[:, 12:15].all() and not edge[raw_valid].any() and not edge[8:12, 28:32].any() and not far.any()
    off = dataclasses.replace(model, edge_disparity_sigmas=0.0)
    assert off.filled(inpainted, all_valid, raw, raw_valid, "m")[0].all()
    # SGBM noise is not an edge: soil at 5.0 m beside 5.2 m (8.0 vs 7.7 px, 0.3 px < 3·√2·0.5 = 2.1 px) keeps its fills
    noisy = np.where(np.arange(40)[None, :] % 2 == 0, 5.0, 5.2).astype(np.float32) * np.ones((20, 1), np.float32)
    assert model.filled(inpainted, all_valid, noisy, raw_valid, "m")[0].all()
    # the threshold is in disparity, not in depth ratio: the same 5 → 5.2 m step at 40× the disparity noise's scale
    assert not dataclasses.replace(model, disparity_sigma_px=0.05).filled(inpainted, all_valid, noisy, raw_valid,
                                                                           "m")[0][:, 12:15].any()
    lone = np.zeros(raw.shape, bool)                                   # no measured pixel near: nothing to compare
    assert dataclasses.replace(model, edge_radius_px=1).occlusion_edge(raw, lone).sum() == 0


def test_fill_model_fit_recovers_a_known_growth():
    rng = np.random.default_rng(0)
    dist = rng.uniform(0, 60, 200_000)
    sigma = 0.04 + 0.003 * dist
    rel0, per_px, cap = fit_fill_model(rng.normal(0, sigma), dist)
    assert rel0 == pytest.approx(0.04, abs=0.01) and per_px == pytest.approx(0.003, rel=0.15) and cap == 0.5


def _two_view_problem(depth_true: float, baseline: float):
    """One point seen from two cam0 views with a small sideways baseline (depth poorly determined)."""
    R = np.broadcast_to(np.eye(3), (1, 2, 3, 3)).copy()
    t = np.zeros((1, 2, 3))
    t[0, 1] = [-baseline, 0.0, 0.0]                                    # anchor → view 1 moves the camera by +b in x
    p = np.array([0.1, -0.05, 1.0]) * depth_true
    z = np.stack([p[:2] / p[2], (p[:2] + t[0, 1, :2]) / (p[2] + t[0, 1, 2])])[None]
    valid = np.ones((1, 2), bool)
    return R, t, z, valid, p


def test_triangulation_weights_a_depth_by_its_sigma():
    R, t, z, valid, p = _two_view_problem(depth_true=3.0, baseline=0.05)
    z = z.copy()
    z[0, 1, 0] += 0.002                                                 # 0.7 px of error on the second view
    x0 = np.array([[z[0, 0, 0], z[0, 0, 1], 1 / 2.0]])
    params = TriangulationParams()
    pa_pix, ok, _ = triangulate_batch(R, t, z, valid, x0, params)
    assert ok[0]
    depth_inv = np.array([[1 / 3.0, np.nan]])                          # the true depth, measured in the anchor view
    tight = triangulate_batch(R, t, z, valid, x0, params, depth_inv, np.array([[100.0, np.nan]]))[0]
    loose = triangulate_batch(R, t, z, valid, x0, params, depth_inv, np.array([[1e-4, np.nan]]))[0]
    # a confident depth pins the point's depth; a near-zero-weight depth leaves the pixel-only solution
    assert abs(tight[0, 2] - 3.0) < 0.01 < abs(pa_pix[0, 2] - 3.0)
    assert loose[0, 2] == pytest.approx(pa_pix[0, 2], rel=1e-3)


def _corrupt_depths(world, bias: float, stated_rel_sigma: float | None):
    """Every third track's depth × (1 + bias), optionally with a stated σ_Z = stated_rel_sigma · Z."""
    frames = []
    for obs in world.frames:
        bad = (obs.ids % 3) == 0
        depth = np.where(bad, obs.depth_m * (1.0 + bias), obs.depth_m)
        sigma = None
        if stated_rel_sigma is not None:
            sigma = np.where(bad, stated_rel_sigma * depth, np.nan)
        frames.append(dataclasses.replace(obs, depth_m=depth, depth_sigma_m=sigma))
    return dataclasses.replace(world, frames=frames)


def _final_error(world, cfg: MsckfConfig) -> float:
    flt = MsckfFilter(cfg, world.T_cam0_imu, world.T_cam1_cam0)
    flt.initialize(world.t0, world.R0, world.p0, world.v0, world.b_g0, world.b_a0, 9.81)
    errs = []
    for m, pose in iterate(world, flt):
        if pose is not None:
            errs.append(np.linalg.norm(pose.p_world - world.p_w[m]))
    return float(np.sqrt(np.mean(np.square(errs))))


def test_bad_depths_with_an_honest_sigma_do_less_harm():
    """A third of the tracks get depths 25 % too far (as a poor fill would). Told σ = 25 %, the filter is clearly
    more accurate than when it trusts them at the measured-depth σ (1 %). (Measured: clean 0.020 m, honest σ
    0.045 m, trusted 0.058 m; a bias of 1 σ shared by a third of the tracks still costs something.)"""
    w = make_world(seed=21, duration=6.0, max_features=150, depth_mode=True, depth_rel_sigma=0.01)
    cfg = matched_config(depth_row=True, depth_rel_sigma=0.01, depth_inv_sigma=1e-3)
    clean = _final_error(w, cfg)
    honest = _final_error(_corrupt_depths(w, 0.25, 0.25), cfg)
    trusted = _final_error(_corrupt_depths(w, 0.25, None), cfg)
    assert clean < honest < 0.85 * trusted


def test_depth_sigma_reaches_the_filter_from_observations():
    obs = FeatureObservations(1.0, np.array([1, 2]), np.zeros((2, 2)), np.zeros((2, 2)), np.array([2.0, np.nan]),
                              np.array([DepthSource.DEPTH_MAP, DepthSource.MONO], np.uint8), np.ones(2, np.int32),
                              np.array([0.3, 0.1]))
    with pytest.raises(ValueError, match="depth_sigma_m"):
        FeatureObservations(1.0, np.array([1]), np.zeros((1, 2)), np.zeros((1, 2)), np.ones(1),
                            np.ones(1, np.uint8), np.ones(1, np.int32), np.ones(2))
    from msckf.state import FeatureStore

    fs = FeatureStore(4)
    rows = fs.add(obs.ids)
    flt = MsckfFilter.__new__(MsckfFilter)
    flt.features = fs
    from msckf.config import MsckfConfig

    flt.config = MsckfConfig()                                         # default: no σ floor
    from msckf.filter import FrameStats

    flt._add_observations(obs, 0, FrameStats())
    assert fs.depth_sigma[rows[0], 0] == pytest.approx(0.3)
    assert np.isnan(fs.depth_sigma[rows[1], 0])                       # no depth: its σ is not kept


def test_geodesic_reach_equals_iterated_constrained_dilation():
    """The compiled search gives the same set as ``steps`` rounds of a 3 × 3 dilation kept inside ``allowed``."""
    import cv2

    from pipeline.far_field_kernels import geodesic_reach
    rng = np.random.default_rng(3)
    for steps in (0, 1, 4, 40):
        allowed = rng.random((40, 60)) < 0.6
        seed = allowed & (rng.random(allowed.shape) < 0.01)
        reach = seed.astype(np.uint8)
        for _ in range(steps):
            reach = cv2.dilate(reach, np.ones((3, 3), np.uint8)) & allowed.astype(np.uint8)
        assert np.array_equal(geodesic_reach(seed, allowed, steps), reach > 0), steps
