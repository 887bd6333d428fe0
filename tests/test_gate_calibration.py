"""The χ² calibration factor of a run's gate statistics (eval.gate_calibration)."""

import numpy as np
import pytest

from eval.gate_calibration import chi2_exceed_fraction, chi2_noise_scale, gate_statistics


def _draws(scale: float, dofs: np.ndarray, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return scale * rng.chisquare(dofs)


@pytest.mark.parametrize("scale", [0.25, 1.0, 4.0])
def test_noise_scale_recovers_the_factor_whatever_the_dof_mix(scale: float) -> None:
    dofs = np.repeat([1, 3, 3, 3, 12, 54], 4000)
    c = chi2_noise_scale(_draws(scale, dofs), dofs)
    assert c == pytest.approx(scale, rel=0.06)


def test_median_gamma_per_dof_is_not_one_when_calibrated_but_the_scale_is() -> None:
    dofs = np.full(20000, 3)
    g = _draws(1.0, dofs, seed=1)
    assert np.median(g / dofs) == pytest.approx(0.79, abs=0.03)        # the χ²(3) median over 3, not 1
    assert chi2_noise_scale(g, dofs) == pytest.approx(1.0, rel=0.05)
    assert chi2_exceed_fraction(g, dofs) == pytest.approx(0.05, abs=0.01)


def test_invalid_entries_are_ignored_and_empty_input_is_nan() -> None:
    dofs = np.array([3.0, 3.0, 0.0, 3.0])
    g = np.array([2.366, 2.366, 5.0, np.inf])                          # χ²(3) median ≈ 2.366
    assert chi2_noise_scale(g, dofs) == pytest.approx(1.0, rel=1e-3)
    assert np.isnan(chi2_noise_scale(np.zeros(0), np.zeros(0)))
    assert np.isnan(chi2_exceed_fraction(np.array([np.nan]), np.array([2.0])))
    assert chi2_noise_scale(np.zeros(4), np.full(4, 2.0)) == 0.0
    with pytest.raises(ValueError):
        chi2_exceed_fraction(g, dofs, quantile=1.0)


def test_gate_statistics_summarises_a_run_and_is_nan_without_features() -> None:
    dofs = np.repeat([3, 12], 5000)
    g = _draws(0.5, dofs, seed=2)
    st = gate_statistics(g, dofs)
    assert st["gamma_per_dof_median"] == pytest.approx(float(np.median(g / dofs)))
    assert st["gamma_per_dof_mean"] == pytest.approx(0.5, rel=0.05)
    assert st["chi2_noise_scale"] == pytest.approx(0.5, rel=0.06)
    assert st["above_chi2_95"] < 0.01                                   # half the stated variance: few exceed
    empty = gate_statistics(np.zeros(0), np.zeros(0))
    assert set(empty) == set(st) and all(np.isnan(v) for v in empty.values())
