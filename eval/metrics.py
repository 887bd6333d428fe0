"""Trajectory error metrics: absolute trajectory error (ATE), relative pose error (RPE) over travelled distances,
drift in % of distance travelled.

Inputs are *associated* trajectories (pose i of the estimate pairs with pose i of the reference), the estimate
already aligned (see :mod:`eval.alignment`). Conventions follow evo 1.38 and rpg_trajectory_evaluation:

* ATE translation error of pose i: ``‖p_est,i − p_ref,i‖`` (metres) — evo ``APE translation_part``.
* ATE rotation error: the angle of ``R_est,iᵀ·R_ref,i`` (degrees) — evo ``rotation_angle_deg``; only when both
  trajectories have orientations.
* RPE over a travelled distance Δ: pairs (i, j) chosen on the *reference*'s distance travelled, for every start i
  the j whose distance from i is nearest Δ, kept when within ``rel_tol·Δ`` (rpg's sub-trajectories; evo
  ``--all_pairs --pairs_from_reference -u m -t rel_tol``). Error ``E = (Q_iᵀQ_j)⁻¹(P_iᵀP_j)`` (Q reference,
  P estimate); its translation norm (m) and rotation angle (deg). With a position-only reference the relative
  orientation is unknown, so the error is the difference of the world-frame displacements after alignment,
  ``‖(p_est,j − p_est,i) − (p_ref,j − p_ref,i)‖``.
* Drift: RPE translation error / Δ · 100 (% of distance travelled), per segment.

Statistics over errors are evo's: rmse, mean, median, std (population), min, max, sse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eval.errors import EvalInputError
from eval.quat import qangle_deg, qconj, qmul, qrotate
from eval.trajectory import Trajectory

__all__ = ["ErrorStats", "AteResult", "RpeResult", "ate", "rpe", "select_pairs_by_distance",
           "default_rpe_distances", "DEFAULT_RPE_DISTANCES_M", "DEFAULT_RPE_FRACTIONS"]

#: Preferred RPE segment lengths (metres) for field-scale sequences (hundreds of metres: a row is 60–90 m).
DEFAULT_RPE_DISTANCES_M = (10.0, 50.0, 100.0)
#: rpg's sub-trajectory lengths as fractions of the reference path length, used when the path is too short.
DEFAULT_RPE_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a set of errors (the unit is the errors' unit). NaN everywhere when ``n == 0``."""

    n: int
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float

    @classmethod
    def of(cls, errors: np.ndarray) -> ErrorStats:
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            nan = float("nan")
            return cls(0, nan, nan, nan, nan, nan, nan, nan)
        sq = e * e
        return cls(int(e.size), float(np.sqrt(np.mean(sq))), float(np.mean(e)), float(np.median(e)),
                   float(np.std(e)), float(np.min(e)), float(np.max(e)), float(np.sum(sq)))

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-able (NaN → None)."""
        out: dict[str, float | int | None] = {}
        for k, v in self.__dict__.items():
            out[k] = None if isinstance(v, float) and not np.isfinite(v) else v
        return out


@dataclass(frozen=True, eq=False)
class AteResult:
    """Absolute trajectory error of associated, aligned trajectories.

    Attributes:
        stamps_s: (M,) reference stamps of the pairs, seconds.
        errors_m: (M,) translation error per pose, metres.
        trans: statistics of ``errors_m`` (metres).
        rot_errors_deg: (M,) rotation error per pose, degrees, or None without orientations.
        rot: statistics of ``rot_errors_deg`` or None.
    """

    stamps_s: np.ndarray
    errors_m: np.ndarray
    trans: ErrorStats
    rot_errors_deg: np.ndarray | None
    rot: ErrorStats | None


@dataclass(frozen=True, eq=False)
class RpeResult:
    """Relative pose error over one travelled distance.

    Attributes:
        delta_m: the nominal segment length Δ, metres.
        first: (K,) start indices of the pairs; second: (K,) end indices.
        errors_m: (K,) translation error per segment, metres. trans: its statistics.
        drift_pct: (K,) ``errors_m / Δ · 100``. drift: its statistics (%).
        rot_errors_deg: (K,) rotation error per segment (deg) or None. rot: its statistics or None.
        mode: ``pose`` (relative poses, both orientations known) or ``displacement`` (position-only reference).
    """

    delta_m: float
    first: np.ndarray
    second: np.ndarray
    errors_m: np.ndarray
    trans: ErrorStats
    drift_pct: np.ndarray
    drift: ErrorStats
    rot_errors_deg: np.ndarray | None
    rot: ErrorStats | None
    mode: str


def _check_associated(ref: Trajectory, est: Trajectory) -> None:
    if len(ref) != len(est):
        raise EvalInputError(f"metrics need associated trajectories of equal length, got {len(ref)} and {len(est)}")
    if len(ref) == 0:
        raise EvalInputError("metrics need at least one associated pose")


def ate(ref: Trajectory, est_aligned: Trajectory) -> AteResult:
    """ATE of associated trajectories (``est_aligned`` already aligned to ``ref``'s world)."""
    _check_associated(ref, est_aligned)
    errors = np.linalg.norm(est_aligned.positions - ref.positions, axis=1)
    rot_err = rot_stats = None
    if ref.has_orientation and est_aligned.has_orientation:
        rot_err = qangle_deg(qmul(qconj(est_aligned.quats_xyzw), ref.quats_xyzw))
        rot_stats = ErrorStats.of(rot_err)
    return AteResult(ref.stamps_s, errors, ErrorStats.of(errors), rot_err, rot_stats)


def select_pairs_by_distance(distances_m: np.ndarray, delta_m: float, tol_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Segment pairs over a travelled distance (vectorised; evo's all-pairs rule).

    For every start i (except the last pose), the j > i whose ``distances_m[j] − distances_m[i]`` is nearest
    ``delta_m`` (the earliest on a tie) is kept when that difference is within ``tol_m`` of ``delta_m``.

    Args:
        distances_m: (N,) non-decreasing cumulative distance travelled, metres.
    Returns:
        ``(first, second)`` int64 index arrays.
    """
    d = np.asarray(distances_m, dtype=np.float64)
    n = d.size
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i = np.arange(n - 1)
    target = d[i] + delta_m
    up = np.searchsorted(d, target, side="left")  # first index with d >= target (approximately)
    up = np.maximum(up, i + 1)
    lo = up - 1
    # the lower candidate must be > i; among equal distances argmin takes the earliest index
    lo_first = np.searchsorted(d, d[np.maximum(lo, 0)], side="left")
    lo_first = np.maximum(lo_first, i + 1)
    has_lo = lo >= i + 1
    has_up = up < n
    up_c = np.minimum(up, n - 1)
    diff_up = np.where(has_up, np.abs((d[up_c] - d[i]) - delta_m), np.inf)
    diff_lo = np.where(has_lo, np.abs((d[np.maximum(lo_first, 0).clip(max=n - 1)] - d[i]) - delta_m), np.inf)
    take_lo = diff_lo <= diff_up
    j = np.where(take_lo, lo_first, up_c)
    diff = np.where(take_lo, diff_lo, diff_up)
    keep = diff <= tol_m
    return i[keep].astype(np.int64, copy=False), j[keep].astype(np.int64, copy=False)


def rpe(ref: Trajectory, est: Trajectory, delta_m: float, rel_tol: float = 0.2,
        ref_distances_m: np.ndarray | None = None) -> RpeResult:
    """RPE over travelled distance ``delta_m`` (pairs on the reference's path; see the module docstring).

    ``est`` may be unaligned for SE(3)/posyaw (RPE is invariant to a rigid transform when both have
    orientations) but must carry the Sim(3) scale; for a position-only reference pass the aligned estimate.
    ``ref_distances_m`` ((N,) ``ref.distances_m()``) may be passed to save recomputing it for several deltas.
    """
    _check_associated(ref, est)
    if not delta_m > 0:
        raise EvalInputError(f"RPE distance must be > 0 m, got {delta_m}")
    d = ref.distances_m() if ref_distances_m is None else ref_distances_m
    first, second = select_pairs_by_distance(d, delta_m, rel_tol * delta_m)
    dp_ref = ref.positions[second] - ref.positions[first]
    dp_est = est.positions[second] - est.positions[first]
    rot_err = rot_stats = None
    if ref.has_orientation and est.has_orientation:
        mode = "pose"
        if first.size:
            qi_ref = qconj(ref.quats_xyzw[first])
            qi_est = qconj(est.quats_xyzw[first])
            errors = np.linalg.norm(qrotate(qi_est, dp_est) - qrotate(qi_ref, dp_ref), axis=1)
            rel_ref = qmul(qi_ref, ref.quats_xyzw[second])
            rel_est = qmul(qi_est, est.quats_xyzw[second])
            rot_err = qangle_deg(qmul(qconj(rel_ref), rel_est))
        else:
            errors = np.zeros(0)
            rot_err = np.zeros(0)
        rot_stats = ErrorStats.of(rot_err)
    else:
        mode = "displacement"
        errors = np.linalg.norm(dp_est - dp_ref, axis=1)
    drift = errors / delta_m * 100.0
    return RpeResult(float(delta_m), first, second, errors, ErrorStats.of(errors), drift, ErrorStats.of(drift),
                     rot_err, rot_stats, mode)


def default_rpe_distances(path_length_m: float, preferred: tuple[float, ...] = DEFAULT_RPE_DISTANCES_M,
                          fractions: tuple[float, ...] = DEFAULT_RPE_FRACTIONS,
                          max_fraction: float = 0.75) -> tuple[float, ...]:
    """RPE segment lengths suited to a reference path of ``path_length_m`` metres.

    The ``preferred`` distances no longer than ``max_fraction`` of the path (so that many segments fit); when
    none fits (a short trajectory), rpg's choice: ``fractions`` × path length, truncated to 2 decimals.
    """
    if not path_length_m > 0:
        return ()
    keep = tuple(float(x) for x in preferred if x <= max_fraction * path_length_m)
    if keep:
        return keep
    out = tuple(sorted({np.floor(f * path_length_m * 100.0) / 100.0 for f in fractions} - {0.0}))
    return tuple(float(x) for x in out)
