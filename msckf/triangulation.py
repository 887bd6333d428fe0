"""Batched inverse-depth Levenberg–Marquardt triangulation (S-MSCKF ``Feature::initializePosition``).

A feature is parameterised in its *anchor* camera (the cam0 of its first observation) by the inverse depth
``x = (α, β, ρ) = (X/Z, Y/Z, 1/Z)``. A view with pose ``(R, t)`` mapping anchor-cam0 points into that view's
camera frame predicts ``h = R (α, β, 1)ᵀ + ρ t`` and the normalised observation ``(h1/h3, h2/h3)``; every
cam0 and cam1 observation of every clone is one view (msckf.md §1.6).

Robust cost: Huber on the per-view residual norm ``e``: ``e²`` for ``e ≤ ε`` and ``2εe − ε²`` beyond; the
IRLS weight is ``w² = ε / e`` beyond ε, the weight that matches this cost. (msckf_vio's fix of issue #85
uses ``w = sqrt(2ε/e)``, which jumps from 1 to √2 at e = ε and is paired with a non-robust squared cost
for step acceptance; here the same Huber cost is used for the weights and for accepting LM steps.)

All features are solved at once: per-feature damping λ, per-feature step acceptance, padded views with
a validity mask — no Python loop over features.

Depth measurements (optional, ``depth_inv`` / ``depth_weight``): a view with a measured depth adds the 1-D
residual ``w · (ρ / h3 − 1/d)`` — the predicted minus the measured inverse depth in that view, whitened to the
normalised-pixel unit by ``w = σ_pixel / σ_ρ`` — with its own Huber term. So a depth enters the triangulation
with the weight its σ gives it (instead of as a virtual right-camera pixel with a pixel's weight).
"""

from __future__ import annotations

import numpy as np

from msckf.options import TriangulationParams

__all__ = ["TriangulationParams", "views_from_clones", "initial_guess", "triangulate_batch"]


