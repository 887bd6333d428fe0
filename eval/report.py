"""The comparison report: Markdown (figures as files) and a self-contained HTML page (figures embedded as base64
PNG), built from run records, optional evaluated trajectories and an optional inpainting benchmark table.

Nothing here touches the file system: :func:`build_report` returns a :class:`Report` whose ``markdown()``,
``html()``, ``summary()`` and ``figures`` the pipeline writes (atomically).
"""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from eval.compare import AFTER, BEFORE, ComparisonRow, Table, compare_groups, markdown_table, table2, variants_table
from eval.evaluate import Evaluation
from eval.instrument import instrument_table
from eval.plots import plot_ate_boxplot, plot_error_over_time, plot_rpe_vs_distance, plot_top_view
from eval.records import RunRecord
from eval.rpe_table import rpe_items, rpe_table
from eval.statistics import GroupStats, summarize, variant_sort_key
from eval.turns import find_turns

__all__ = ["Figure", "Report", "build_report", "rpe_series", "markdown_to_html"]

def metric_note(after: str = AFTER) -> str:
    """The note under Table 2; ``after`` is the inpainted variant compared (the paper's method by default)."""
    which = "the paper's method" if after == AFTER else f"inpainting method `{after[len(AFTER) + 1:-1]}`"
    return (
        "ATE = mean translational error after alignment, RMSE = root mean square of the same errors (metres), each "
        "averaged over the successful runs (mean ± sample std). Δ = relative change of the mean, after vs before "
        f"(negative = lower error after inpainting). Before = `{BEFORE}`, after = `{after}` ({which}). "
        "Significance: Welch's t-test on per-run RMSE (α = 0.05) and a seeded 95 % percentile-bootstrap CI of "
        "ΔRMSE. Failed runs are counted in the run columns and excluded from the means.")


METRIC_NOTE = metric_note()
LADDER_TITLE = "Is the instrument sound? The depth oracle ladder (simulated sequences)"
RPE_NOTE = ("RPE = translation RMSE of the relative pose error over segments of that travelled distance (pairs on "
            "the ground truth's path; mean ± sample std over the successful runs, metres), in brackets the mean drift "
            "(error / distance, %). Only distances up to ¾ of a sequence's path are evaluated.")


@dataclass(frozen=True)
class Figure:
    """One report figure: ``name`` (file stem), caption and PNG bytes."""

    name: str
    caption: str
    png: bytes


