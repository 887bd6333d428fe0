"""PLIP algebra: the identities the fusion layer relies on."""

import numpy as np
import pytest
import torch

from inpaint.plip import plip_add, plip_scalar_mul, plip_sub, plip_weighted_sum, plip_weighted_sum_iterated

GAMMA = 1026.0


@pytest.fixture
def vals():
    rng = np.random.default_rng(0)
    return rng.uniform(0, 1000, size=(3, 50))


def test_addition_is_associative_and_commutative(vals):
    a, b, c = vals
    np.testing.assert_allclose(plip_add(plip_add(a, b, GAMMA), c, GAMMA), plip_add(a, plip_add(b, c, GAMMA), GAMMA),
                               rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(plip_add(a, b, GAMMA), plip_add(b, a, GAMMA), rtol=1e-12)


def test_subtraction_inverts_addition(vals):
    a, b, _ = vals
    np.testing.assert_allclose(plip_sub(plip_add(a, b, GAMMA), b, GAMMA), a, rtol=1e-10, atol=1e-8)


def test_zero_is_neutral_and_scalar_one_is_identity(vals):
    a = vals[0]
    np.testing.assert_allclose(plip_add(a, 0.0, GAMMA), a)
    np.testing.assert_allclose(plip_scalar_mul(1.0, a, GAMMA), a, rtol=1e-12)
    # c ⊗ a = a ⊕ a ⊕ … (c times) for integer c
    np.testing.assert_allclose(plip_scalar_mul(3.0, a, GAMMA), plip_add(plip_add(a, a, GAMMA), a, GAMMA), rtol=1e-10)


def test_closed_form_equals_iterated_form(vals):
    rng = np.random.default_rng(1)
    w = rng.dirichlet(np.ones(3), size=50).T  # 3×50, columns sum to 1
    np.testing.assert_allclose(plip_weighted_sum(vals, w, GAMMA), plip_weighted_sum_iterated(vals, w, GAMMA),
                               rtol=1e-10, atol=1e-8)


def test_weighted_sum_tends_to_arithmetic_mean_for_large_gamma(vals):
    w = np.array([0.2, 0.3, 0.5])[:, None]
    np.testing.assert_allclose(plip_weighted_sum(vals, w, 1e12), (w * vals).sum(axis=0), rtol=1e-6)
    # and for finite γ it is a different (logarithmic) combination
    assert not np.allclose(plip_weighted_sum(vals, w, GAMMA), (w * vals).sum(axis=0), rtol=1e-3)


def test_fusion_of_equal_inputs_returns_them():
    g = np.full((4, 7), 0.37)
    w = np.array([0.1, 0.2, 0.3, 0.4])[:, None]
    np.testing.assert_allclose(plip_weighted_sum(g, w, 1.0), g[0], rtol=1e-12)


def test_torch_and_numpy_agree(vals):
    w = np.array([0.2, 0.3, 0.5])[:, None]
    t = plip_weighted_sum(torch.from_numpy(vals), torch.from_numpy(w), GAMMA, axis=0)
    np.testing.assert_allclose(t.numpy(), plip_weighted_sum(vals, w, GAMMA), rtol=1e-12)
