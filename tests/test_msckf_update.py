"""Measurement update: Jacobians against numerical ones, OC projection, the fast Schur-complement update and
χ² gate against the literal S-MSCKF QR path, and the pruning policy."""

import numpy as np
import pytest

from msckf.config import load_config
from msckf.filter import MsckfFilter
from msckf.options import WindowOptions
from msckf.rotation import so3_exp
from msckf.state import CloneStore
from msckf.synthetic import iterate, make_world, rosario_extrinsics
from msckf.update import (
    FeatureBatch,
    MeasurementSpec,
    ekf_update_information,
    find_redundant_clones,
    gating_chi2,
    measurement_blocks,
    qr_update,
    schur_information,
)

WINDOW = WindowOptions(rotation_threshold=0.2618, translation_threshold=0.4, tracking_rate_threshold=0.5)

_, _T10 = rosario_extrinsics()
G_W = np.array([0.0, 0.0, -9.81])


def _single_feature(rng, n=3):
    R_w_c = so3_exp(rng.normal(size=(n, 3)) * 0.1)[None]
    p_c = (np.arange(n)[:, None] * np.array([0.2, 0.0, 0.3]) + rng.normal(size=(n, 3)) * 0.05)[None]
    p_f = np.array([[0.5, -0.3, 6.0]])
    obs = np.zeros((1, n, 4))
    depth = np.full((1, n), 5.5)
    return R_w_c, p_c, p_f, obs, depth


@pytest.mark.parametrize("depth_row", [False, True])
def test_measurement_jacobians_match_numerical_jacobians(depth_row):
    rng = np.random.default_rng(0)
    n = 3
    R_w_c, p_c, p_f, obs, depth = _single_feature(rng, n)
    spec = MeasurementSpec(_T10[:3, :3], _T10[:3, 3], G_W, 0.01, oc=False, depth_row=depth_row,
                           depth_inv_sigma=0.02, depth_rel_sigma=0.0)
    use = np.full((1, n), depth_row)
    has = np.ones((1, n), dtype=bool)
    pos = np.arange(n)[None]

    def h(Rw, pc, pf):
        b = measurement_blocks(spec, pf, Rw, pc, np.swapaxes(Rw, -1, -2), pc, obs, depth, use, has, pos, n)
        return -b.r[0]                                  # obs are zeros: r = −h (whitened depth row)

    b = measurement_blocks(spec, p_f, R_w_c, p_c, np.swapaxes(R_w_c, -1, -2), p_c, obs, depth, use, has, pos, n)
    eps = 1e-7
    for j in range(n):
        for a in range(6):
            d = np.zeros(3)
            d[a % 3] = eps
            Rp, Rm, pp, pm = R_w_c.copy(), R_w_c.copy(), p_c.copy(), p_c.copy()
            if a < 3:
                Rp[0, j] = R_w_c[0, j] @ so3_exp(d)
                Rm[0, j] = R_w_c[0, j] @ so3_exp(-d)
            else:
                pp[0, j] += d
                pm[0, j] -= d
            num = (h(Rp, pp, p_f) - h(Rm, pm, p_f)) / (2 * eps)
            assert np.allclose(num[j][b.rows[0, j]], b.Hx[0, j][b.rows[0, j], a], atol=1e-6)
            others = [i for i in range(n) if i != j]
            assert np.allclose(num[others], 0.0, atol=1e-9)  # a clone only affects its own rows
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        num = (h(R_w_c, p_c, p_f + d) - h(R_w_c, p_c, p_f - d)) / (2 * eps)
        assert np.allclose(num[b.rows[0]], b.Hf[0][..., a][b.rows[0]], atol=1e-6)
    assert b.rows.shape[-1] == (5 if depth_row else 4)
    if depth_row:
        assert b.rows[0, :, 4].all()
        assert (~b.rows[0, :, 2:4]).all()               # the depth row replaces the depth-implied cam1 rows


def test_oc_projection_annihilates_the_unobservable_direction():
    rng = np.random.default_rng(1)
    R_w_c, p_c, p_f, obs, depth = _single_feature(rng)
    R_null = np.swapaxes(R_w_c, -1, -2) @ so3_exp(rng.normal(size=3) * 0.01)   # first estimates differ a bit
    p_null = p_c + rng.normal(size=p_c.shape) * 0.01
    spec = MeasurementSpec(_T10[:3, :3], _T10[:3, 3], G_W, 0.01, oc=True)
    b = measurement_blocks(spec, p_f, R_w_c, p_c, R_null, p_null, obs, depth, np.zeros((1, 3), bool),
                           np.ones((1, 3), bool), np.arange(3)[None], 3)
    for j in range(3):
        u = np.concatenate([R_null[0, j] @ G_W, np.cross(p_f[0] - p_null[0, j], G_W)])
        assert np.allclose(b.Hx[0, j] @ u, 0.0, atol=1e-12)
        assert np.allclose(b.Hf[0, j], -b.Hx[0, j][:, 3:6])


