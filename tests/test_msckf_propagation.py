"""IMU propagation of the MSCKF: nominal state against gtsam preintegration, Φ against a numerical Jacobian,
OC-EKF constraints, process noise."""

import gtsam
import numpy as np
import pytest

from msckf.propagation import (
    ImuNoise,
    error_jacobian_F,
    oc_modify_transition,
    process_noise,
    propagate_samples,
    rk4_nominal,
    transition_matrix,
)
from msckf.rotation import so3_exp, so3_log
from msckf.state import ImuState

G = 9.81
G_W = np.array([0.0, 0.0, -G])


def _imu_stream(n=225, rate=150.0):
    """1.5 s of smoothly varying readings (rad/s, m/s²) with a tilted start."""
    dt = 1.0 / rate
    t = np.arange(1, n + 1) * dt
    R0 = so3_exp(np.array([0.1, -0.2, 0.3]))
    gyro = np.stack([0.3 * np.sin(2 * t), 0.2 * np.cos(3 * t), 0.5 + 0.1 * np.sin(t)], axis=1)
    acc = np.stack([0.5 * np.cos(2 * t), 0.3 * np.sin(t), np.zeros(n)], axis=1) + R0.T @ np.array([0.0, 0.0, G])
    return t, dt, R0, gyro, acc


def _gtsam_predict(R0, p0, v0, bg, ba, gyro, acc, dt, substeps):
    params = gtsam.PreintegrationParams.MakeSharedU(G)
    params.setAccelerometerCovariance(np.eye(3) * 1e-4)
    params.setGyroscopeCovariance(np.eye(3) * 1e-6)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    bias = gtsam.imuBias.ConstantBias(ba, bg)           # accelerometer bias first
    pim = gtsam.PreintegratedImuMeasurements(params, bias)
    h = dt / substeps
    for a, w in zip(acc, gyro):
        for _ in range(substeps):
            pim.integrateMeasurement(a, w, h)
    s = pim.predict(gtsam.NavState(gtsam.Rot3(R0), p0, v0), bias)
    return s.attitude().matrix(), np.asarray(s.position()), np.asarray(s.velocity())


def test_nominal_propagation_matches_gtsam_preintegration():
    t, dt, R0, gyro, acc = _imu_stream()
    bg, ba = np.array([0.01, -0.02, 0.005]), np.array([0.05, -0.03, 0.02])
    p0, v0 = np.array([1.0, 2.0, 3.0]), np.array([0.5, -0.2, 0.1])
    st = ImuState(0.0, R0.copy(), p0.copy(), v0.copy(), bg.copy(), ba.copy(), np.eye(3), np.zeros(3))
    propagate_samples(st, np.zeros((21, 21)), t, gyro, acc, ImuNoise(1e-3, 1e-4, 1e-2, 1e-3), G_W, oc=False)

    # Same stream, same pairing (each sample held over the interval ending at it). gtsam integrates each step
    # with the rotation at its start (first order in dt), our RK4 is 4th order: close, not equal.
    R1, p1, v1 = _gtsam_predict(R0, p0, v0, bg, ba, gyro, acc, dt, 1)
    assert np.linalg.norm(so3_log(R1.T @ st.R_w_i)) < 1e-4
    assert np.abs(p1 - st.p).max() < 5e-3
    assert np.abs(v1 - st.v).max() < 1e-2

    # Sub-stepping gtsam converges to the exact solution of the held-sample ODE as 1/N; Richardson
    # extrapolation of N and 2N removes the first-order term. The filter must agree with that limit tightly.
    N = 25
    Ra, pa, va = _gtsam_predict(R0, p0, v0, bg, ba, gyro, acc, dt, N)
    Rb, pb, vb = _gtsam_predict(R0, p0, v0, bg, ba, gyro, acc, dt, 2 * N)
    e_rot = 2 * so3_log(Rb.T @ st.R_w_i) - so3_log(Ra.T @ st.R_w_i)
    e_pos = 2 * (pb - st.p) - (pa - st.p)
    e_vel = 2 * (vb - st.v) - (va - st.v)
    assert np.abs(e_rot).max() < 1e-9
    assert np.abs(e_pos).max() < 1e-7
    assert np.abs(e_vel).max() < 1e-7


