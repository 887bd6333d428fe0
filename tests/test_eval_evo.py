"""ATE / RPE agree with evo (dev dependency) to 1e-6 m on random and simulated trajectories, SE(3) and Sim(3)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.association import associate
from eval.evaluate import EvalOptions, evaluate
from eval.metrics import rpe
from eval.synthetic import field_path, perturbed_estimate
from eval.trajectory import Trajectory

evo_sync = pytest.importorskip("evo.core.sync", reason="evo is a dev dependency (pip install evo) and not installed")
from evo.core import metrics as evo_metrics  # noqa: E402
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402

TOL = 1e-6


def _to_evo(traj: Trajectory) -> PoseTrajectory3D:
    return PoseTrajectory3D(positions_xyz=np.array(traj.positions), timestamps=np.array(traj.stamps_s),
                            orientations_quat_wxyz=np.roll(np.array(traj.quats_xyzw), 1, axis=1))


def _random_pair(seed: int) -> tuple[Trajectory, Trajectory]:
    """A random-walk 3-D reference with random orientations, and an estimate at other stamps in another frame."""
    rng = np.random.default_rng(seed)
    n = 400
    t_ref = 1000.0 + np.cumsum(rng.uniform(0.04, 0.06, n))
    p_ref = np.cumsum(rng.normal(0.0, 0.3, (n, 3)), axis=0)
    q_ref = Rotation.random(n, rng=rng).as_quat()
    ref = Trajectory(t_ref, p_ref, q_ref)
    r_w = Rotation.random(rng=rng)
    keep = np.sort(rng.choice(n, size=300, replace=False))
    t_est = t_ref[keep] + rng.uniform(-0.015, 0.015, keep.size)
    order = np.argsort(t_est)
    keep, t_est = keep[order], t_est[order]
    p_est = 1.3 * r_w.apply(p_ref[keep] + rng.normal(0.0, 0.1, (keep.size, 3))) + rng.normal(0.0, 5.0, 3)
    jitter = Rotation.from_rotvec(rng.normal(0.0, 0.02, (keep.size, 3)))
    q_est = (r_w * Rotation.from_quat(q_ref[keep]) * jitter).as_quat()
    return ref, Trajectory(t_est, p_est, q_est)


def _simulated_pair(seed: int) -> tuple[Trajectory, Trajectory]:
    gt = field_path(duration_s=150.0, rate_hz=10.0)
    est = perturbed_estimate(gt, seed=seed, yaw_drift_deg=3.0, scale=1.05, time_offset_s=0.004, keep_every=2)
    return gt, est


CASES = [("random", s) for s in (0, 1, 2)] + [("simulated", s) for s in (0, 1)]


@pytest.mark.parametrize("kind,seed", CASES)
@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_ate_matches_evo(kind: str, seed: int, align: str) -> None:
    ref, est = (_random_pair if kind == "random" else _simulated_pair)(seed)
    ev = evaluate(ref, est, EvalOptions(align=align, max_diff_s=0.02, rpe_distances_m=()))
    ref_e, est_e = evo_sync.associate_trajectories(_to_evo(ref), _to_evo(est), max_diff=0.02)
    assert ref_e.num_poses == len(ev.association)
    np.testing.assert_array_equal(ref_e.timestamps, ev.association.ref.stamps_s)
    np.testing.assert_array_equal(est_e.timestamps, ev.association.est.stamps_s)
    r, t, s = est_e.align(ref_e, correct_scale=(align == "sim3"))
    np.testing.assert_allclose(ev.alignment.rotation, r, atol=1e-9)
    np.testing.assert_allclose(ev.alignment.translation, t, atol=1e-7)
    assert ev.alignment.scale == pytest.approx(s, abs=1e-9)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    evo_stats = ape.get_all_statistics()
    ours = ev.ate.trans
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(ours, key) == pytest.approx(evo_stats[key], abs=TOL), key
    np.testing.assert_allclose(ev.ate.errors_m, ape.error, atol=TOL)
    ape_rot = evo_metrics.APE(evo_metrics.PoseRelation.rotation_angle_deg)
    ape_rot.process_data((ref_e, est_e))
    np.testing.assert_allclose(ev.ate.rot_errors_deg, ape_rot.error, atol=1e-6)


@pytest.mark.parametrize("kind,seed", CASES)
@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_rpe_matches_evo(kind: str, seed: int, align: str) -> None:
    ref, est = (_random_pair if kind == "random" else _simulated_pair)(seed)
    assoc = associate(ref, est, max_diff_s=0.02)
    ev = evaluate(ref, est, EvalOptions(align=align, rpe_distances_m=()))
    ref_e, est_e = evo_sync.associate_trajectories(_to_evo(ref), _to_evo(est), max_diff=0.02)
    est_e.align(ref_e, correct_scale=(align == "sim3"))
    length = assoc.ref.path_length_m()
    for delta in (0.1 * length, 0.25 * length, 5.0):
        ours = rpe(assoc.ref, ev.est_aligned, delta, rel_tol=0.2)
        for relation, errors in ((evo_metrics.PoseRelation.translation_part, ours.errors_m),
                                 (evo_metrics.PoseRelation.rotation_angle_deg, ours.rot_errors_deg)):
            m = evo_metrics.RPE(relation, delta=delta, delta_unit=evo_metrics.Unit.meters, rel_delta_tol=0.2,
                                all_pairs=True, pairs_from_reference=True)
            m.process_data((copy.deepcopy(ref_e), copy.deepcopy(est_e)))
            assert len(m.error) == errors.size > 0
            np.testing.assert_allclose(errors, m.error, atol=TOL)
            if relation is evo_metrics.PoseRelation.translation_part:
                assert ours.trans.rmse == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.rmse), abs=TOL)