@dataclass(frozen=True)
class Report:
    """A built report. ``sections`` are extra Markdown blocks (title, text) appended at the end."""

    title: str
    groups: list[GroupStats]
    rows: list[ComparisonRow]
    figures: list[Figure]
    inpaint_bench_md: str | None = None
    notes: tuple[str, ...] = ()
    code_versions: tuple[str, ...] = ()
    sections: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    after_variant: str = AFTER
    #: The depth oracle ladder (Markdown), shown right after Table 2: whether the instrument behind it is sound.
    ladder_md: str | None = None

    # ---- tables -------------------------------------------------------------------------------------------------
    def _tables(self) -> tuple[Table, Table]:
        return table2(self.rows), variants_table(self.groups)

    def summary(self) -> dict:
        """JSON-able summary: the groups' statistics and the before/after rows."""
        return {"title": self.title, "groups": [g.to_dict() for g in self.groups],
                "comparison": [r.to_dict() for r in self.rows], "code_versions": list(self.code_versions),
                "figures": [f.name + ".png" for f in self.figures]}

    # ---- Markdown -----------------------------------------------------------------------------------------------
    def markdown(self, figure_dir: str = "figures") -> str:
        """The report as Markdown; figures referenced as ``<figure_dir>/<name>.png``."""
        t2, tv = self._tables()
        out = [f"# {self.title}", ""]
        out += [f"Code version(s): {', '.join(f'`{v}`' for v in self.code_versions)}", ""] if self.code_versions else []
        out += ["## Before / after depth inpainting (paper Table 2 layout)", ""]
        out += [markdown_table(t2) if self.rows else "_No `depth-raw` / `depth-inpainted` runs found._\n", "",
                metric_note(self.after_variant), ""]
        if self.ladder_md:
            out += [f"## {LADDER_TITLE}", "", self.ladder_md.strip(), ""]
        out += ["## All variants (five-run statistics)", "", markdown_table(tv), ""]
        for note in self.notes:
            out += [f"> {note}", ""]
        if self.figures:
            out += ["## Figures", ""]
            for f in self.figures:
                out += [f"![{f.caption}]({figure_dir}/{f.name}.png)", "", f"*{f.caption}*", ""]
        if self.inpaint_bench_md:
            out += ["## Inpainting benchmark", "", self.inpaint_bench_md.strip(), ""]
        for title, body in self.sections:
            out += [f"## {title}", "", body.strip(), ""]
        return "\n".join(out).rstrip() + "\n"

    # ---- HTML ---------------------------------------------------------------------------------------------------
    def html(self) -> str:
        """A self-contained HTML page (inline CSS, figures as base64 PNG data URIs, no external resources)."""
        t2, tv = self._tables()
        parts = [f"<h1>{html.escape(self.title)}</h1>"]
        if self.code_versions:
            parts.append("<p class='meta'>Code version(s): " + ", ".join(
                f"<code>{html.escape(v)}</code>" for v in self.code_versions) + "</p>")
        parts.append("<h2>Before / after depth inpainting (paper Table 2 layout)</h2>")
        parts.append(_html_table(t2, failed_col=None) if self.rows else
                     "<p><em>No <code>depth-raw</code> / <code>depth-inpainted</code> runs found.</em></p>")
        parts.append(f"<p class='note'>{_inline(metric_note(self.after_variant))}</p>")
        if self.ladder_md:
            parts.append(f"<h2>{html.escape(LADDER_TITLE)}</h2>")
            parts.append(markdown_to_html(self.ladder_md))
        parts.append("<h2>All variants (five-run statistics)</h2>")
        parts.append(_html_table(tv, failed_col=3))
        for note in self.notes:
            parts.append(f"<blockquote>{_inline(note)}</blockquote>")
        if self.figures:
            parts.append("<h2>Figures</h2><div class='figs'>")
            for f in self.figures:
                data = base64.b64encode(f.png).decode("ascii")
                parts.append(f"<figure><img alt='{html.escape(f.caption, quote=True)}' "
                             f"src='data:image/png;base64,{data}'><figcaption>{html.escape(f.caption)}"
                             f"</figcaption></figure>")
            parts.append("</div>")
        if self.inpaint_bench_md:
            parts.append("<h2>Inpainting benchmark</h2>")
            parts.append(markdown_to_html(self.inpaint_bench_md))
        for title, body in self.sections:
            parts.append(f"<h2>{html.escape(title)}</h2>")
            parts.append(markdown_to_html(body))
        body = "\n".join(parts)
        return (f"<!DOCTYPE html>\n<html lang='en'>\n<head>\n<meta charset='utf-8'>\n"
                f"<meta name='viewport' content='width=device-width, initial-scale=1'>\n"
                f"<title>{html.escape(self.title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n{body}\n"
                f"</body>\n</html>\n")


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif;margin:24px auto;max-width:1280px;
color:#222;padding:0 16px;line-height:1.4}
h1{font-size:1.6em;border-bottom:2px solid #444;padding-bottom:4px}h2{font-size:1.25em;margin-top:1.6em}
table{border-collapse:collapse;font-size:13px;margin:8px 0}th,td{border:1px solid #bbb;padding:4px 8px;text-align:left;
vertical-align:top}th{background:#eef1f5}tr:nth-child(even) td{background:#fafafa}
td.failed{background:#fde2e2 !important;color:#a00;font-weight:bold}
.note{font-size:12px;color:#555;max-width:1000px}.meta{color:#666;font-size:12px}
.figs{display:flex;flex-wrap:wrap;gap:16px}figure{margin:0;border:1px solid #ddd;padding:6px;background:#fff}
figure img{max-width:600px;width:100%;height:auto;display:block}figcaption{font-size:12px;color:#444;max-width:600px}
code{background:#f3f3f3;padding:0 3px}blockquote{border-left:4px solid #e0a800;margin:8px 0;padding:4px 10px;
background:#fff8e1}pre{background:#f6f6f6;padding:8px;overflow:auto}
"""


def _inline(text: str) -> str:
    """Escape HTML, then ``**bold**`` → <strong>, ```code``` → <code>."""
    s = html.escape(text)
    s = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", s)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", s)


def _html_table(table: Table, failed_col: int | None) -> str:
    header, body = table
    rows = ["<tr>" + "".join(f"<th>{_inline(h)}</th>" for h in header) + "</tr>"]
    for row in body:
        cells = []
        for i, c in enumerate(row):
            cls = " class='failed'" if failed_col is not None and i == failed_col and c.strip("*") not in ("0", "") \
                else ""
            if failed_col is None and "failed" in c and i in (1, 4):
                cls = " class='failed'"
            cells.append(f"<td{cls}>{_inline(c)}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return "<table>\n" + "\n".join(rows) + "\n</table>"


def markdown_to_html(md: str) -> str:
    """Minimal Markdown → HTML for embedded tables: pipe tables, ``#`` headings, ``- `` bullet lists, paragraphs,
    fenced code."""
    out: list[str] = []
    lines = md.replace("\r\n", "\n").split("\n")
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if stripped.startswith("```"):
            j = i + 1
            while j < len(lines) and not lines[j].strip().startswith("```"):
                j += 1
            out.append("<pre>" + html.escape("\n".join(lines[i + 1:j])) + "</pre>")
            i = j + 1
            continue
        if stripped.startswith("|"):
            j = i
            block = []
            while j < len(lines) and lines[j].strip().startswith("|"):
                block.append(lines[j].strip())
                j += 1
            out.append(_pipe_table_html(block))
            i = j
            continue
        if stripped.startswith("- "):
            j = i
            items = []
            while j < len(lines) and lines[j].strip().startswith("- "):
                items.append(f"<li>{_inline(lines[j].strip()[2:])}</li>")
                j += 1
            out.append("<ul>" + "".join(items) + "</ul>")
            i = j
            continue
        m = re.match(r"^(#{1,6})\s+(.*)$", stripped)
        if m:
            level = min(6, len(m.group(1)) + 2)
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
        elif stripped:
            out.append(f"<p>{_inline(stripped)}</p>")
        i += 1
    return "\n".join(out)


def _split_row(line: str) -> list[str]:
    cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))
    return [c.strip().replace("\\|", "|") for c in cells]


def _pipe_table_html(block: list[str]) -> str:
    rows = [_split_row(b) for b in block]
    is_sep = [all(re.fullmatch(r":?-{2,}:?", c) for c in r if c) and any(r) for r in rows]
    if len(rows) >= 2 and is_sep[1]:
        header, body = rows[0], [r for r, s in zip(rows[2:], is_sep[2:]) if not s]
    else:
        header, body = [], [r for r, s in zip(rows, is_sep) if not s]
    return _html_table((header, body), failed_col=None) if header else \
        "<table>\n" + "\n".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body) + \
        "\n</table>"


def rpe_series(records: Sequence[RunRecord], sequence: str) -> dict[str, tuple[list[float], list[float], list[float]]]:
    """Per variant of ``sequence``: RPE translation RMSE vs segment length, mean and sample std over ok runs."""
    per: dict[str, dict[float, list[float]]] = {}
    for r in records:
        if r.sequence != sequence or not r.ok:
            continue
        for d, item in rpe_items(r).items():
            v = item.get("trans_rmse_m")
            if isinstance(v, (int, float)) and math.isfinite(v):
                per.setdefault(r.display_variant(), {}).setdefault(d, []).append(float(v))
    out = {}
    for variant in sorted(per, key=variant_sort_key):
        ds = sorted(per[variant])
        vals = [np.asarray(per[variant][d]) for d in ds]
        out[variant] = (ds, [float(v.mean()) for v in vals],
                        [float(v.std(ddof=1)) if v.size > 1 else float("nan") for v in vals])
    return out


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "x"


def build_report(records: Sequence[RunRecord],
                 evaluations: Mapping[tuple[str, str], Evaluation] | None = None,
                 inpaint_bench_md: str | None = None, title: str = "agrivio: depth inpainting vs VIO accuracy",
                 notes: Sequence[str] = (), sections: Sequence[tuple[str, str]] = (),
                 after: str | None = None, ladder_md: str | None = None) -> Report:
    """Statistics, the before/after comparison and the figures.

    Args:
        records: every run (ok and failed).
        evaluations: (sequence, displayed variant) → the evaluation of one representative run, for the
            top-view and error-over-time figures (optional; without it only box plots and RPE are drawn).
        inpaint_bench_md: the inpainting benchmark table (Markdown), embedded as is.
        notes: lines shown as call-outs (e.g. records that could not be read).
        after: the displayed variant compared with ``depth-raw`` in Table 2 (e.g. ``depth-inpainted[telea]``);
            default: the paper's method when it ran, else the first other inpainting method (alphabetical).
        ladder_md: the depth oracle ladder (Markdown, e.g. ``pipeline.oracle_stage``'s), shown after Table 2.
    """
    groups = summarize(records)
    # "After" is the paper's method when it ran; otherwise the one other inpainting method that ran (if any).
    inpainted = sorted({g.variant for g in groups if g.base_variant == AFTER})
    if after is None or after not in inpainted:
        after = AFTER if AFTER in inpainted else next(iter(inpainted), AFTER)
    rows = compare_groups(groups, after=after)
    evaluations = evaluations or {}
    figures: list[Figure] = []
    for seq in sorted({g.sequence for g in groups}):
        seq_groups = [g for g in groups if g.sequence == seq]
        values = {g.variant: g.metrics["ate_rmse_m"].values for g in seq_groups}
        failed = {g.variant: g.n_failed for g in seq_groups}
        figures.append(Figure(f"{_slug(seq)}_ate_box", f"{seq}: ATE RMSE per run and variant (failed runs counted "
                              f"under each box)", plot_ate_boxplot(values, failed, title=f"{seq}: ATE RMSE over runs")))
        evs = {v: e for (s, v), e in sorted(evaluations.items(), key=lambda kv: variant_sort_key(kv[0][1]))
               if s == seq}
        if evs:
            reference = next(iter(evs.values())).ref
            figures.append(Figure(f"{_slug(seq)}_top_view", f"{seq}: top view of one run per variant, aligned to "
                                  f"ground truth", plot_top_view(reference, {v: e.est_aligned for v, e in evs.items()},
                                                                 title=f"{seq}: top view (aligned)")))
            turns = find_turns(reference)
            turn_note = f"; {len(turns)} turn(s) of the ground truth shaded" if turns else ""
            figures.append(Figure(f"{_slug(seq)}_error_time", f"{seq}: translational error over time (one run per "
                                  f"variant{turn_note})",
                                  plot_error_over_time({v: (e.ate.stamps_s, e.ate.errors_m) for v, e in evs.items()},
                                                       title=f"{seq}: ATE over time",
                                                       spans=[(t.start_s, t.end_s) for t in turns],
                                                       t0_s=float(reference.stamps_s[0]))))
        series = rpe_series(records, seq)
        if series:
            figures.append(Figure(f"{_slug(seq)}_rpe", f"{seq}: RPE translation RMSE vs travelled distance (mean ± "
                                  f"std over runs)", plot_rpe_vs_distance(series, title=f"{seq}: RPE vs distance")))
    versions = tuple(sorted({r.code_version for r in records if r.code_version}))
    long_rpe = rpe_table(records)
    if long_rpe:
        sections = [*sections, ("Relative pose error over distance", markdown_table(long_rpe) + "\n\n" + RPE_NOTE)]
    instrument = instrument_table(records)
    if instrument:
        sections = [*sections, ("Depth given to the filter and its χ² gate", instrument)]
    return Report(title, groups, rows, figures, inpaint_bench_md, tuple(notes), versions, tuple(sections), after,
                  ladder_md)
