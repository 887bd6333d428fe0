"""Before/after comparison in the shape of the paper's Table 2, plus every other variant.

The paper (Table 2) reports, per Rosario sequence, "ATE (m)" and "RMSE" of S-MSCKF before and after depth
inpainting, each averaged over five runs. We read "ATE" as the mean translational error after alignment and
"RMSE" as the RMSE of the same errors (``ate_mean_m`` and ``ate_rmse_m`` of the run records); the report states
this. "Before" is the ``depth-raw`` variant, "after" ``depth-inpainted`` with the paper's method.

Relative change = (after − before) / before of the across-run means (negative = better). Significance: Welch's
t-test over the per-run values and a seeded percentile-bootstrap 95 % CI of the relative change.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from eval.statistics import GroupStats, MetricSummary, bootstrap_relative_change, welch_test
from eval.variants import DEPTH_INPAINTED, DEPTH_RAW

__all__ = ["ComparisonRow", "compare_groups", "table2", "variants_table", "markdown_table", "table2_markdown",
           "variants_markdown", "fmt_pm", "BEFORE", "AFTER", "ALPHA"]

BEFORE = DEPTH_RAW
AFTER = DEPTH_INPAINTED
#: Significance level for the note.
ALPHA = 0.05


@dataclass(frozen=True)
class ComparisonRow:
    """One sequence of the before/after table.

    Attributes:
        sequence: the sequence.
        before, after: the two groups (None when a variant has no run for this sequence).
        ate_change, rmse_change: relative change of the across-run mean of ``ate_mean_m`` / ``ate_rmse_m``
            (fraction; −0.5 = 50 % lower after), None when not computable.
        welch: (t, p) of Welch's test on per-run ATE RMSE, or None.
        bootstrap_ci: 95 % bootstrap CI of the RMSE relative change (fractions), or None.
        note: a one-line human-readable significance note.
    """

    sequence: str
    before: GroupStats | None
    after: GroupStats | None
    ate_change: float | None
    rmse_change: float | None
    welch: tuple[float, float] | None
    bootstrap_ci: tuple[float, float] | None
    note: str

    def to_dict(self) -> dict:
        return {"sequence": self.sequence, "before": self.before.to_dict() if self.before else None,
                "after": self.after.to_dict() if self.after else None, "ate_change": self.ate_change,
                "rmse_change": self.rmse_change,
                "welch": {"t": self.welch[0], "p": self.welch[1]} if self.welch else None,
                "bootstrap_ci": list(self.bootstrap_ci) if self.bootstrap_ci else None, "note": self.note}


def _rel(before: MetricSummary | None, after: MetricSummary | None) -> float | None:
    if before is None or after is None or before.n == 0 or after.n == 0 or before.mean == 0.0:
        return None
    return (after.mean - before.mean) / before.mean


def _note(row_before: GroupStats | None, row_after: GroupStats | None, welch: tuple[float, float] | None,
          rmse_change: float | None) -> str:
    if row_before is None or row_after is None:
        missing = BEFORE if row_before is None else AFTER
        return f"no {missing} runs"
    parts = []
    if welch is None:
        parts.append("too few successful runs for a test (need ≥ 2 per side)")
    else:
        t, p = welch
        direction = "lower" if (rmse_change or 0.0) < 0 else "higher"
        if p < ALPHA:
            parts.append(f"RMSE {direction} after, significant (Welch p = {p:.3g})")
        else:
            parts.append(f"difference not significant (Welch p = {p:.3g})")
    failed = row_before.n_failed + row_after.n_failed
    if failed:
        parts.append(f"{failed} failed run(s) excluded from the means")
    return "; ".join(parts)


def compare_groups(groups: Sequence[GroupStats], before: str = BEFORE, after: str = AFTER,
                   bootstrap_seed: int = 0) -> list[ComparisonRow]:
    """The before/after rows, one per sequence that has runs of ``before`` or ``after`` (sorted by sequence)."""
    by_key = {(g.sequence, g.variant): g for g in groups}
    sequences = sorted({g.sequence for g in groups if g.variant in (before, after)})
    rows = []
    for seq in sequences:
        gb, ga = by_key.get((seq, before)), by_key.get((seq, after))
        rb = gb.metrics.get("ate_rmse_m") if gb else None
        ra = ga.metrics.get("ate_rmse_m") if ga else None
        mb = gb.metrics.get("ate_mean_m") if gb else None
        ma = ga.metrics.get("ate_mean_m") if ga else None
        welch = welch_test(rb.values, ra.values) if rb and ra else None
        ci = bootstrap_relative_change(rb.values, ra.values, seed=bootstrap_seed) if rb and ra else None
        rmse_change = _rel(rb, ra)
        rows.append(ComparisonRow(seq, gb, ga, _rel(mb, ma), rmse_change, welch, ci,
                                  _note(gb, ga, welch, rmse_change)))
    return rows


def fmt_pm(s: MetricSummary | None, digits: int = 3) -> str:
    """``mean ± std`` (``mean`` alone for one run, ``–`` for none).

    The mean has ``digits`` decimals; the std has at least two significant digits (up to 6 decimals), so that a
    spread of a few tenths of a millimetre over five runs does not print as ``± 0.000``.
    """
    if s is None or s.n == 0:
        return "–"
    if s.n == 1 or not math.isfinite(s.std):
        return f"{s.mean:.{digits}f}"
    # a spread that rounds to 0 at 6 decimals (identical runs whose mean is inexact in binary, std ≈ 1e-17) is 0
    std_digits = digits if s.std < 5e-7 else min(6, max(digits, 1 - math.floor(math.log10(s.std))))
    return f"{s.mean:.{digits}f} ± {s.std:.{std_digits}f}"


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{x * 100:+.1f} %"


def _runs(g: GroupStats | None) -> str:
    if g is None:
        return "0"
    return f"{g.n_ok}/{g.n_runs}" + (f" (**{g.n_failed} failed**)" if g.n_failed else "")


def _md_escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


Table = tuple[list[str], list[list[str]]]


def markdown_table(table: Table) -> str:
    """A pipe table from ``(header, rows)``; cells may hold ``**bold**``; pipes in cells are escaped."""
    header, body = table
    lines = ["| " + " | ".join(_md_escape(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md_escape(c) for c in row) + " |" for row in body]
    return "\n".join(lines) + "\n"


def table2(rows: Sequence[ComparisonRow]) -> Table:
    """The before/after table, one row per sequence; metres; mean ± std over successful runs."""
    header = ["Sequence", "runs before", "ATE (m) before", "RMSE (m) before", "runs after", "ATE (m) after",
              "RMSE (m) after", "ΔATE", "ΔRMSE", "ΔRMSE 95 % CI", "significance"]
    body = []
    for r in rows:
        gb, ga = r.before, r.after
        ci = "–" if r.bootstrap_ci is None else f"[{r.bootstrap_ci[0] * 100:+.1f} %, {r.bootstrap_ci[1] * 100:+.1f} %]"
        body.append([r.sequence, _runs(gb), fmt_pm(gb.metrics.get("ate_mean_m") if gb else None),
                     fmt_pm(gb.metrics.get("ate_rmse_m") if gb else None), _runs(ga),
                     fmt_pm(ga.metrics.get("ate_mean_m") if ga else None),
                     fmt_pm(ga.metrics.get("ate_rmse_m") if ga else None), _pct(r.ate_change), _pct(r.rmse_change),
                     ci, r.note])
    return header, body


def variants_table(groups: Sequence[GroupStats]) -> Table:
    """Every sequence × variant: runs ok/total, failed runs, ATE mean and RMSE (mean ± std, min–max), ATE RMSE as a
    percentage of the distance driven (mean over runs), reasons."""
    header = ["Sequence", "Variant", "runs ok/total", "failed", "ATE mean (m)", "ATE RMSE (m)", "RMSE min–max (m)",
              "ATE RMSE (% of distance)", "failure reasons"]
    body = []
    for g in groups:
        r = g.metrics.get("ate_rmse_m")
        span = "–" if r is None or r.n == 0 else f"{r.min:.3f}–{r.max:.3f}"
        reasons = "; ".join(f"seed {s}: {reason[:160]}" for s, reason in g.failures) or "–"
        failed = f"**{g.n_failed}**" if g.n_failed else "0"
        pct = g.metrics.get("ate_rmse_pct_distance")
        pct_s = "–" if pct is None or pct.n == 0 else f"{pct.mean:.2f} %"
        body.append([g.sequence, g.variant, f"{g.n_ok}/{g.n_runs}", failed, fmt_pm(g.metrics.get("ate_mean_m")),
                     fmt_pm(r), span, pct_s, reasons])
    return header, body


def table2_markdown(rows: Sequence[ComparisonRow]) -> str:
    """:func:`table2` as Markdown."""
    return markdown_table(table2(rows))


def variants_markdown(groups: Sequence[GroupStats]) -> str:
    """:func:`variants_table` as Markdown."""
    return markdown_table(variants_table(groups))
