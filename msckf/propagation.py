"""IMU propagation: RK4 nominal state, Φ and Q of the 21-d error state, OC-EKF modifications.

S-MSCKF's process model (msckf.md §1.3–1.4), in the conventions of :mod:`msckf.rotation`:

* Each IMU sample is held constant over the interval that *ends* at its stamp (msckf_vio ``processModel``).
* Nominal state: rotation by the closed-form ``Exp(ω dt)``; velocity/position by RK4 with
  ``v̇ = R_w_i(t) a + g``, ``ṗ = v`` and the rotation evaluated at t, t + dt/2, t + dt.
* Continuous error model: ``F[θ,θ] = −[ω]×``, ``F[θ,b_g] = −I``, ``F[v,θ] = −R_w_i [a]×``,
  ``F[v,b_a] = −R_w_i``, ``F[p,v] = I``; noise ``[n_g, n_wg, n_a, n_wa]`` enters through
  ``G = diag-blocks(−I, I, −R_w_i, I)``.
* ``Φ = I + FΔt + (FΔt)²/2 + (FΔt)³/6``; ``Q = Φ G Q_c Gᵀ Φᵀ Δt`` (Q_c = diag(σ_g², σ_bg², σ_a², σ_ba²)).
* OC-EKF (Hesch et al., as msckf_vio): ``Φ[θ,θ] = R̂_i_w(k+1) R̂_w_i,null``; ``Φ[v,θ]`` and ``Φ[p,θ]`` are
  projected so that the unobservable gravity-yaw direction stays unobservable.
"""

from __future__ import annotations

import numpy as np

from msckf.options import ImuNoise
from msckf.rotation import orthonormalize, skew, so3_exp3
from msckf.state import IMU_DIM, ImuState

__all__ = ["ImuNoise", "rk4_nominal", "error_jacobian_F", "transition_matrix", "process_noise",
           "oc_modify_transition", "propagate_samples"]