def views_from_clones(R_w_c: np.ndarray, p_c: np.ndarray, obs: np.ndarray, has: np.ndarray,
                      R_c1_c0: np.ndarray, t_c1_c0: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Turn per-clone observations into anchor-relative views.

    Args:
        R_w_c: (k, n, 3, 3) cam0 → world rotations of the clones (time order, padded).
        p_c: (k, n, 3) cam0 positions in world, m.
        obs: (k, n, 4) normalised (u0, v0, u1, v1); NaN cam1 for monocular observations.
        has: (k, n) bool, which padded clones hold an observation (at least one per feature).
        R_c1_c0, t_c1_c0: cam0 → cam1 rotation (3, 3) and translation (3,), m.
    Returns:
        R (k, 2n, 3, 3) and t (k, 2n, 3) mapping anchor-cam0 points into each view (cam0 of clone j at 2j,
        cam1 at 2j+1); z (k, 2n, 2); valid (k, 2n); anchor (k,) index of the anchor clone.
    """
    k, n = has.shape
    anchor = np.argmax(has, axis=1)
    ar = np.arange(k)
    R_w_a = R_w_c[ar, anchor]                                  # (k, 3, 3)
    p_a = p_c[ar, anchor]                                      # (k, 3)
    R_c_w = np.swapaxes(R_w_c, -1, -2)                         # (k, n, 3, 3)
    R0 = R_c_w @ R_w_a[:, None]                                # anchor cam0 -> clone cam0
    t0 = (R_c_w @ (p_a[:, None, :] - p_c)[..., None])[..., 0]
    R1 = R_c1_c0 @ R0
    t1 = t0 @ R_c1_c0.T + t_c1_c0
    R = np.stack([R0, R1], axis=2).reshape(k, 2 * n, 3, 3)
    t = np.stack([t0, t1], axis=2).reshape(k, 2 * n, 3)
    z = obs.reshape(k, n, 2, 2).reshape(k, 2 * n, 2)
    valid = np.stack([has, has & np.isfinite(obs[..., 2]) & np.isfinite(obs[..., 3])], axis=2).reshape(k, 2 * n)
    z = np.where(valid[..., None], z, 0.0)
    return R, t, z, valid, anchor


def initial_guess(R: np.ndarray, t: np.ndarray, z: np.ndarray, valid: np.ndarray, anchor_view: np.ndarray,
                  anchor_depth: np.ndarray | None, fallback_inverse_depth: float = 0.1) -> np.ndarray:
    """Initial (α, β, ρ): the measured anchor depth when given and finite, else the linear two-view depth
    (msckf_vio ``generateInitialGuess``) between the anchor and the valid view with the longest baseline.

    Args:
        R, t, z, valid: as returned by :func:`views_from_clones`. anchor_view: (k,) index of the anchor's cam0 view.
        anchor_depth: (k,) measured Z of the anchor observation in metres (NaN where none) or None.
    Returns:
        (k, 3) inverse-depth parameters.
    """
    k = len(z)
    ar = np.arange(k)
    z1 = z[ar, anchor_view]
    base = np.where(valid, np.linalg.norm(t, axis=-1), -1.0)
    j = np.argmax(base, axis=1)
    Rj, tj, z2 = R[ar, j], t[ar, j], z[ar, j]
    m = (Rj @ np.concatenate([z1, np.ones((k, 1))], axis=1)[..., None])[..., 0]
    A = np.stack([m[:, 0] - z2[:, 0] * m[:, 2], m[:, 1] - z2[:, 1] * m[:, 2]], axis=1)
    b = np.stack([z2[:, 0] * tj[:, 2] - tj[:, 0], z2[:, 1] * tj[:, 2] - tj[:, 1]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.sum(A * b, axis=1) / np.sum(A * A, axis=1)
        rho = 1.0 / depth
    rho = np.where(np.isfinite(rho) & (rho > 0) & (base[ar, j] > 0), rho, fallback_inverse_depth)
    if anchor_depth is not None:
        d = np.asarray(anchor_depth, dtype=np.float64)
        ok = np.isfinite(d) & (d > 0)
        rho = np.where(ok, 1.0 / np.where(ok, d, 1.0), rho)
    return np.concatenate([z1, rho[:, None]], axis=1)


def _residuals(x: np.ndarray, R: np.ndarray, t: np.ndarray, z: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """h (k, V, 3), residual z_hat − z (k, V, 2), W = [R[:, :2] | t] (k, V, 3, 3)."""
    W = np.concatenate([R[..., :2], t[..., None]], axis=-1)
    h = (W @ x[:, None, :, None])[..., 0] + R[..., 2]           # R (α, β, 1) + ρ t
    with np.errstate(divide="ignore", invalid="ignore"):
        r = h[..., :2] / h[..., 2:3] - z
    return h, r, W


def _huber_cost(r: np.ndarray, valid: np.ndarray, eps: float) -> np.ndarray:
    e = np.linalg.norm(r, axis=-1)
    c = np.where(e <= eps, e * e, 2.0 * eps * e - eps * eps)
    c = np.where(valid, c, 0.0)
    c = np.where(np.isfinite(c), c, np.inf)
    return c.sum(axis=1)


def _depth_residuals(x: np.ndarray, R: np.ndarray, t: np.ndarray, depth_inv: np.ndarray, weight: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Whitened inverse-depth residuals (k, V, 1) and their Jacobians (k, V, 1, 3) w.r.t. (α, β, ρ)."""
    h3 = R[..., 2, 0] * x[:, None, 0] + R[..., 2, 1] * x[:, None, 1] + R[..., 2, 2] + x[:, None, 2] * t[..., 2]
    rho = x[:, None, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = weight * (rho / h3 - depth_inv)
        inv_h3_2 = 1.0 / (h3 * h3)
        J = np.stack([-rho * R[..., 2, 0] * inv_h3_2, -rho * R[..., 2, 1] * inv_h3_2,
                      (h3 - rho * t[..., 2]) * inv_h3_2], axis=-1) * weight[..., None]
    return r[..., None], J[..., None, :]


def _total_cost(x: np.ndarray, R: np.ndarray, t: np.ndarray, z: np.ndarray, valid: np.ndarray, eps: float,
                depth_inv: np.ndarray | None, depth_weight: np.ndarray | None, dvalid: np.ndarray | None
                ) -> np.ndarray:
    _, r, _ = _residuals(x, R, t, z)
    cost = _huber_cost(r, valid, eps)
    if depth_inv is not None:
        rd, _ = _depth_residuals(x, R, t, depth_inv, depth_weight)
        cost = cost + _huber_cost(rd, dvalid, eps)
    return cost


def triangulate_batch(R: np.ndarray, t: np.ndarray, z: np.ndarray, valid: np.ndarray, x0: np.ndarray,
                      params: TriangulationParams = TriangulationParams(), depth_inv: np.ndarray | None = None,
                      depth_weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve all features' inverse-depth LM problems together.

    Args:
        R, t: (k, V, 3, 3), (k, V, 3) anchor-cam0 → view transforms. z: (k, V, 2) normalised observations.
        valid: (k, V) bool. x0: (k, 3) initial (α, β, ρ).
        params: LM settings.
        depth_inv: optional (k, V) measured inverse depth (1/m) of the point in each view's frame (NaN: none).
        depth_weight: (k, V) whitening ``σ_pixel / σ_ρ`` of each depth residual (see the module doc).
    Returns:
        p_anchor (k, 3): point in the anchor cam0 frame (m); ok (k,): finite, ρ > 0 and in front of every
        valid view (S-MSCKF's validity test); cost (k,): final Huber cost (normalised units²).
    """
    k = len(x0)
    eps = params.huber_epsilon
    x = np.array(x0, dtype=np.float64)
    dvalid = None
    if depth_inv is not None:
        depth_inv = np.asarray(depth_inv, dtype=np.float64)
        dvalid = np.isfinite(depth_inv) & np.isfinite(depth_weight) & (depth_weight > 0)
        depth_weight = np.where(dvalid, depth_weight, 0.0)
        depth_inv = np.where(dvalid, depth_inv, 0.0)
        if not dvalid.any():
            depth_inv = depth_weight = dvalid = None
    cost = _total_cost(x, R, t, z, valid, eps, depth_inv, depth_weight, dvalid)
    lam = np.full(k, params.initial_damping)
    active = np.isfinite(cost)
    outer = np.zeros(k, dtype=np.int64)
    inner = np.zeros(k, dtype=np.int64)
    A = np.zeros((k, 3, 3))
    b = np.zeros((k, 3))
    need = np.ones(k, dtype=bool)
    max_steps = params.outer_loop_max_iteration * (params.inner_loop_max_iteration + 1) + 1
    eye = np.eye(3)
    for _ in range(max_steps):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        upd = idx[need[idx]]
        if len(upd):
            h, rr, W = _residuals(x[upd], R[upd], t[upd], z[upd])
            inv_h3 = 1.0 / h[..., 2]
            J = (W[..., :2, :] - (h[..., :2, None] * inv_h3[..., None, None]) * W[..., 2:3, :]) \
                * inv_h3[..., None, None]                           # (u, V, 2, 3)
            e = np.linalg.norm(rr, axis=-1)
            w2 = np.where(e <= eps, 1.0, eps / np.maximum(e, 1e-300))
            w2 = np.where(valid[upd] & np.isfinite(e), w2, 0.0)
            rr = np.where(np.isfinite(rr), rr, 0.0)
            J = np.where(np.isfinite(J), J, 0.0)
            Jw = (J * w2[..., None, None]).reshape(len(upd), -1, 3)         # (u, 2V, 3)
            JwT = np.swapaxes(Jw, 1, 2)
            A[upd] = JwT @ J.reshape(len(upd), -1, 3)
            b[upd] = (JwT @ rr.reshape(len(upd), -1, 1))[..., 0]
            if depth_inv is not None:
                rd, Jd = _depth_residuals(x[upd], R[upd], t[upd], depth_inv[upd], depth_weight[upd])
                ed = np.abs(rd[..., 0])
                wd = np.where(ed <= eps, 1.0, eps / np.maximum(ed, 1e-300))
                wd = np.where(dvalid[upd] & np.isfinite(ed), wd, 0.0)
                rd = np.where(np.isfinite(rd), rd, 0.0)
                Jd = np.where(np.isfinite(Jd), Jd, 0.0).reshape(len(upd), -1, 3)
                JdwT = np.swapaxes(Jd * wd.reshape(len(upd), -1, 1), 1, 2)
                A[upd] += JdwT @ Jd
                b[upd] += (JdwT @ rd.reshape(len(upd), -1, 1))[..., 0]
            need[upd] = False
        Ad = A[idx] + lam[idx, None, None] * eye
        try:
            delta = np.linalg.solve(Ad, b[idx][..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = np.stack([np.linalg.lstsq(a, bb, rcond=None)[0] for a, bb in zip(Ad, b[idx])])
        x_new = x[idx] - delta
        if depth_inv is None:
            new_cost = _total_cost(x_new, R[idx], t[idx], z[idx], valid[idx], eps, None, None, None)
        else:
            new_cost = _total_cost(x_new, R[idx], t[idx], z[idx], valid[idx], eps, depth_inv[idx],
                                   depth_weight[idx], dvalid[idx])
        better = new_cost < cost[idx]
        acc = idx[better]
        rej = idx[~better]
        x[acc] = x_new[better]
        cost[acc] = new_cost[better]
        lam[acc] = np.maximum(lam[acc] / 10.0, 1e-10)
        outer[acc] += 1
        inner[acc] = 0
        need[acc] = True
        lam[rej] = np.minimum(lam[rej] * 10.0, 1e12)
        inner[rej] += 1
        exhausted = rej[inner[rej] > params.inner_loop_max_iteration]
        outer[exhausted] += 1
        inner[exhausted] = 0
        dn = np.linalg.norm(delta, axis=1)
        done = (dn <= params.estimation_precision) & (better | (inner[idx] == 0))
        active[idx[done]] = False
        active[outer > params.outer_loop_max_iteration] = False

    rho = x[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p_anchor = np.stack([x[:, 0] / rho, x[:, 1] / rho, 1.0 / rho], axis=1)
        h, _, _ = _residuals(x, R, t, z)
    in_front = np.all((h[..., 2] > 0) | ~valid, axis=1)
    ok = np.all(np.isfinite(x), axis=1) & (rho > 0) & in_front & np.all(np.isfinite(p_anchor), axis=1)
    return p_anchor, ok, cost