def _perturb(x, d):
    R, bg, v, ba, p = x
    return (R @ so3_exp(d[0:3]), bg + d[3:6], v + d[6:9], ba + d[9:12], p + d[12:15])


def _err(a, b):
    return np.concatenate([so3_log(b[0].T @ a[0]), a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4]])


@pytest.mark.parametrize("seed", [1, 2])
def test_transition_matrix_matches_numerical_jacobian(seed):
    rng = np.random.default_rng(seed)
    R = so3_exp(rng.normal(size=3))
    x = (R, rng.normal(size=3) * 0.01, rng.normal(size=3), rng.normal(size=3) * 0.1, rng.normal(size=3))
    gyro = rng.normal(size=3) * 0.5
    acc = R.T @ -G_W + rng.normal(size=3)

    def step(x, dt):
        Rn, vn, pn = rk4_nominal(x[0], x[2], x[4], gyro - x[1], acc - x[3], dt, G_W)
        return (Rn, x[1], vn, x[3], pn)

    errs = []
    for dt in (0.01, 0.005):
        x1 = step(x, dt)
        J = np.zeros((15, 15))
        for j in range(15):
            d = np.zeros(15)
            d[j] = 1e-6
            J[:, j] = (_err(step(_perturb(x, d), dt), x1) - _err(step(_perturb(x, -d), dt), x1)) / 2e-6
        Phi = transition_matrix(error_jacobian_F(x[0], gyro - x[1], acc - x[3]), dt)
        assert np.allclose(Phi[15:, :], np.eye(21)[15:, :])          # extrinsics are constant
        errs.append(np.abs(Phi[:15, :15] - J).max())
    # Φ linearises F at the start of the step: it matches the exact one-step Jacobian up to O(dt²).
    assert errs[1] < 5e-5
    assert errs[0] / errs[1] > 3.0                                       # second-order convergence


def test_oc_transition_keeps_the_gravity_direction_unobservable():
    rng = np.random.default_rng(3)
    R_null = so3_exp(rng.normal(size=3))
    gyro, acc, dt = rng.normal(size=3) * 0.3, R_null.T @ -G_W + rng.normal(size=3), 0.007
    v_null, p_null = rng.normal(size=3), rng.normal(size=3)
    R_new, v_new, p_new = rk4_nominal(R_null, v_null, p_null, gyro, acc, dt, G_W)
    Phi = transition_matrix(error_jacobian_F(R_null, gyro, acc), dt)
    Phi_oc = oc_modify_transition(Phi, R_new, R_null, v_new, v_null, p_new, p_null, G_W, dt)
    u = R_null.T @ G_W
    assert np.allclose(Phi_oc[0:3, 0:3], R_new.T @ R_null, atol=1e-14)
    assert np.allclose(Phi_oc[0:3, 0:3] @ u, R_new.T @ G_W, atol=1e-12)
    assert np.allclose(Phi_oc[6:9, 0:3] @ u, np.cross(v_null - v_new, G_W), atol=1e-12)
    assert np.allclose(Phi_oc[12:15, 0:3] @ u, np.cross(dt * v_null + p_null - p_new, G_W), atol=1e-12)
    # Only the modified blocks change, and only slightly (the modification is a small correction).
    mask = np.ones_like(Phi, dtype=bool)
    mask[0:3, 0:3] = mask[6:9, 0:3] = mask[12:15, 0:3] = False
    assert np.array_equal(Phi_oc[mask], Phi[mask])
    assert np.abs(Phi_oc - Phi).max() < 0.05


