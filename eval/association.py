"""Time association of an estimate with a reference trajectory.

Two ways, both giving pose pairs at (approximately) the same time:

* :func:`associate` — nearest stamp within ``max_diff_s`` (default 20 ms, the Rosario authors' ``--t_max_diff``).
  Same rule as evo's ``sync.associate_trajectories`` (nearest time): the trajectory with fewer poses is walked,
  each of its stamps is matched to the nearest stamp of the other (ties go to the earlier stamp), and kept when
  the difference is at most ``max_diff_s``. One pose of the denser trajectory may serve two sparse ones.
* :func:`interpolate_reference` — the reference resampled at the estimate's stamps (positions linear,
  rotations slerp), only inside the reference's time span and where the bracketing reference poses are at most
  ``max_gap_s`` apart (no interpolation across a GPS outage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Slerp

from eval.errors import EvalInputError
from eval.trajectory import Trajectory

__all__ = ["Association", "match_stamps", "associate", "interpolate_reference"]

DEFAULT_MAX_DIFF_S = 0.02


@dataclass(frozen=True, eq=False)
class Association:
    """Pose pairs of a reference and an estimate.

    Attributes:
        ref: (M poses) the reference at the pairs (a subset, or interpolated poses).
        est: (M poses) the estimate at the pairs, in the estimate's own frame and clock.
        ref_index: (M,) int64 index into the original reference (-1 for interpolated poses).
        est_index: (M,) int64 index into the original estimate.
        max_dt_s: largest |t_ref − (t_est + offset)| among the pairs, seconds (0 when interpolated).
    """

    ref: Trajectory
    est: Trajectory
    ref_index: np.ndarray
    est_index: np.ndarray
    max_dt_s: float

    def __len__(self) -> int:
        return len(self.est)


def match_stamps(stamps_a: np.ndarray, stamps_b: np.ndarray, max_diff_s: float) -> tuple[np.ndarray, np.ndarray]:
    """For every stamp of ``stamps_a`` the nearest stamp of ``stamps_b`` (both sorted, seconds).

    Returns ``(ia, ib)`` int64 arrays of the matched indices, keeping pairs with ``|a − b| <= max_diff_s``;
    on a tie the earlier ``b`` wins. Vectorised (binary search), O((Na + Nb) log Nb).
    """
    a = np.asarray(stamps_a, dtype=np.float64)
    b = np.asarray(stamps_b, dtype=np.float64)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    upper = np.searchsorted(b, a, side="right")
    upper_c = np.minimum(upper, b.size - 1)
    lower = np.maximum(upper - 1, 0)
    diff_up = np.abs(b[upper_c] - a)
    diff_lo = np.where(upper > 0, a - b[lower], np.inf)
    take_up = (upper < b.size) & (diff_up < diff_lo)
    best = np.where(take_up, upper_c, lower)
    diff = np.where(take_up, diff_up, np.abs(a - b[lower]))
    keep = diff <= max_diff_s
    return np.flatnonzero(keep).astype(np.int64, copy=False), best[keep].astype(np.int64, copy=False)


def _check_orders(ref: Trajectory, est: Trajectory) -> None:
    if len(ref) == 0 or len(est) == 0:
        raise EvalInputError("cannot associate an empty trajectory")


def associate(ref: Trajectory, est: Trajectory, max_diff_s: float = DEFAULT_MAX_DIFF_S,
              offset_s: float = 0.0) -> Association:
    """Pair estimate and reference poses by nearest time stamp.

    Args:
        ref: reference (ground truth).
        est: estimate.
        max_diff_s: largest accepted |t_ref − (t_est + offset_s)|, seconds.
        offset_s: added to the estimate's stamps for the matching only (the estimate keeps its own clock).

    Raises:
        EvalInputError: when no pair is found (no overlap in time, or clocks offset by more than ``max_diff_s``).
    """
    _check_orders(ref, est)
    if not max_diff_s >= 0.0:
        raise EvalInputError(f"max_diff_s must be >= 0, got {max_diff_s}")
    est_t = est.stamps_s + offset_s
    if len(est) > len(ref):  # walk the sparser trajectory (as evo does)
        ir, ie = match_stamps(ref.stamps_s, est_t, max_diff_s)
    else:
        ie, ir = match_stamps(est_t, ref.stamps_s, max_diff_s)
    if ir.size == 0:
        raise EvalInputError(
            f"no pose of the estimate ({est.stamps_s[0]:.3f}–{est.stamps_s[-1]:.3f} s, {len(est)} poses) is within "
            f"{max_diff_s * 1e3:g} ms of a reference pose ({ref.stamps_s[0]:.3f}–{ref.stamps_s[-1]:.3f} s, "
            f"{len(ref)} poses){'' if offset_s == 0 else f' with offset {offset_s:g} s'}: no overlap in time")
    max_dt = float(np.max(np.abs(ref.stamps_s[ir] - est_t[ie])))
    return Association(ref.subset(ir), est.subset(ie), ir, ie, max_dt)


def interpolate_reference(ref: Trajectory, est: Trajectory, max_gap_s: float = 0.5,
                          offset_s: float = 0.0) -> Association:
    """The reference interpolated at the estimate's stamps (+ ``offset_s``).

    Positions are interpolated linearly, orientations by slerp (kept identity for a position-only reference).
    Estimate poses outside the reference's time span, or whose bracketing reference poses are more than
    ``max_gap_s`` apart, are dropped. The returned reference carries the estimate's stamps (+ offset).

    Raises:
        EvalInputError: when no estimate pose can be paired, or the reference has fewer than 2 poses.
    """
    _check_orders(ref, est)
    if len(ref) < 2:
        raise EvalInputError("interpolating the reference needs at least 2 reference poses")
    t = est.stamps_s + offset_s
    rs = ref.stamps_s
    hi = np.searchsorted(rs, t, side="left")
    inside = (t >= rs[0]) & (t <= rs[-1])
    hi_c = np.clip(hi, 1, len(rs) - 1)
    lo_c = hi_c - 1
    exact = (hi < len(rs)) & (rs[np.minimum(hi, len(rs) - 1)] == t)
    gap_ok = (rs[hi_c] - rs[lo_c]) <= max_gap_s
    keep = inside & (gap_ok | exact)
    ie = np.flatnonzero(keep).astype(np.int64)
    if ie.size == 0:
        raise EvalInputError(
            f"no estimate stamp ({est.stamps_s[0]:.3f}–{est.stamps_s[-1]:.3f} s) lies inside the reference "
            f"({rs[0]:.3f}–{rs[-1]:.3f} s) between poses at most {max_gap_s:g} s apart: no overlap in time")
    tq = t[ie]
    hi_k, lo_k = hi_c[ie], lo_c[ie]
    w = (tq - rs[lo_k]) / (rs[hi_k] - rs[lo_k])
    positions = (1.0 - w)[:, None] * ref.positions[lo_k] + w[:, None] * ref.positions[hi_k]
    if ref.has_orientation:
        quats = Slerp(rs, ref.rotations)(tq).as_quat()
    else:
        quats = np.tile([0.0, 0.0, 0.0, 1.0], (ie.size, 1))
    ref_i = Trajectory(tq, positions, quats, has_orientation=ref.has_orientation)
    return Association(ref_i, est.subset(ie), np.full(ie.size, -1, np.int64), ie, 0.0)
