"""Alignment recovers known transforms exactly; degenerate inputs give clear errors; lever arm."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.alignment import align_yaw, apply_lever_arm, fit_alignment, umeyama
from eval.association import associate
from eval.errors import EvalInputError
from eval.evaluate import EvalOptions, evaluate
from eval.synthetic import field_path, random_transform
from eval.trajectory import Trajectory


@pytest.mark.parametrize("seed", range(5))
def test_umeyama_recovers_se3_and_sim3(seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.normal(0, 20, (50, 3))
    rot, t = random_transform(rng)
    for scale, with_scale in ((1.0, False), (rng.uniform(0.3, 3.0), True)):
        dst = scale * src @ rot.T + t
        a = umeyama(src, dst, with_scale=with_scale)
        np.testing.assert_allclose(a.rotation, rot, atol=1e-10)
        np.testing.assert_allclose(a.translation, t, atol=1e-9)
        assert a.scale == pytest.approx(scale, rel=1e-12)
        assert np.linalg.det(a.rotation) == pytest.approx(1.0)
        np.testing.assert_allclose(a.apply_points(src), dst, atol=1e-9)


def test_umeyama_handles_reflection_case() -> None:
    # planar points: the SVD may return a reflection; the result must stay a rotation
    rng = np.random.default_rng(7)
    src = np.column_stack([rng.normal(0, 5, (30, 2)), np.zeros(30)])
    rot = Rotation.from_euler("z", 170, degrees=True).as_matrix()
    a = umeyama(src, src @ rot.T + 1.0)
    assert np.linalg.det(a.rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(a.rotation, rot, atol=1e-10)


@pytest.mark.parametrize("seed", range(3))
def test_yaw_alignment_recovers_yaw_and_translation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.normal(0, 10, (40, 3))
    yaw = rng.uniform(-np.pi, np.pi)
    rot = Rotation.from_euler("z", yaw).as_matrix()
    t = rng.normal(0, 5, 3)
    a = align_yaw(src, src @ rot.T + t)
    assert a.method == "posyaw" and a.scale == 1.0
    np.testing.assert_allclose(a.rotation, rot, atol=1e-12)
    np.testing.assert_allclose(a.translation, t, atol=1e-10)


def test_alignment_through_evaluate_is_exact() -> None:
    gt = field_path(duration_s=60.0, rate_hz=10.0)
    rot = Rotation.from_euler("z", 40, degrees=True)
    est = Trajectory(gt.stamps_s, rot.apply(gt.positions) + [5.0, -3.0, 1.0], (rot * gt.rotations).as_quat())
    for method in ("se3", "posyaw", "sim3"):
        ev = evaluate(gt, est, EvalOptions(align=method))
        assert ev.ate.trans.max < 1e-9
        assert ev.ate.rot.max < 1e-6
        for r in ev.rpe:
            assert r.trans.max < 1e-9
    assert evaluate(gt, est, EvalOptions(align="none")).ate.trans.rmse > 1.0


def test_fewer_than_three_poses() -> None:
    src = np.array([[0.0, 0, 0], [1, 1, 0]])
    for fn in (lambda: umeyama(src, src), lambda: align_yaw(src, src)):
        with pytest.raises(EvalInputError, match="at least 3"):
            fn()
    traj = Trajectory.from_positions(np.array([0.0, 1.0]), src)
    with pytest.raises(EvalInputError, match="at least 3"):
        evaluate(traj, traj)


def test_collinear_positions() -> None:
    line = np.outer(np.arange(10.0), [1.0, 2.0, 0.5])
    with pytest.raises(EvalInputError, match="one line"):
        umeyama(line, line + 1.0)
    with pytest.raises(EvalInputError, match="one line"):
        umeyama(line, line, with_scale=True)
    # yaw alignment: a straight horizontal line determines the yaw, a vertical one (or one point) does not
    a = align_yaw(line, line + 1.0)
    np.testing.assert_allclose(a.rotation, np.eye(3), atol=1e-12)
    vertical = np.outer(np.arange(10.0), [0.0, 0.0, 1.0])
    with pytest.raises(EvalInputError, match="yaw is undetermined"):
        align_yaw(vertical, vertical)
    still = np.zeros((10, 3))
    with pytest.raises(EvalInputError, match="yaw is undetermined"):
        align_yaw(still, still)


def test_no_overlap_in_time() -> None:
    gt = field_path(duration_s=20.0)
    late = Trajectory(gt.stamps_s + 100.0, gt.positions, gt.quats_xyzw)
    with pytest.raises(EvalInputError, match="no overlap in time"):
        associate(gt, late)
    with pytest.raises(EvalInputError, match="no overlap in time"):
        evaluate(gt, late, EvalOptions(interpolate=True))
    # clocks 50 ms apart: no pair within 20 ms, but an offset fixes it
    shifted = Trajectory(gt.stamps_s + 0.05, gt.positions, gt.quats_xyzw)
    with pytest.raises(EvalInputError, match="20 ms"):
        associate(gt, shifted)
    assert len(associate(gt, shifted, offset_s=-0.05)) == len(gt)


def test_unknown_method_and_first_n() -> None:
    gt = field_path(duration_s=30.0)
    with pytest.raises(EvalInputError, match="unknown alignment"):
        fit_alignment(gt, gt, "affine")
    with pytest.raises(EvalInputError, match="unknown alignment"):
        EvalOptions(align="foo")
    a = fit_alignment(gt, gt, "se3", first_n=50)
    assert a.n_pairs == 50


def test_lever_arm() -> None:
    gt = field_path(duration_s=60.0, rate_hz=10.0)
    arm = np.array([1.8, -0.03, 1.59])
    antenna = apply_lever_arm(gt, arm)
    np.testing.assert_allclose(antenna.positions, gt.positions + gt.rotations.apply(arm), atol=1e-12)
    gps = Trajectory.from_positions(antenna.stamps_s, antenna.positions)
    assert evaluate(gps, gt, EvalOptions(lever_arm_m=tuple(arm))).ate.trans.max < 1e-9
    assert evaluate(gps, gt).ate.trans.rmse > 0.1  # without the lever arm the antenna offset shows
    with pytest.raises(EvalInputError, match="orientation"):
        apply_lever_arm(gps, arm)


def test_eval_options_round_trip_through_a_record_dict():
    """Records store EvalOptions.to_dict(); from_dict gives the same options back (lists → tuples), and keys of
    other versions are ignored rather than breaking an old record."""
    from eval.evaluate import EvalOptions

    opts = EvalOptions(align="posyaw", max_diff_s=0.03, lever_arm_m=(0.1, -0.2, 0.3), rpe_distances_m=(10.0, 50.0))
    assert EvalOptions.from_dict(opts.to_dict()) == opts
    assert EvalOptions.from_dict({**opts.to_dict(), "from_the_future": 1, "first_n": None}) == opts