def test_process_noise_is_symmetric_psd_and_matches_definition():
    rng = np.random.default_rng(4)
    R = so3_exp(rng.normal(size=3))
    Phi = transition_matrix(error_jacobian_F(R, rng.normal(size=3), rng.normal(size=3)), 0.01)
    noise = ImuNoise(gyro_noise=0.005, gyro_bias_noise=0.001, acc_noise=0.05, acc_bias_noise=0.01)
    Q = process_noise(Phi, noise.diag12(), 0.01)
    G = np.zeros((21, 12))
    G[0:3, 0:3], G[3:6, 3:6], G[6:9, 6:9], G[9:12, 9:12] = -np.eye(3), np.eye(3), -R, np.eye(3)
    Q_def = Phi @ G @ np.diag(noise.diag12()) @ G.T @ Phi.T * 0.01        # S-MSCKF's formula
    assert np.allclose(Q, Q_def, atol=1e-18)
    assert np.allclose(Q, Q.T)
    assert np.linalg.eigvalsh(Q).min() > -1e-15


def _reference_propagation(st, P, times, gyro, acc, noise, oc):
    """msckf_vio ``processModel`` sample by sample, built from the single-step functions."""
    P_II, Phi_total = P[:21, :21].copy(), np.eye(21)
    for k in range(len(times)):
        dt, w, a = times[k] - st.time, gyro[k] - st.b_g, acc[k] - st.b_a
        Phi = transition_matrix(error_jacobian_F(st.R_w_i, w, a), dt)
        Rn, vn, pn = rk4_nominal(st.R_w_i, st.v, st.p, w, a, dt, G_W)
        if oc:
            Phi = oc_modify_transition(Phi, Rn, st.R_w_i_null, vn, st.v_null, pn, st.p_null, G_W, dt)
        P_II = Phi @ P_II @ Phi.T + process_noise(Phi, noise.diag12(), dt)
        Phi_total = Phi @ Phi_total
        st.R_w_i, st.v, st.p, st.time = Rn, vn, pn, times[k]
        st.R_w_i_null, st.v_null, st.p_null = Rn.copy(), vn.copy(), pn.copy()
    out = P.copy()
    out[:21, :21] = P_II
    out[:21, 21:] = Phi_total @ P[:21, 21:]
    out[21:, :21] = out[:21, 21:].T
    return out


@pytest.mark.parametrize("oc", [True, False])
def test_batched_propagation_equals_sample_by_sample_reference(oc):
    """The stacked implementation equals msckf_vio's per-sample recursion, cross terms (P_IC) included; the
    first sample uses the OC null copies kept from before the last update."""
    t, dt, R0, gyro, acc = _imu_stream(n=12)
    rng = np.random.default_rng(5)
    A = rng.normal(size=(33, 33))
    P = A @ A.T

    def fresh():
        return ImuState(0.0, R0.copy(), np.ones(3), np.array([0.5, 0.0, 0.0]), np.array([0.01, 0.0, 0.0]),
                        np.zeros(3), np.eye(3), np.zeros(3), R_w_i_null=R0 @ so3_exp(np.array([0.01, 0, 0])),
                        p_null=np.ones(3) * 1.01, v_null=np.array([0.52, 0.0, 0.0]))

    noise = ImuNoise(0.005, 0.001, 0.05, 0.01)
    st, st_ref = fresh(), fresh()
    P_batch = propagate_samples(st, P, t, gyro, acc, noise, G_W, oc=oc)
    P_ref = _reference_propagation(st_ref, P, t, gyro, acc, noise, oc)
    assert np.allclose(P_batch, P_ref, rtol=1e-12, atol=1e-12 * np.abs(P_ref).max())
    assert np.allclose(st.R_w_i, st_ref.R_w_i, atol=1e-14) and np.allclose(st.p, st_ref.p, atol=1e-14)
    assert np.array_equal(P_batch[21:, 21:], P[21:, 21:])
