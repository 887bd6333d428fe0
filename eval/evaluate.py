"""One-call evaluation of an estimate against a reference: lever arm → association → alignment → ATE, RPE.

This is what ``agrivio evaluate`` and the run pipeline call; the parts live in :mod:`eval.association`,
:mod:`eval.alignment` and :mod:`eval.metrics`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from eval.alignment import ALIGN_METHODS, Alignment, apply_lever_arm, fit_alignment
from eval.association import DEFAULT_MAX_DIFF_S, Association, associate, interpolate_reference
from eval.errors import EvalInputError
from eval.metrics import AteResult, RpeResult, ate, default_rpe_distances, rpe
from eval.trajectory import Trajectory

__all__ = ["EvalOptions", "Evaluation", "evaluate"]


@dataclass(frozen=True)
class EvalOptions:
    """How to compare an estimate with a reference (defaults in brackets).

    Attributes:
        align: ``se3`` [default; the Rosario authors' ``evo --align``] | ``sim3`` | ``posyaw`` | ``none``.
        max_diff_s: association tolerance, seconds [0.02].
        offset_s: added to estimate stamps for the association, seconds [0].
        interpolate: interpolate the reference at the estimate's stamps instead of nearest-stamp matching [False].
        max_gap_s: with ``interpolate``, largest reference gap to interpolate across, seconds [0.5].
        first_n: fit the alignment on the first N pairs only [None = all].
        lever_arm_m: (3,) ``t_body_point`` — express the estimate at this body-frame point (e.g. the GPS antenna)
            before comparing [None].
        rpe_distances_m: RPE segment lengths [None = :func:`eval.metrics.default_rpe_distances` of the reference
            path length].
        rpe_rel_tol: RPE pair tolerance relative to the segment length [0.2, rpg's].
    """

    align: str = "se3"
    max_diff_s: float = DEFAULT_MAX_DIFF_S
    offset_s: float = 0.0
    interpolate: bool = False
    max_gap_s: float = 0.5
    first_n: int | None = None
    lever_arm_m: tuple[float, float, float] | None = None
    rpe_distances_m: tuple[float, ...] | None = None
    rpe_rel_tol: float = 0.2

    def __post_init__(self) -> None:
        if self.align not in ALIGN_METHODS:
            raise EvalInputError(f"unknown alignment {self.align!r}; choose one of {', '.join(ALIGN_METHODS)}")
        if self.lever_arm_m is not None:
            object.__setattr__(self, "lever_arm_m", tuple(float(x) for x in np.asarray(self.lever_arm_m).reshape(3)))
        if self.rpe_distances_m is not None:
            object.__setattr__(self, "rpe_distances_m", tuple(float(x) for x in self.rpe_distances_m))

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EvalOptions:
        """The inverse of :meth:`to_dict` (lists become tuples). Keys of other versions and None values are
        ignored, so a record written by another version still gives the options it can state."""
        names = {f.name for f in fields(cls)}
        kwargs: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()
                                  if k in names and v is not None}
        return cls(**kwargs)


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Everything one comparison produced.

    Attributes:
        options: the options used.
        association: the pose pairs (``association.est`` is unaligned, at the lever-arm point if one was given).
        alignment: the fitted transform (estimate world → reference world).
        est_aligned: the associated estimate after alignment (for plots: top view, error over time).
        ate: absolute errors. rpe: one :class:`RpeResult` per segment length (ascending).
        ref_path_length_m: distance travelled along the associated reference, metres.
    """

    options: EvalOptions
    association: Association
    alignment: Alignment
    est_aligned: Trajectory
    ate: AteResult
    rpe: tuple[RpeResult, ...] = field(default_factory=tuple)
    ref_path_length_m: float = 0.0

    @property
    def ref(self) -> Trajectory:
        return self.association.ref

    def metrics(self) -> dict[str, Any]:
        """Flat, JSON-able metrics for a run record (metres, degrees, %)."""
        t = self.ate.trans
        out: dict[str, Any] = {
            "ate_rmse_m": t.rmse, "ate_mean_m": t.mean, "ate_median_m": t.median, "ate_std_m": t.std,
            "ate_min_m": t.min, "ate_max_m": t.max,
            "n_pairs": len(self.association), "align": self.alignment.method, "align_scale": self.alignment.scale,
            "align_yaw_deg": self.alignment.yaw_deg(), "ref_path_length_m": self.ref_path_length_m,
            "duration_s": self.association.ref.duration_s,
        }
        if self.ate.rot is not None:
            out["ate_rot_rmse_deg"] = self.ate.rot.rmse
            out["ate_rot_mean_deg"] = self.ate.rot.mean
        rpe_out = {}
        drifts = []
        for r in self.rpe:
            item: dict[str, Any] = {"delta_m": r.delta_m, "n": r.trans.n, "mode": r.mode,
                                    "trans_rmse_m": r.trans.rmse, "trans_mean_m": r.trans.mean,
                                    "trans_median_m": r.trans.median, "drift_mean_pct": r.drift.mean}
            if r.rot is not None:
                item["rot_rmse_deg"] = r.rot.rmse
                item["rot_mean_deg"] = r.rot.mean
            rpe_out[f"{r.delta_m:g}"] = item
            drifts.append(r.drift_pct)
        out["rpe"] = rpe_out
        all_drift = np.concatenate(drifts) if drifts else np.zeros(0)
        out["drift_pct"] = float(np.mean(all_drift)) if all_drift.size else None
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in out.items()}


def evaluate(ref: Trajectory, est: Trajectory, options: EvalOptions | None = None) -> Evaluation:
    """Compare ``est`` with ``ref``: lever arm, associate (or interpolate), align, ATE, RPE.

    Raises:
        EvalInputError: no overlap in time, fewer than 3 pairs, degenerate alignment, a lever arm without
            orientation.
    """
    opt = options or EvalOptions()
    if opt.lever_arm_m is not None:
        est = apply_lever_arm(est, np.asarray(opt.lever_arm_m))
    if opt.interpolate:
        assoc = interpolate_reference(ref, est, max_gap_s=opt.max_gap_s, offset_s=opt.offset_s)
    else:
        assoc = associate(ref, est, max_diff_s=opt.max_diff_s, offset_s=opt.offset_s)
    if len(assoc) < 3:
        raise EvalInputError(f"only {len(assoc)} pose(s) of the estimate could be associated with the reference "
                             f"(need at least 3); check the time overlap and the association tolerance")
    alignment = fit_alignment(assoc.ref, assoc.est, opt.align, opt.first_n)
    est_aligned = alignment.apply(assoc.est)
    ate_res = ate(assoc.ref, est_aligned)
    travelled = assoc.ref.distances_m()
    length = float(travelled[-1])
    distances = opt.rpe_distances_m if opt.rpe_distances_m is not None else default_rpe_distances(length)
    rpes = tuple(rpe(assoc.ref, est_aligned, d, opt.rpe_rel_tol, travelled) for d in sorted(distances))
    return Evaluation(opt, assoc, alignment, est_aligned, ate_res, rpes, length)
