"""Batched inverse-depth LM triangulation: exact without noise, robust to an outlier, features independent."""

import numpy as np

from msckf.rotation import so3_exp
from msckf.synthetic import FX, rosario_extrinsics
from msckf.triangulation import TriangulationParams, initial_guess, triangulate_batch, views_from_clones

_, _T10 = rosario_extrinsics()
R10, t10 = _T10[:3, :3], _T10[:3, 3]


def _scene(k=120, n=8, seed=0):
    rng = np.random.default_rng(seed)
    R_w_c = so3_exp(rng.normal(size=(k * n, 3)) * 0.02).reshape(k, n, 3, 3)
    j = np.broadcast_to(np.arange(n)[None, :], (k, n))
    p_c = np.stack([0.1 * j * rng.normal(size=(k, n)), 0.02 * rng.normal(size=(k, n)), 0.15 * j], axis=-1)
    pf = np.stack([rng.uniform(-3, 3, k), rng.uniform(-1, 1, k), rng.uniform(3, 15, k)], axis=1)
    return R_w_c, p_c, pf, rng


def _observe(R_w_c, p_c, pf):
    P0 = np.einsum("knji,knj->kni", R_w_c, pf[:, None, :] - p_c)
    P1 = P0 @ R10.T + t10
    return np.concatenate([P0[..., :2] / P0[..., 2:], P1[..., :2] / P1[..., 2:]], axis=-1), P0[..., 2]


def _solve(R_w_c, p_c, obs, has, depth=None, params=TriangulationParams()):
    R, t, z, v, a = views_from_clones(R_w_c, p_c, obs, has, R10, t10)
    x0 = initial_guess(R, t, z, v, 2 * a, depth)
    pa, ok, _ = triangulate_batch(R, t, z, v, x0, params)
    ar = np.arange(len(a))
    return np.einsum("kij,kj->ki", R_w_c[ar, a], pa) + p_c[ar, a], ok


def test_exact_on_noise_free_stereo_and_mono_observations():
    R_w_c, p_c, pf, _ = _scene()
    obs, _ = _observe(R_w_c, p_c, pf)
    has = np.ones(obs.shape[:2], dtype=bool)
    pw, ok = _solve(R_w_c, p_c, obs, has)
    assert ok.all()
    assert np.abs(pw - pf).max() < 1e-9
    mono = obs.copy()
    mono[..., 2:] = np.nan                              # cam0 only: parallax from the motion
    pw, ok = _solve(R_w_c, p_c, mono, has)
    assert ok.all()
    assert np.abs(pw - pf).max() < 1e-8
    # padding: features with different observation counts in one batch
    has2 = has.copy()
    has2[::2, :3] = False
    pw, ok = _solve(R_w_c, p_c, obs, has2)
    assert ok.all() and np.abs(pw - pf).max() < 1e-9


def test_robust_to_one_outlier_observation():
    R_w_c, p_c, pf, rng = _scene(seed=1)
    obs, _ = _observe(R_w_c, p_c, pf)
    has = np.ones(obs.shape[:2], dtype=bool)
    noisy = obs + rng.normal(0, 0.5 / FX, obs.shape)
    bad = noisy.copy()
    bad[:, 3, 0:2] += 30.0 / FX                         # one cam0 view 30 px off in every feature
    err = lambda pw: np.median(np.linalg.norm(pw - pf, axis=1) / pf[:, 2])  # noqa: E731
    clean, ok0 = _solve(R_w_c, p_c, noisy, has)
    robust, ok1 = _solve(R_w_c, p_c, bad, has)
    plain, ok2 = _solve(R_w_c, p_c, bad, has, params=TriangulationParams(huber_epsilon=1e3))  # no Huber
    assert ok0.all() and ok1.all() and ok2.all()
    assert err(robust) < 2.0 * err(clean)
    assert err(plain) > 4.0 * err(robust)


def test_batch_solutions_equal_individual_solutions():
    R_w_c, p_c, pf, rng = _scene(k=12, seed=2)
    obs, _ = _observe(R_w_c, p_c, pf)
    obs = obs + rng.normal(0, 1.0 / FX, obs.shape)
    has = np.ones(obs.shape[:2], dtype=bool)
    has[3, 5:] = False
    pw, _ = _solve(R_w_c, p_c, obs, has)
    for f in range(12):
        n = int(has[f].sum())
        one, _ = _solve(R_w_c[f:f + 1, :n], p_c[f:f + 1, :n], obs[f:f + 1, :n], has[f:f + 1, :n])
        assert np.allclose(one[0], pw[f], rtol=0, atol=1e-12)


def test_depth_seed_and_rejection_of_points_behind_the_camera():
    R_w_c, p_c, pf, _ = _scene(k=20, seed=3)
    obs, z = _observe(R_w_c, p_c, pf)
    has = np.ones(obs.shape[:2], dtype=bool)
    R, t, zz, v, a = views_from_clones(R_w_c, p_c, obs, has, R10, t10)
    x0 = initial_guess(R, t, zz, v, 2 * a, z[:, 0])
    assert np.allclose(x0[:, 2], 1.0 / z[:, 0])         # seeded with the measured depth
    pw, ok = _solve(R_w_c, p_c, obs, has, depth=z[:, 0])
    assert ok.all() and np.abs(pw - pf).max() < 1e-9
    # an observation set that only fits a point behind the cameras is rejected
    behind = obs.copy()
    behind[..., 2:] = np.nan
    flipped_pf = pf.copy()
    P0 = np.einsum("knji,knj->kni", R_w_c, flipped_pf[:, None, :] - p_c)
    P0[..., 2] *= -1.0                                   # mirror the point behind every camera
    behind[..., :2] = P0[..., :2] / P0[..., 2:]
    _, ok = _solve(R_w_c, p_c, behind, has)
    assert not ok.any()
