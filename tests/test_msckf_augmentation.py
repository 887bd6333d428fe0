"""State augmentation: the clone Jacobian against a numerical one, and the grown covariance."""

import numpy as np

from msckf.augmentation import augment, augmentation_jacobian, clone_pose
from msckf.rotation import so3_exp, so3_log
from msckf.state import CloneStore, ImuState


def _state(rng):
    return ImuState(0.0, so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3),
                    rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.1, so3_exp(rng.normal(size=3)),
                    rng.normal(size=3) * 0.1)


def _perturbed(s: ImuState, d: np.ndarray) -> ImuState:
    """Apply a 21-d error with the library's convention (rotation errors local; R_c_i = Exp(−δθ_e) R̂_c_i)."""
    return ImuState(0.0, s.R_w_i @ so3_exp(d[0:3]), s.p + d[12:15], s.v + d[6:9], s.b_g + d[3:6], s.b_a + d[9:12],
                    so3_exp(-d[15:18]) @ s.R_c_i, s.p_i_c + d[18:21])


def test_augmentation_jacobian_matches_numerical_jacobian():
    rng = np.random.default_rng(0)
    s = _state(rng)
    R0, p0 = clone_pose(s)
    J_num = np.zeros((6, 21))
    for j in range(21):
        d = np.zeros(21)
        d[j] = 1e-6
        Rp, pp = clone_pose(_perturbed(s, d))
        Rm, pm = clone_pose(_perturbed(s, -d))
        # clone error: R_w_c = R̂_w_c Exp(δθ_c), p_c = p̂_c + δp_c
        J_num[:3, j] = (so3_log(R0.T @ Rp) - so3_log(R0.T @ Rm)) / 2e-6
        J_num[3:, j] = (pp - pm) / 2e-6
    J = augmentation_jacobian(s)
    assert np.allclose(J, J_num, atol=1e-8)
    # the upstream fix (PR #116): the translation-extrinsic block is the rotation, not the identity
    assert np.allclose(J[3:6, 18:21], s.R_w_i)


def test_augment_grows_covariance_consistently():
    rng = np.random.default_rng(1)
    s = _state(rng)
    A = rng.normal(size=(27, 27))
    P = A @ A.T                                   # 21 + one existing clone
    clones = CloneStore(4)
    clones.add(0, 0.0, np.eye(3), np.zeros(3))
    P2 = augment(s, P, clones)
    J = augmentation_jacobian(s)
    T = np.zeros((33, 27))
    T[:27, :27] = np.eye(27)
    T[27:, :21] = J
    assert P2.shape == (33, 33)
    assert np.allclose(P2, T @ P @ T.T, rtol=1e-12, atol=1e-12)
    assert len(clones) == 2
    R, p = clone_pose(s)
    slot = clones.order[-1]
    assert np.allclose(clones.R_w_c[slot], R) and np.allclose(clones.p[slot], p)
    assert np.allclose(clones.R_c_w_null[slot], R.T) and np.allclose(clones.p_null[slot], p)