#: The simulated world's noise as the filter is told it (normalised pixel σ = 1 px at fx 351.06).
# the synthetic world's noise: white 1 px pixels (update and gate σ alike, not the 0.18 px gate calibrated on
# rendered KLT tracks); its depths are unbiased, so the gate needs no shared scale term
_WORLD_NOISE = dict(gyro_noise=0.002, acc_noise=0.02, gyro_bias_noise=1e-4, acc_bias_noise=1e-3,
                    feature_noise=1.0 / 351.06, gate_noise=1.0 / 351.06, gate_depth_scale=0.0,
                    gyro_bias_cov=1e-6, acc_bias_cov=1e-4)


def _triangulated_live_rows(flt: MsckfFilter) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The filter's live features seen by ≥ 3 clones, triangulated where not yet: (rows that are initialised,
    clone order, triangulation success of those that needed it)."""
    from msckf.filter import FrameStats

    fs = flt.features
    rows = fs.alive_rows()
    order = np.asarray(flt.clones.order)
    rows = rows[fs.has[rows][:, order].sum(axis=1) >= 3]
    ok = flt._triangulate(rows[~fs.initialized[rows]], FrameStats())
    return rows[fs.initialized[rows]], order, ok


@pytest.fixture(scope="module", params=["stereo", "depth"])
def running_filter(request):
    """A filter after 40 frames of the simulated world (stereo matches or depth-map observations), with its
    live features triangulated."""
    w = make_world(seed=3, duration=3.0, max_features=120, depth_mode=request.param == "depth",
                   depth_rel_sigma=0.02)
    cfg = load_config(dict(_WORLD_NOISE, depth_row=False))
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81,
                   covariance=np.diag(np.r_[[1e-4] * 3, [1e-6] * 3, [1e-2] * 3, [1e-4] * 3, [1e-4] * 3,
                                            [1e-5] * 3, [1e-5] * 3]))
    for _ in iterate(w, flt, stop_after=40):
        pass
    rows, order, ok = _triangulated_live_rows(flt)
    assert len(ok) == 0 or ok.mean() > 0.9
    return flt, rows, order


def _projected_chi2(P, batch, sigma, n_clones):
    """Reference χ² of each feature, literally: QR null space of its H_f, γ = r_oᵀ(H_o P_cc H_oᵀ + σ²I)⁻¹r_o."""
    k, n, R, _ = batch.Hx.shape
    gam = np.full(k, np.inf)
    Pcc = P[21:, 21:]
    for f in range(k):
        rows = batch.rows[f].reshape(-1)
        m = int(rows.sum())
        if m <= 3:
            continue
        Hx = np.zeros((n * R, 6 * n_clones))
        for j in range(n):
            c = batch.pos[f, j]
            if c < n_clones:
                Hx[j * R:(j + 1) * R, 6 * c:6 * c + 6] = batch.Hx[f, j]
        Q2 = np.linalg.qr(batch.Hf[f].reshape(-1, 3)[rows], mode="complete")[0][:, 3:]
        Ho, ro = Q2.T @ Hx[rows], Q2.T @ batch.r[f].reshape(-1)[rows]
        gam[f] = ro @ np.linalg.solve(Ho @ Pcc @ Ho.T + sigma * sigma * np.eye(m - 3), ro)
    return gam


@pytest.mark.parametrize("oc", [True, False])
@pytest.mark.parametrize("depth_row", [False, True])
def test_schur_update_equals_qr_null_space_update(running_filter, oc, depth_row):
    flt, rows, order = running_filter
    spec = MeasurementSpec(flt.R_c1_c0, flt.t_c1_c0, flt.g_w, flt.config.update.feature_noise, oc=oc,
                           depth_row=depth_row)
    mask = flt.features.has[rows][:, order]
    b = flt._batch(rows, mask, spec)
    has_depth = bool(np.isfinite(flt.features.depth[rows]).any())
    assert b.rows.shape[-1] == (5 if depth_row else 4)
    assert not depth_row or b.rows[..., 4].any() == has_depth
    sigma = flt.config.update.feature_noise
    n_cl = len(order)
    dx_ref, P_ref = qr_update(flt.P, b, sigma, n_cl)
    gamma_ref = _projected_chi2(flt.P, b, sigma, n_cl)
    Lam, eta, ok = schur_information(b, n_cl)
    assert ok.all()
    dx, P_new = ekf_update_information(flt.P, Lam, eta, sigma)
    assert np.allclose(dx, dx_ref, rtol=1e-7, atol=1e-10 * np.abs(dx_ref).max())
    assert np.allclose(P_new, P_ref, rtol=1e-6, atol=1e-9 * np.abs(P_ref).max())
    gamma = gating_chi2(flt.P, b, sigma)
    assert np.allclose(gamma, gamma_ref, rtol=1e-7)


def test_filter_runs_identically_with_schur_and_qr_updates():
    w = make_world(seed=4, duration=4.0, max_features=80)
    poses = {}
    for method in ("schur", "qr"):
        cfg = load_config(dict(gyro_noise=0.002, acc_noise=0.02, gyro_bias_noise=1e-4, acc_bias_noise=1e-3,
                               feature_noise=1.0 / 351.06, gyro_bias_cov=1e-6, acc_bias_cov=1e-4,
                               update_method=method))
        flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
        flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
        poses[method] = np.array([np.r_[p.p_world, p.v_world] for _, p in iterate(w, flt)])
    assert np.abs(poses["schur"] - poses["qr"]).max() < 1e-8


def test_pruning_policy_follows_msckf_vio():
    cl = CloneStore(8)
    for i in range(6):                                  # 6 clones, 1 m apart: nothing is redundant
        cl.add(i, float(i), np.eye(3), np.array([float(i), 0.0, 0.0]))
    assert find_redundant_clones(cl, WINDOW, 0.9) == [cl.order[0], cl.order[1]]
    cl2 = CloneStore(8)
    for i, x in enumerate([0.0, 1.0, 2.0, 2.1, 2.2, 5.0]):   # 3rd/2nd-newest within 0.4 m of the key (4th-newest)
        cl2.add(i, float(i), np.eye(3), np.array([x, 0.0, 0.0]))
    assert find_redundant_clones(cl2, WINDOW, 0.9) == [cl2.order[3], cl2.order[4]]
    # low tracking rate → the oldest go, even when the recent ones are close
    assert find_redundant_clones(cl2, WINDOW, 0.3) == [cl2.order[0], cl2.order[1]]
    cl3 = CloneStore(8)
    for i, x in enumerate([0.0, 1.0, 2.0, 2.1, 5.0, 6.0]):   # 3rd-newest close, 2nd-newest far
        cl3.add(i, float(i), np.eye(3), np.array([x, 0.0, 0.0]))
    cl3.R_w_c[cl3.order[3]] = so3_exp(np.array([0.0, 0.0, 0.1]))      # 5.7° < 15°: still redundant
    assert find_redundant_clones(cl3, WINDOW, 0.9) == [cl3.order[0], cl3.order[3]]
    cl3.R_w_c[cl3.order[3]] = so3_exp(np.array([0.0, 0.0, 0.3]))      # 17° > 15°: not redundant
    assert find_redundant_clones(cl3, WINDOW, 0.9) == [cl3.order[0], cl3.order[1]]


def test_robust_weight_scales_a_features_sigma_by_its_excess_chi2(running_filter):
    """A feature with γ/dof = 4·k enters with half the weight (σ doubled); features within
    ``k`` are untouched, and a weighted feature moves the state less than the unweighted one."""
    from msckf.update import downweight_features

    flt, rows, order = running_filter
    spec = MeasurementSpec(flt.R_c1_c0, flt.t_c1_c0, flt.g_w, flt.config.update.feature_noise, depth_row=True)
    b = flt._batch(rows[:6], flt.features.has[rows[:6]][:, order], spec)
    sigma = flt.config.update.feature_noise
    gamma = gating_chi2(flt.P, b, sigma)
    dof = b.n_rows - 3
    k = 2.0
    g_dof = np.array([0.5, 1.9, 4.0 * k, 9.0 * k, 0.1, 2.0 * k])
    w = downweight_features(b, g_dof, k)
    scale = np.array([1.0, 1.0, 0.5, 1.0 / 3.0, 1.0, 1.0 / np.sqrt(2.0)])
    assert np.allclose(w.r, b.r * scale[:, None, None])
    assert np.allclose(w.Hx, b.Hx * scale[:, None, None, None])
    gw = gating_chi2(flt.P, w, sigma)
    assert np.allclose(gw[[0, 1, 4]], gamma[[0, 1, 4]]) and np.all(gw[[2, 3, 5]] < gamma[[2, 3, 5]])
    one = b.subset(np.array([False, False, True, False, False, False]))
    dx_full, _ = qr_update(flt.P, one, sigma, len(order))
    dx_weighted, _ = qr_update(flt.P, w.subset(np.array([False, False, True, False, False, False])),
                                            sigma, len(order))
    assert np.linalg.norm(dx_weighted) < np.linalg.norm(dx_full)
    assert dof.min() > 0


def test_track_drift_whitening_makes_the_gate_statistic_chi2_for_drifting_tracks():
    """Tracks whose pixel error is white jitter plus a random walk (as KLT drift on the simulator is): with the
    drift model the χ² statistic has its nominal mean (γ/dof ≈ 1); treating the errors as white with the same
    jitter σ inflates it several times. q = 0 leaves the batch untouched."""
    from msckf.update import FeatureBatch, whiten_track_drift

    rng = np.random.default_rng(7)
    k, n, sigma, q, dt = 600, 10, 3e-4, 2.4e-6, 1.0 / 15.0
    t = np.tile(np.arange(n) * dt, (k, 1)) + 5.0
    valid = np.ones((k, n), bool)
    valid[: k // 3, 7:] = False                                      # shorter tracks, padded
    rows = np.zeros((k, n, 4), bool)
    rows[:, :, :2] = valid[:, :, None]
    Hf = rng.normal(size=(k, n, 4, 3)) * rows[..., None]
    steps = rng.normal(size=(k, n, 2)) * np.sqrt(q * dt)
    steps[:, 0] = 0.0
    err = np.cumsum(steps, axis=1) + rng.normal(size=(k, n, 2)) * sigma
    r = np.zeros((k, n, 4))
    r[:, :, :2] = err + np.einsum("knrj,kj->knr", Hf[:, :, :2], rng.normal(size=(k, 3)))
    r *= rows
    b = FeatureBatch(np.zeros((k, n), np.int64), np.zeros((k, n, 4, 6)), Hf, r, rows)
    P = np.zeros((21 + 6, 21 + 6))
    dof = b.n_rows - 3
    white = gating_chi2(P, b, sigma) / dof
    whitened = gating_chi2(P, whiten_track_drift(b, t, valid, sigma, q), sigma) / dof
    assert 0.9 < whitened.mean() < 1.1
    assert white.mean() > 3.0
    assert whiten_track_drift(b, t, valid, sigma, 0.0) is b


def test_track_drift_whitening_of_stereo_rows_shares_the_drift_between_cameras():
    """A stereo track's right coordinate is matched from the left one in every frame, so both carry the same
    random walk (plus their own jitter): the joint (u0, u1) / (v0, v1) model gives γ/dof ≈ 1 where whitening each
    row on its own (independent walks) misstates the statistic."""
    from msckf.update import FeatureBatch, whiten_track_drift

    rng = np.random.default_rng(11)
    k, n, sigma, q, dt = 600, 10, 3e-4, 2.4e-6, 1.0 / 15.0
    t = np.tile(np.arange(n) * dt, (k, 1))
    valid = np.ones((k, n), bool)
    valid[: k // 4, 6:] = False
    rows = np.repeat(valid[:, :, None], 4, axis=2)
    rows[k // 2:, :3, 2:] = False                                    # some right observations missing
    Hf = rng.normal(size=(k, n, 4, 3)) * rows[..., None]
    steps = rng.normal(size=(k, n, 2)) * np.sqrt(q * dt)
    steps[:, 0] = 0.0
    walk = np.cumsum(steps, axis=1)                                  # (k, n, 2): u and v drift, shared
    err = np.concatenate([walk, walk], axis=2) + rng.normal(size=(k, n, 4)) * sigma
    r = (err + np.einsum("knrj,kj->knr", Hf, rng.normal(size=(k, 3)))) * rows
    b = FeatureBatch(np.zeros((k, n), np.int64), np.zeros((k, n, 4, 6)), Hf, r, rows)
    P = np.zeros((21 + 6, 21 + 6))
    dof = b.n_rows - 3
    joint = gating_chi2(P, whiten_track_drift(b, t, valid, sigma, q), sigma) / dof
    assert 0.9 < joint.mean() < 1.1
    # the same rows whitened one camera at a time (as if the walks were independent) are off
    left_only = FeatureBatch(b.pos, b.Hx, b.Hf, b.r * np.array([1, 1, 0, 0]), b.rows & np.array([1, 1, 0, 0], bool))
    right_only = FeatureBatch(b.pos, b.Hx, b.Hf, b.r * np.array([0, 0, 1, 1]), b.rows & np.array([0, 0, 1, 1], bool))
    wl, wr = whiten_track_drift(left_only, t, valid, sigma, q), whiten_track_drift(right_only, t, valid, sigma, q)
    separate = FeatureBatch(b.pos, wl.Hx + wr.Hx, wl.Hf + wr.Hf, wl.r + wr.r, b.rows)
    ratio = float((gating_chi2(P, separate, sigma) / dof).mean())
    assert ratio > 1.5, ratio  # independent walks: the shared common-mode error counts as information


def _qr_update_full_width(P, batch, sigma, n_clones):
    """Reference: the full-width S-MSCKF update (every clone column, dense Joseph form), as before 2026-12-02."""
    from msckf.update import null_space_project

    ncol = 6 * n_clones
    H, r = null_space_project(batch, n_clones)
    if H.shape[0] > H.shape[1]:
        Raug = np.linalg.qr(np.concatenate([H, r[:, None]], axis=1), mode="r")
        H, r = Raug[:ncol, :ncol], Raug[:ncol, ncol]
    Hfull = np.zeros((H.shape[0], P.shape[0]))
    Hfull[:, 21:] = H
    S = Hfull @ P @ Hfull.T + sigma * sigma * np.eye(H.shape[0])
    K = np.linalg.solve(S, Hfull @ P).T
    IKH = np.eye(P.shape[0]) - K @ Hfull
    P_new = IKH @ P @ IKH.T + sigma * sigma * K @ K.T
    return K @ r, 0.5 * (P_new + P_new.T)


@pytest.mark.parametrize("which", ["all", "two_clones", "one_feature"])
def test_active_column_qr_update_equals_the_full_width_update(running_filter, which):
    """The update on the observed clones' columns (low-rank Joseph form) equals the dense full-width one to
    rounding, for a batch over every clone, a pruning-like batch over two clones and a single feature."""
    from msckf.update import null_space_project, null_space_project_active

    flt, rows, order = running_filter
    spec = MeasurementSpec(flt.R_c1_c0, flt.t_c1_c0, flt.g_w, flt.config.update.feature_noise)
    mask = flt.features.has[rows][:, order].copy()
    if which == "two_clones":
        mask[:, 2:] = False                            # the two oldest clones, as a pruning update
        rows, mask = rows[mask.sum(axis=1) == 2], mask[mask.sum(axis=1) == 2]
    elif which == "one_feature":
        rows, mask = rows[:1], mask[:1]
    b = flt._batch(rows, mask, spec)
    sigma = flt.config.update.feature_noise
    n_cl = len(order)
    H_a, r_a, active = null_space_project_active(b, n_cl)
    H_full, r_full = null_space_project(b, n_cl)
    cols = (6 * active[:, None] + np.arange(6)).reshape(-1)
    assert np.array_equal(H_full[:, cols], H_a) and np.array_equal(r_full, r_a)
    assert not np.any(np.delete(H_full, cols, axis=1))
    if which == "two_clones":
        assert len(active) == 2
    dx_ref, P_ref = _qr_update_full_width(flt.P, b, sigma, n_cl)
    dx, P_new = qr_update(flt.P, b, sigma, n_cl)
    assert np.abs(dx - dx_ref).max() <= 1e-12 * np.abs(dx_ref).max()
    assert np.abs(P_new - P_ref).max() <= 1e-12 * np.abs(P_ref).max()
    lo, lo_ref = np.linalg.eigvalsh(P_new).min(), np.linalg.eigvalsh(P_ref).min()
    assert lo >= lo_ref - 1e-14 * np.abs(P_ref).max()


def test_depth_track_whitening_counts_correlated_depth_rows_as_they_inform():
    """n depth rows of a track whose errors share a part of variance β (× a reading's own) carry the information
    n / (1 + nβ) of one row, not n; pixel rows are untouched, padding stays zero, β = 0 is a no-op, and the χ²
    statistic of rows with such a shared error has its nominal mean and spread after whitening."""
    from msckf.update import FeatureBatch, whiten_depth_track

    rng = np.random.default_rng(3)
    k, n, beta = 2000, 8, 2.0
    rows = np.zeros((k, n, 5), bool)
    rows[:, :, 4] = True
    rows[: k // 2, 6:, 4] = False                                    # shorter tracks: padding
    h = rng.normal(size=3)
    Hf = np.where(rows[..., None], np.broadcast_to(h, (k, n, 5, 3)), 0.0)
    err = rng.normal(size=(k, 1)) * np.sqrt(beta) + rng.normal(size=(k, n))
    r = np.zeros((k, n, 5))
    r[:, :, 4] = np.where(rows[:, :, 4], err, 0.0)
    b = FeatureBatch(np.zeros((k, n), np.int64), np.zeros((k, n, 5, 6)), Hf, r, rows)
    w = whiten_depth_track(b, beta)
    info = np.einsum("knj,kni->kji", w.Hf[:, :, 4], w.Hf[:, :, 4])   # (k, 3, 3) Hfᵀ Hf of the depth rows
    m = rows[:, :, 4].sum(axis=1)
    expect = (m / (1 + m * beta))[:, None, None] * np.outer(h, h)
    np.testing.assert_allclose(info, expect, rtol=1e-9, atol=1e-12)
    assert np.all(w.r[~rows] == 0.0) and np.array_equal(w.Hf[:, :, :4], b.Hf[:, :, :4])
    assert whiten_depth_track(b, 0.0) is b
    # χ² of the raw residual (no state uncertainty, no feature fit): mean m when whitened, inflated when not
    g_white = np.einsum("kn,kn->k", r[:, :, 4], r[:, :, 4]) / m
    g_whitened = np.einsum("kn,kn->k", w.r[:, :, 4], w.r[:, :, 4]) / m
    assert 0.9 < g_whitened.mean() < 1.1
    assert g_white.mean() > 2.5


def test_gate_noise_sets_the_pixel_rows_sigma_and_leaves_the_depth_row_its_own():
    """``gating_chi2(..., pixel_sigma=σ_g)``: features whose pixel rows carry white noise σ_g (plus an error that
    the feature position absorbs) and whose inverse-depth row carries its own σ (whitened to the feature σ σ_f)
    have γ/dof ≈ 1; with σ_f on every row γ/dof drops to roughly (σ_g/σ_f)² on the pixel share; σ_g = σ_f is
    the default path to the last bit."""
    from msckf.update import FeatureBatch

    rng = np.random.default_rng(11)
    k, n, sig_f, sig_g = 800, 8, 7e-3, 1e-3
    rows = np.zeros((k, n, 5), bool)
    rows[:, :, :2] = True
    rows[:, :, 4] = rng.random((k, n)) < 0.5                          # half the observations carry a depth row
    Hf = rng.normal(size=(k, n, 5, 3)) * rows[..., None]
    r = np.zeros((k, n, 5))
    r[:, :, :4] = rng.normal(size=(k, n, 4)) * sig_g
    r[:, :, 4] = rng.normal(size=(k, n)) * sig_f                      # whitened depth row: σ_f
    r = (r + np.einsum("knrj,kj->knr", Hf, rng.normal(size=(k, 3)) * 0.05)) * rows
    b = FeatureBatch(np.zeros((k, n), np.int64), np.zeros((k, n, 5, 6)), Hf, r, rows)
    P = np.zeros((21 + 6, 21 + 6))
    dof = b.n_rows - 3
    calibrated = gating_chi2(P, b, sig_f, sig_g) / dof
    assert 0.93 < calibrated.mean() < 1.07
    assert gating_chi2(P, b, sig_f).mean() / dof.mean() < 0.5
    np.testing.assert_array_equal(gating_chi2(P, b, sig_f, sig_f), gating_chi2(P, b, sig_f))


def test_stereo_front_end_gates_with_its_own_noise_and_the_depth_front_end_keeps_the_config():
    """``msckf.vio.filter_config``: the stereo back end gets ``gate_noise = stereo_gate_noise``, ``feature_noise =
    stereo_feature_noise`` and ``track_drift_psd = stereo_track_drift_psd``; the depth back end gets the config
    unchanged; a stereo value of 0 falls back to the shared one."""
    from msckf.vio import filter_config

    cfg = load_config({"stereo_gate_noise": 0.0005, "gate_noise": 0.0, "stereo_feature_noise": 0.0009,
                       "stereo_track_drift_psd": 2e-6})
    st = filter_config(cfg, "stereo").update
    assert (st.gate_noise, st.feature_noise, st.track_drift_psd) == (0.0005, 0.0009, 2e-6)
    assert filter_config(cfg, "depth") is cfg
    off = load_config({"stereo_gate_noise": 0.0, "gate_noise": 0.002, "stereo_feature_noise": 0.0,
                       "stereo_track_drift_psd": 0.0, "track_drift_psd": 1e-6})
    st = filter_config(off, "stereo").update
    assert (st.gate_noise, st.feature_noise, st.track_drift_psd) == (0.002, off.update.feature_noise, 1e-6)


def test_gate_statistic_stays_large_for_a_feature_with_a_huge_jacobian():
    """A real feature (tests/data/gate_huge_jacobian_feature.npz: the clone covariance blocks and measurement
    blocks recorded at 33.9 s of a 120 s stereo run of rosario-like-01, seed 4) whose point lies nearly in one
    clone's image plane: Jacobian ≈ 6e7 and residuals of thousands of normalised units there. The Schur-complement
    form rᵀS⁻¹r − bᵀC⁻¹b that the gate used gave γ = −9.7e9 with the stereo gate's pixel σ (catastrophic
    cancellation), so the gate accepted it and the update moved the velocity by 5 m/s; the run diverged 10 s later.
    γ must be large (rejected), never negative."""
    from pathlib import Path

    from scipy.stats import chi2

    z = np.load(Path(__file__).parent / "data" / "gate_huge_jacobian_feature.npz")
    batch = FeatureBatch(np.array([[0, 1]]), z["Hx"], z["Hf"], z["r"], z["rows"])
    P, sigma = z["P"], float(z["sigma"])
    threshold = chi2.ppf(0.95, int(batch.rows.sum()) - 3)
    for pixel_sigma in (None, 0.0005):
        assert gating_chi2(P, batch, sigma, pixel_sigma)[0] > 1e3 * threshold
    # the former formula, kept here as the reference of the failure
    k, n, R, _ = batch.Hx.shape
    S = np.zeros((n * R, n * R))
    for i in range(n):
        for j in range(n):
            Pij = P[21 + 6 * i:27 + 6 * i, 21 + 6 * j:27 + 6 * j]
            S[i * R:(i + 1) * R, j * R:(j + 1) * R] = batch.Hx[0, i] @ Pij @ batch.Hx[0, j].T
    S += np.diag(np.tile([0.0005 ** 2] * 4 + [sigma ** 2] * (R - 4), n))
    r, Hf = batch.r.reshape(-1), batch.Hf.reshape(-1, 3)
    Xr, Xf = np.linalg.solve(S, r), np.linalg.solve(S, Hf)
    b_ = Hf.T @ Xr
    assert r @ Xr - b_ @ np.linalg.solve(Hf.T @ Xf, b_) < 0


def test_gate_depth_scale_tolerates_one_scale_error_shared_by_a_features_depths():
    """A filter's live features with every depth reading scaled by 1.15 (what the gate sees when the filter's own
    scale is 15 % off): with a tight pixel σ in the gate and a 1 % depth σ, ≈ 9 % of them fail (8.6 % since the
    features are triangulated again before each update, stop 47: five times the unbiased rate); with
    ``gate_depth_scale`` 0.1 (one relative error shared by a feature's readings, gate only) ≤ 2 % do, as with
    unbiased depths; the update's blocks are the same with and without the option."""
    import copy
    from dataclasses import replace

    from msckf.update import chi2_threshold, gating_chi2

    w = make_world(seed=3, duration=3.0, max_features=300, depth_mode=True, depth_rel_sigma=0.01)
    sig = _WORLD_NOISE["feature_noise"]
    cfg = load_config(dict(_WORLD_NOISE, depth_rel_sigma=0.01, depth_inv_sigma=1e-3))
    flt = MsckfFilter(cfg, w.T_cam0_imu, w.T_cam1_cam0)
    flt.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    for _ in iterate(w, flt, stop_after=60):
        pass
    rows, order, _ = _triangulated_live_rows(flt)
    fs = flt.features
    assert len(rows) > 100
    mask = fs.has[rows][:, order]
    spec = flt._measurement_spec()
    rejected, blocks = {}, {}
    for factor in (1.0, 1.15):
        g = copy.deepcopy(flt)
        g.features.depth[rows] *= factor
        for s in (0.0, 0.1):
            g.config = replace(g.config, update=replace(g.config.update, gate_depth_scale=s))
            b, b_gate = g._batches(rows, mask, spec)
            assert (b_gate is b) == (s == 0.0)
            gamma = gating_chi2(g.P, b_gate, sig, sig)
            rejected[factor, s] = float(np.mean(gamma >= chi2_threshold(0.95, b_gate.n_rows - 3)))
            blocks[factor, s] = b
    assert rejected[1.15, 0.0] >= max(0.07, 4 * rejected[1.0, 0.0]), rejected
    assert rejected[1.15, 0.1] <= 0.02 and rejected[1.0, 0.1] <= 0.02, rejected
    for factor in (1.0, 1.15):
        assert np.array_equal(blocks[factor, 0.0].r, blocks[factor, 0.1].r)
        assert np.array_equal(blocks[factor, 0.0].Hx, blocks[factor, 0.1].Hx)


def test_depth_sigma_at_prediction_makes_a_relative_sigma_independent_of_the_reading():
    """A σ_Z stated relative to the measured Z: at the measured depth (default) σ_ρ = rel / Z_meas depends on the
    reading's own error; at the predicted depth it is rel / Z_pred for every reading. The configured model's
    absolute inverse-depth part is not rescaled."""
    from msckf.update import inverse_depth_sigma

    z_true, rel = 5.0, 0.1
    z_meas = z_true * np.array([0.9, 1.0, 1.1])
    stated = rel * z_meas
    at_meas = inverse_depth_sigma(z_meas, stated, 0.01, 0.05)
    np.testing.assert_allclose(at_meas, rel / z_meas)
    at_pred = inverse_depth_sigma(z_meas, stated, 0.01, 0.05, z_pred=np.full(3, z_true))
    np.testing.assert_allclose(at_pred, np.full(3, rel / z_true))
    model = inverse_depth_sigma(z_meas, None, 0.02, 0.0, z_pred=np.full(3, z_true))
    np.testing.assert_allclose(model, 0.02)
    # and the option reaches the update's blocks: the whitened depth row differs only with it on
    spec = MeasurementSpec(_T10[:3, :3], _T10[:3, 3], G_W, 0.01, oc=False, depth_row=True)
    on = MeasurementSpec(_T10[:3, :3], _T10[:3, 3], G_W, 0.01, oc=False, depth_row=True,
                         depth_sigma_at_prediction=True)
    rng = np.random.default_rng(0)
    R_w_c, p_c, p_f, obs, depth = _single_feature(rng, 3)
    depth = depth * 1.05
    args = (p_f, R_w_c, p_c, np.swapaxes(R_w_c, -1, -2), p_c, obs, depth, np.ones((1, 3), bool),
            np.ones((1, 3), bool), np.arange(3)[None], 3)
    b0 = measurement_blocks(spec, *args, depth_sigma=0.1 * depth)
    b1 = measurement_blocks(on, *args, depth_sigma=0.1 * depth)
    assert np.array_equal(b0.r[..., :4], b1.r[..., :4]) and not np.allclose(b0.r[..., 4], b1.r[..., 4])


def _explicit_feature_rows(b, f, n_clones, cov_extra):
    """Feature f's valid rows laid out on the full clone state: (H (m, 6C), H_f (m, 3), r (m,), C (m, m)), C the
    rows' covariance in units of σ² (I + ``cov_extra(f, i, j, i2, j2)``)."""
    k, n, R = b.r.shape
    idx = [(i, j) for i in range(n) for j in range(R) if b.rows[f, i, j]]
    H = np.zeros((len(idx), 6 * n_clones))
    Hf = np.zeros((len(idx), 3))
    r = np.zeros(len(idx))
    C = np.eye(len(idx))
    for a, (i, j) in enumerate(idx):
        H[a, 6 * b.pos[f, i]:6 * b.pos[f, i] + 6] = b.Hx[f, i, j]
        Hf[a], r[a] = b.Hf[f, i, j], b.r[f, i, j]
        for c, (i2, j2) in enumerate(idx):
            C[a, c] += cov_extra(f, i, j, i2, j2)
    return H, Hf, r, C


def test_whitening_across_clones_keeps_each_jacobian_on_its_own_clone():
    """Whitening a feature's depth rows for a shared error combines rows of *different* clones. The update's
    information and the gate's χ² must then equal the explicit forms with each row's Jacobian on its own clone's
    columns and the rows' full covariance — until stop 40 the combined Jacobian was stored on each observation's
    own clone (information off by 2.5 on a scale of 20 here; on a consistent simulated world a 0.5 % shared term
    on 0.2 % depths raised the ANEES of position from 5.2 to 14.5)."""
    from msckf.update import FeatureBatch, null_space_project, schur_information, whiten_depth_shared

    rng = np.random.default_rng(0)
    k, n, R, C = 3, 4, 5, 5
    rows = np.ones((k, n, R), bool)
    rows[:, :, 2:4] = False
    rows[2, 3] = False
    pos = np.tile(np.arange(n), (k, 1))
    pos[2, 3] = C                                                    # padding
    b = FeatureBatch(pos, rng.normal(size=(k, n, R, 6)) * rows[..., None],
                     rng.normal(size=(k, n, R, 3)) * rows[..., None], rng.normal(size=(k, n, R)) * rows, rows)
    A = rng.uniform(0.5, 3.0, size=(k, n))
    w = whiten_depth_shared(b, A)

    def extra(f, i, j, i2, j2):
        return A[f, i] * A[f, i2] if j == 4 and j2 == 4 else 0.0

    Lam = np.zeros((6 * C, 6 * C))
    P = np.eye(21 + 6 * C) * 1e-3 + 1e-4
    sigma = 0.3
    gammas = []
    for f in range(k):
        H, Hf, r, Cov = _explicit_feature_rows(b, f, C, extra)
        Ci = np.linalg.inv(Cov)
        Ixf = H.T @ Ci @ Hf
        Lam += H.T @ Ci @ H - Ixf @ np.linalg.solve(Hf.T @ Ci @ Hf, Ixf.T)
        Hs = np.zeros((len(r), 21 + 6 * C))
        Hs[:, 21:] = H
        S = Hs @ P @ Hs.T + sigma ** 2 * Cov
        Si = np.linalg.inv(S)
        gammas.append(r @ Si @ r - (Hf.T @ Si @ r) @ np.linalg.solve(Hf.T @ Si @ Hf, Hf.T @ Si @ r))
    H_o, _ = null_space_project(w, C)
    np.testing.assert_allclose(H_o.T @ H_o, Lam, atol=1e-10 * np.abs(Lam).max())
    np.testing.assert_allclose(schur_information(w, C)[0], Lam, atol=1e-10 * np.abs(Lam).max())
    np.testing.assert_allclose(gating_chi2(P, w, sigma), gammas, rtol=1e-8)
    # the drift model combines the pixel rows of different clones the same way
    from msckf.update import whiten_track_drift
    t = np.tile(np.arange(n) / 15.0, (k, 1))
    valid = pos < C
    q, sig = 2e-6, 3e-4
    d = whiten_track_drift(b, t, valid, sig, q)

    def drift(f, i, j, i2, j2):
        same_axis = j < 4 and j2 < 4 and j % 2 == j2 % 2
        return q * min(t[f, i], t[f, i2]) / sig ** 2 if same_axis else 0.0

    Lam_d = np.zeros((6 * C, 6 * C))
    for f in range(k):
        H, Hf, r, Cov = _explicit_feature_rows(b, f, C, drift)
        Ci = np.linalg.inv(Cov)
        Ixf = H.T @ Ci @ Hf
        Lam_d += H.T @ Ci @ H - Ixf @ np.linalg.solve(Hf.T @ Ci @ Hf, Ixf.T)
    H_o, _ = null_space_project(d, C)
    np.testing.assert_allclose(H_o.T @ H_o, Lam_d, atol=1e-10 * np.abs(Lam_d).max())