def rk4_nominal(R_w_i: np.ndarray, v: np.ndarray, p: np.ndarray, gyro: np.ndarray, acc: np.ndarray,
                dt: float, g_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One RK4 step of the nominal IMU kinematics with bias-corrected readings held constant over dt.

    Args:
        R_w_i: (3, 3) IMU → world at the start. v, p: (3,) world velocity (m/s) and position (m).
        gyro: (3,) bias-corrected angular rate, IMU frame, rad/s. acc: (3,) bias-corrected specific force,
            IMU frame, m/s². dt: seconds. g_w: (3,) gravity in world, m/s² (``(0, 0, −|g|)``).
    Returns:
        (R_w_i, v, p) at t + dt.
    """
    R_half = R_w_i @ so3_exp3(gyro * (0.5 * dt))
    R_end = R_w_i @ so3_exp3(gyro * dt)
    k1v = R_w_i @ acc + g_w
    k2v = R_half @ acc + g_w
    k3v = k2v  # the rotation at t + dt/2 is the same for k2 and k3 (a does not depend on v or p)
    k4v = R_end @ acc + g_w
    k1p = v
    k2p = v + k1v * (0.5 * dt)
    k3p = v + k2v * (0.5 * dt)
    k4p = v + k3v * dt
    v_new = v + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    p_new = p + dt / 6.0 * (k1p + 2.0 * k2p + 2.0 * k3p + k4p)
    return R_end, v_new, p_new


def error_jacobian_F(R_w_i: np.ndarray, gyro: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Continuous-time 21×21 error-state Jacobian F at the given (bias-corrected) readings."""
    F = np.zeros((IMU_DIM, IMU_DIM))
    F[0:3, 0:3] = -skew(gyro)
    F[0:3, 3:6] = -np.eye(3)
    F[6:9, 0:3] = -R_w_i @ skew(acc)
    F[6:9, 9:12] = -R_w_i
    F[12:15, 6:9] = np.eye(3)
    return F


def transition_matrix(F: np.ndarray, dt: float) -> np.ndarray:
    """Φ = I + FΔt + (FΔt)²/2 + (FΔt)³/6 (S-MSCKF's 3rd-order series), 21×21."""
    Fdt = F * dt
    Fdt2 = Fdt @ Fdt
    return np.eye(IMU_DIM) + Fdt + 0.5 * Fdt2 + (1.0 / 6.0) * (Fdt2 @ Fdt)


def process_noise(Phi: np.ndarray, noise_diag12: np.ndarray, dt: float) -> np.ndarray:
    """Q = Φ G Q_c Gᵀ Φᵀ Δt (21×21, symmetric).

    Because Q_c is isotropic per block and G's blocks are ±I or −R_w_i, G Q_c Gᵀ is the constant diagonal
    diag(σ_g² I, σ_bg² I, σ_a² I, σ_ba² I, 0) — so Q = Φ[:, :12] diag Φ[:, :12]ᵀ Δt exactly.
    """
    A = Phi[:, :12] * noise_diag12
    Q = (A @ Phi[:, :12].T) * dt
    return 0.5 * (Q + Q.T)


def oc_modify_transition(Phi: np.ndarray, R_w_i_new: np.ndarray, R_w_i_null: np.ndarray,
                         v_new: np.ndarray, v_null: np.ndarray, p_new: np.ndarray, p_null: np.ndarray,
                         g_w: np.ndarray, dt: float) -> np.ndarray:
    """Observability-constrained Φ (msckf_vio ``processModel``), returned as a modified copy.

    ``Φ[θ,θ] = R_i_w,new R_w_i,null``; with ``u = R_i_w,null g`` and ``s = uᵀ/(uᵀu)``:
    ``Φ[v,θ] ← A1 − (A1 u − w1) s`` with ``w1 = [v_null − v_new]× g`` and
    ``Φ[p,θ] ← A2 − (A2 u − w2) s`` with ``w2 = [Δt v_null + p_null − p_new]× g``.
    """
    Phi = Phi.copy()
    Phi[0:3, 0:3] = R_w_i_new.T @ R_w_i_null
    u = R_w_i_null.T @ g_w
    s = u / (u @ u)
    A1 = Phi[6:9, 0:3]
    w1 = skew(v_null - v_new) @ g_w
    Phi[6:9, 0:3] = A1 - np.outer(A1 @ u - w1, s)
    A2 = Phi[12:15, 0:3]
    w2 = skew(dt * v_null + p_null - p_new) @ g_w
    Phi[12:15, 0:3] = A2 - np.outer(A2 @ u - w2, s)
    return Phi


def propagate_samples(state: ImuState, P: np.ndarray, times: np.ndarray, gyros: np.ndarray, accs: np.ndarray,
                      noise: ImuNoise, g_w: np.ndarray, oc: bool) -> np.ndarray:
    """Propagate the state and covariance through IMU samples (each held over the interval ending at it).

    The nominal state is integrated sample by sample (:func:`rk4_nominal`); the K transition matrices, OC
    modifications and noise matrices are then formed together (stacked 21×21 arrays), and only the covariance
    recursion ``P_II ← Φ P_II Φᵀ + Q`` runs per sample. ``P_IC`` is multiplied once by ``Φ_K ⋯ Φ_1``.
    Identical to applying :func:`error_jacobian_F`, :func:`transition_matrix`, :func:`oc_modify_transition` and
    :func:`process_noise` sample by sample (msckf_vio ``processModel``).

    Args:
        state: modified in place (nominal values, ``time``, OC null copies).
        P: (21 + 6N)² covariance; a new array is returned.
        times: (K,) sample stamps in seconds, increasing; samples not after ``state.time`` are skipped.
        gyros, accs: (K, 3) raw readings (rad/s, m/s²), IMU frame; biases are subtracted here.
        noise: IMU noise σ's. g_w: (3,) world gravity. oc: apply the OC-EKF modifications.
    Returns:
        The propagated covariance (symmetrised).
    """
    times = np.asarray(times, dtype=np.float64)
    keep = times > state.time
    times, gyros, accs = times[keep], np.asarray(gyros)[keep], np.asarray(accs)[keep]
    K = len(times)
    if K == 0:
        return P
    dts = np.diff(np.concatenate([[state.time], times]))
    w = gyros - state.b_g
    a = accs - state.b_a
    # nominal states: index 0 = start, k = after sample k
    Rs = np.empty((K + 1, 3, 3))
    vs = np.empty((K + 1, 3))
    ps = np.empty((K + 1, 3))
    Rs[0], vs[0], ps[0] = state.R_w_i, state.v, state.p
    for k in range(K):
        Rs[k + 1], vs[k + 1], ps[k + 1] = rk4_nominal(Rs[k], vs[k], ps[k], w[k], a[k], float(dts[k]), g_w)
    R0 = Rs[:-1]                                                          # start-of-step rotations
    # stacked F·dt
    Fdt = np.zeros((K, IMU_DIM, IMU_DIM))
    dt3 = dts[:, None, None]
    Fdt[:, 0:3, 0:3] = -skew(w) * dt3
    Fdt[:, 0:3, 3:6] = -np.eye(3) * dt3
    Fdt[:, 6:9, 0:3] = -(R0 @ skew(a)) * dt3
    Fdt[:, 6:9, 9:12] = -R0 * dt3
    Fdt[:, 12:15, 6:9] = np.eye(3) * dt3
    Fdt2 = Fdt @ Fdt
    Phi = np.eye(IMU_DIM) + Fdt + 0.5 * Fdt2 + (1.0 / 6.0) * (Fdt2 @ Fdt)
    if oc:
        # first estimates: the values at the end of the previous propagation step (for the first sample, the
        # null copies kept from the last call, i.e. before the EKF update)
        Rn = np.concatenate([state.R_w_i_null[None], Rs[1:-1]])
        vn = np.concatenate([state.v_null[None], vs[1:-1]])
        pn = np.concatenate([state.p_null[None], ps[1:-1]])
        R1, v1, p1 = Rs[1:], vs[1:], ps[1:]
        Phi[:, 0:3, 0:3] = np.swapaxes(R1, 1, 2) @ Rn
        u = np.swapaxes(Rn, 1, 2) @ g_w                                   # (K, 3)
        s = u / np.sum(u * u, axis=1, keepdims=True)
        w1 = skew(vn - v1) @ g_w
        w2 = skew(dts[:, None] * vn + pn - p1) @ g_w
        A1 = Phi[:, 6:9, 0:3]
        Phi[:, 6:9, 0:3] = A1 - ((A1 @ u[..., None])[..., 0] - w1)[:, :, None] * s[:, None, :]
        A2 = Phi[:, 12:15, 0:3]
        Phi[:, 12:15, 0:3] = A2 - ((A2 @ u[..., None])[..., 0] - w2)[:, :, None] * s[:, None, :]
    B = Phi[:, :, :12]
    Q = (B * noise.diag12()) @ np.swapaxes(B, 1, 2) * dt3
    Q = 0.5 * (Q + np.swapaxes(Q, 1, 2))
    P_II = P[:IMU_DIM, :IMU_DIM]
    Phi_total = Phi[0]
    P_II = Phi[0] @ P_II @ Phi[0].T + Q[0]
    for k in range(1, K):
        P_II = Phi[k] @ P_II @ Phi[k].T + Q[k]
        Phi_total = Phi[k] @ Phi_total
    state.R_w_i = orthonormalize(Rs[-1])     # products of exact rotations drift only ~1e-16 per step
    state.v, state.p = vs[-1].copy(), ps[-1].copy()
    state.R_w_i_null, state.v_null, state.p_null = state.R_w_i.copy(), state.v.copy(), state.p.copy()
    state.time = float(times[-1])
    out = P.copy()
    out[:IMU_DIM, :IMU_DIM] = 0.5 * (P_II + P_II.T)
    if P.shape[0] > IMU_DIM:
        out[:IMU_DIM, IMU_DIM:] = Phi_total @ P[:IMU_DIM, IMU_DIM:]
        out[IMU_DIM:, :IMU_DIM] = out[:IMU_DIM, IMU_DIM:].T
    return out
