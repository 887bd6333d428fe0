"""Association, quaternion helpers, ATE statistics and RPE pair selection against brute-force references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.association import associate, interpolate_reference, match_stamps
from eval.errors import EvalInputError
from eval.evaluate import EvalOptions, evaluate
from eval.metrics import ErrorStats, ate, default_rpe_distances, rpe, select_pairs_by_distance
from eval.quat import qangle_deg, qconj, qmul, qrotate
from eval.synthetic import field_path, perturbed_estimate
from eval.trajectory import Trajectory


def _brute_match(a: np.ndarray, b: np.ndarray, max_diff: float) -> tuple[list[int], list[int]]:
    ia, ib = [], []
    for i, x in enumerate(a):
        d = np.abs(b - x)
        j = int(np.argmin(d))  # first minimum = the earlier stamp on a tie
        if d[j] <= max_diff:
            ia.append(i)
            ib.append(j)
    return ia, ib


@pytest.mark.parametrize("seed", range(20))
def test_match_stamps_equals_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = np.unique(np.round(rng.uniform(0, 10, rng.integers(1, 60)), 3))
    b = np.unique(np.round(rng.uniform(0, 10, rng.integers(1, 200)), 2))  # exact ties happen
    ia, ib = match_stamps(a, b, 0.02)
    ea, eb = _brute_match(a, b, 0.02)
    assert ia.tolist() == ea and ib.tolist() == eb


def test_associate_walks_sparser_trajectory() -> None:
    gt = field_path(duration_s=30.0, rate_hz=5.0)  # 5 Hz GPS-like
    est = perturbed_estimate(field_path(duration_s=30.0, rate_hz=15.0), seed=0, time_offset_s=0.004)
    a = associate(gt, est, max_diff_s=0.02)
    assert len(a) == len(gt)
    assert a.max_dt_s <= 0.02
    np.testing.assert_array_equal(a.ref.stamps_s, gt.stamps_s[a.ref_index])


def test_interpolate_reference() -> None:
    t = np.arange(0.0, 10.0, 1.0)
    rot = Rotation.from_euler("z", (0.1 * t)[:, None])
    ref = Trajectory(t, np.column_stack([t, 2 * t, np.zeros_like(t)]), rot.as_quat())
    est = Trajectory(np.array([-1.0, 0.5, 2.25, 8.75, 9.5]), np.zeros((5, 3)), np.tile([0, 0, 0, 1.0], (5, 1)))
    a = interpolate_reference(ref, est, max_gap_s=1.0)
    assert a.est_index.tolist() == [1, 2, 3]  # outside the reference span: dropped
    np.testing.assert_allclose(a.ref.positions[:, 0], [0.5, 2.25, 8.75])
    np.testing.assert_allclose(a.ref.positions[:, 1], [1.0, 4.5, 17.5])
    yaw = a.ref.rotations.as_euler("ZYX")[:, 0]
    np.testing.assert_allclose(yaw, [0.05, 0.225, 0.875], atol=1e-12)
    # a gap in the reference larger than max_gap_s is not interpolated across
    gap = ref.subset(np.array([0, 1, 2, 6, 7, 8, 9]))
    kept = interpolate_reference(gap, Trajectory.from_positions(np.array([1.5, 4.0, 7.5]), np.zeros((3, 3))),
                                 max_gap_s=1.5)
    assert kept.est_index.tolist() == [0, 2]
    with pytest.raises(EvalInputError, match="at least 2"):
        interpolate_reference(ref.subset(np.array([0])), est)


def test_quaternion_helpers_match_scipy() -> None:
    rng = np.random.default_rng(1)
    a, b = Rotation.random(100, rng=rng), Rotation.random(100, rng=rng)
    v = rng.normal(size=(100, 3))
    prod = qmul(a.as_quat(), b.as_quat())
    np.testing.assert_allclose(Rotation.from_quat(prod).as_matrix(), (a * b).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(qrotate(a.as_quat(), v), a.apply(v), atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(qconj(a.as_quat())).as_matrix(), a.inv().as_matrix(), atol=1e-12)
    np.testing.assert_allclose(qangle_deg(a.as_quat()), np.degrees(a.magnitude()), atol=1e-9)


def test_error_stats_known_values() -> None:
    s = ErrorStats.of(np.array([3.0, 4.0, 0.0, 5.0]))
    assert s.n == 4 and s.rmse == pytest.approx(np.sqrt(50 / 4)) and s.mean == 3.0 and s.median == 3.5
    assert s.min == 0.0 and s.max == 5.0 and s.sse == 50.0 and s.std == pytest.approx(np.std([3, 4, 0, 5]))
    empty = ErrorStats.of(np.zeros(0))
    assert empty.n == 0 and empty.to_dict()["rmse"] is None


def test_ate_constant_offset() -> None:
    gt = field_path(duration_s=20.0)
    shifted = Trajectory(gt.stamps_s, gt.positions + [0.3, 0.4, 0.0], gt.quats_xyzw)
    res = ate(gt, shifted)
    np.testing.assert_allclose(res.errors_m, 0.5)
    assert res.trans.rmse == pytest.approx(0.5) and res.rot.max < 1e-9
    assert ate(Trajectory.from_positions(gt.stamps_s, gt.positions), shifted).rot is None


def _brute_pairs(d: np.ndarray, delta: float, tol: float) -> list[tuple[int, int]]:
    out = []
    for i in range(d.size - 1):
        rel = d[i + 1:] - d[i]
        k = int(np.argmin(np.abs(rel - delta)))
        if abs(rel[k] - delta) <= tol:
            out.append((i, i + 1 + k))
    return out


@pytest.mark.parametrize("seed", range(10))
def test_pair_selection_equals_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    steps = np.round(rng.exponential(0.5, 300), 1) * (rng.uniform(size=300) > 0.2)  # standstills and ties
    d = np.concatenate([[0.0], np.cumsum(steps)])
    for delta in (1.0, 5.0, 20.0):
        i, j = select_pairs_by_distance(d, delta, 0.2 * delta)
        assert list(zip(i.tolist(), j.tolist())) == _brute_pairs(d, delta, 0.2 * delta)


def test_rpe_modes_and_drift() -> None:
    gt = field_path(duration_s=100.0, rate_hz=10.0)
    # constant 1 % scale error: relative errors are 1 % of each segment's straight-line displacement
    est = Trajectory(gt.stamps_s, gt.positions * 1.01, gt.quats_xyzw)
    res = rpe(gt, est, 10.0)
    assert res.mode == "pose" and res.trans.n > 800
    chord = np.linalg.norm(gt.positions[res.second] - gt.positions[res.first], axis=1)
    np.testing.assert_allclose(res.errors_m, 0.01 * chord, rtol=1e-9)
    np.testing.assert_allclose(res.drift_pct, res.errors_m / 10.0 * 100.0)
    pos_only = Trajectory.from_positions(gt.stamps_s, gt.positions)
    res2 = rpe(pos_only, est, 10.0)
    assert res2.mode == "displacement" and res2.rot is None
    np.testing.assert_allclose(res2.errors_m, res.errors_m, rtol=1e-9)
    with pytest.raises(EvalInputError, match="> 0"):
        rpe(gt, est, 0.0)


def test_default_rpe_distances() -> None:
    assert default_rpe_distances(500.0) == (10.0, 50.0, 100.0)
    assert default_rpe_distances(100.0) == (10.0, 50.0)  # 100 m segments need ≥ 133 m of path
    assert default_rpe_distances(50.0) == (10.0,)
    assert default_rpe_distances(12.34) == (1.23, 2.46, 3.7, 4.93, 6.17)
    assert default_rpe_distances(0.0) == ()


def test_evaluation_metrics_are_json_ready_and_deterministic() -> None:
    import json

    gt = field_path(duration_s=60.0, rate_hz=5.0)
    est = perturbed_estimate(field_path(duration_s=60.0, rate_hz=15.0), seed=3, time_offset_s=0.003)
    gps = Trajectory.from_positions(gt.stamps_s, gt.positions)
    m1 = evaluate(gps, est, EvalOptions(align="posyaw")).metrics()
    m2 = evaluate(gps, est, EvalOptions(align="posyaw")).metrics()
    assert json.dumps(m1, sort_keys=True) == json.dumps(m2, sort_keys=True)
    assert m1["n_pairs"] == len(gt) and "ate_rot_rmse_deg" not in m1
    assert set(m1["rpe"]) == {"10"}  # 60 m path: 50 m segments (> ¾ of it) are not evaluated
    assert m1["rpe"]["10"]["mode"] == "displacement" and m1["drift_pct"] > 0
