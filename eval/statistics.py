"""Statistics over repeated runs (five seeds per sequence × variant) and before/after significance.

Failed runs are never dropped silently: every group counts its failed runs and keeps their reasons; summary
numbers are over the successful runs only, and say how many those were.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as sps

from eval.records import RunRecord
from eval.variants import ODOMETRY, VARIANTS

__all__ = ["MetricSummary", "GroupStats", "summarize", "variant_sort_key", "welch_test", "bootstrap_relative_change",
           "DEFAULT_METRICS", "VARIANT_ORDER"]

#: Metrics summarised by default: ATE RMSE and ATE mean (metres).
DEFAULT_METRICS = ("ate_rmse_m", "ate_mean_m", "ate_rmse_pct_distance")
#: Display order of the standard variants (:data:`eval.variants.VARIANTS`); anything else goes between
#: depth-inpainted and odometry.
VARIANT_ORDER = VARIANTS


@dataclass(frozen=True)
class MetricSummary:
    """Summary of one metric over the successful runs of a group.

    ``std`` is the sample standard deviation (ddof = 1; NaN for a single run). ``values`` are per run, in seed order.
    """

    n: int
    mean: float
    std: float
    min: float
    max: float
    values: tuple[float, ...]

    @classmethod
    def of(cls, values: Sequence[float | None]) -> MetricSummary:
        v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
        nan = float("nan")
        if v.size == 0:
            return cls(0, nan, nan, nan, nan, ())
        std = float(np.std(v, ddof=1)) if v.size > 1 else nan
        return cls(int(v.size), float(v.mean()), std, float(v.min()), float(v.max()), tuple(float(x) for x in v))

    def to_dict(self) -> dict:
        def clean(x: float) -> float | None:
            return x if math.isfinite(x) else None
        return {"n": self.n, "mean": clean(self.mean), "std": clean(self.std), "min": clean(self.min),
                "max": clean(self.max), "values": list(self.values)}


@dataclass(frozen=True)
class GroupStats:
    """All runs of one sequence × variant.

    Attributes:
        sequence, variant: the group (variant as displayed, see ``RunRecord.display_variant``).
        n_runs, n_ok, n_failed: run counts.
        failures: (seed, reason) of each failed run.
        metrics: metric name → summary over the successful runs (a run missing the metric is not counted in it).
        seeds: seeds of all runs, sorted.
        base_variant: the runs' own variant (``depth-inpainted`` for every inpainting method); inpaint_method: their
            inpainting method (None where none applies) — fields, so nothing parses them out of ``variant``.
    """

    sequence: str
    variant: str
    n_runs: int
    n_ok: int
    n_failed: int
    failures: tuple[tuple[int, str], ...]
    metrics: dict[str, MetricSummary] = field(default_factory=dict)
    seeds: tuple[int, ...] = ()
    base_variant: str = ""
    inpaint_method: str | None = None

    def to_dict(self) -> dict:
        return {"sequence": self.sequence, "variant": self.variant, "n_runs": self.n_runs, "n_ok": self.n_ok,
                "n_failed": self.n_failed, "failures": [{"seed": s, "reason": r} for s, r in self.failures],
                "seeds": list(self.seeds), "metrics": {k: v.to_dict() for k, v in self.metrics.items()}}


def variant_sort_key(variant: str) -> tuple[int, str]:
    """Order: stereo, depth-raw, depth-inpainted, other variants (alphabetical), odometry."""
    if variant in VARIANT_ORDER:
        rank = VARIANT_ORDER.index(variant)
        return (rank if variant != ODOMETRY else 10, variant)
    return (5, variant)


def summarize(records: Iterable[RunRecord], metric_names: Sequence[str] = DEFAULT_METRICS) -> list[GroupStats]:
    """Group runs by (sequence, displayed variant) and summarise ``metric_names`` over the successful ones.

    Returns groups sorted by sequence, then :func:`variant_sort_key`. Runs within a group are taken in seed order.
    """
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for rec in records:
        groups.setdefault((rec.sequence, rec.display_variant()), []).append(rec)
    out = []
    for (seq, var), recs in groups.items():
        recs = sorted(recs, key=lambda r: r.seed)
        ok = [r for r in recs if r.ok]
        failed = [r for r in recs if not r.ok]
        metrics = {m: MetricSummary.of([r.metric(m) for r in ok]) for m in metric_names}
        out.append(GroupStats(seq, var, len(recs), len(ok), len(failed),
                              tuple((r.seed, r.failure_reason or "") for r in failed), metrics,
                              tuple(r.seed for r in recs), recs[0].variant, recs[0].inpaint_method))
    out.sort(key=lambda g: (g.sequence, variant_sort_key(g.variant)))
    return out


def welch_test(before: Sequence[float], after: Sequence[float]) -> tuple[float, float] | None:
    """Welch's unequal-variance t-test of ``after`` vs ``before``: (t statistic, two-sided p-value).

    None when either side has fewer than 2 values or both have zero variance (the test is undefined).
    """
    a = np.asarray(before, dtype=np.float64)
    b = np.asarray(after, dtype=np.float64)
    if a.size < 2 or b.size < 2 or (np.ptp(a) == 0.0 and np.ptp(b) == 0.0):
        return None
    res = sps.ttest_ind(b, a, equal_var=False)
    return float(res.statistic), float(res.pvalue)


def bootstrap_relative_change(before: Sequence[float], after: Sequence[float], n_boot: int = 10000,
                              confidence: float = 0.95, seed: int = 0) -> tuple[float, float] | None:
    """Percentile bootstrap CI of the relative change of the mean, ``(mean(after) − mean(before)) / mean(before)``.

    Each side is resampled with replacement independently (seeded, deterministic). Returns (low, high) as
    fractions (−0.5 = 50 % lower), or None with fewer than 2 runs on a side or a zero "before" mean.
    """
    a = np.asarray(before, dtype=np.float64)
    b = np.asarray(after, dtype=np.float64)
    if a.size < 2 or b.size < 2 or a.mean() == 0.0:
        return None
    rng = np.random.default_rng(seed)
    ma = a[rng.integers(0, a.size, size=(n_boot, a.size))].mean(axis=1)
    mb = b[rng.integers(0, b.size, size=(n_boot, b.size))].mean(axis=1)
    ok = ma != 0.0
    rel = (mb[ok] - ma[ok]) / ma[ok]
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(rel, [alpha, 1.0 - alpha])
    return float(lo), float(hi)
