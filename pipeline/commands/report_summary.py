"""What every command that writes a comparison report prints about it (compare, run-sequence, batch, demo)."""

from __future__ import annotations

from pipeline.report_stage import Comparison


def print_comparison(comp: Comparison) -> None:
    """The one-screen summary of a written report: counts, notes, the tables and where the files are."""
    n_failed = sum(1 for _, r in comp.records if not r.ok)
    print(f"{len(comp.records)} run record(s) ({n_failed} failed) in {len(comp.report.groups)} sequence×variant "
          f"group(s)")
    for line in comp.notes:
        print(f"note: {line}")
    print()
    print(comp.tables)
    print()
    print(f"wrote {comp.out / 'report.md'}, {comp.out / 'report.html'}, {comp.out / 'summary.json'}, "
          f"{len(comp.report.figures)} figure(s)")
