"""Which run records are the same run: duplicates are collapsed before statistics, conflicts are refused.

A run is identified by (sequence, variant, inpainting method, seed, input key) — the input key
(:mod:`pipeline.run_key`) says which bag, GT, frames, configuration and code made it. Two copies of one run folder
under a runs directory are one run, not two independent samples: counting both would halve the p-values' honesty.

* same identity, same outcome (status, failure reason, metrics): a duplicate — kept once, with a note;
* same identity, different outcome: a conflict — an error naming both files;
* same (sequence, variant, method, seed) but different input keys: runs of different inputs under one name — an
  error naming both files (compare one folder of runs made from the same inputs).

Also builds the report's "Run inputs and data quality" section from the records.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from eval.records import RunRecord
from pipeline.errors import AgrivioError


def _outcome(rec: RunRecord) -> str:
    return json.dumps({"status": rec.status, "failure": rec.failure_reason, "metrics": rec.metrics},
                      sort_keys=True, default=str)


def _short(path: Path) -> str:
    return str(path)


def collapse_duplicates(found: Sequence[tuple[Path, RunRecord]]) -> tuple[list[tuple[Path, RunRecord]], list[str]]:
    """Drop duplicate runs (first path kept); return the unique records and one note per collapsed duplicate.

    Raises:
        AgrivioError: naming both files, for a conflicting duplicate or for one run name with two input keys.
    """
    by_name: dict[tuple[str, str, str | None, int], tuple[Path, RunRecord]] = {}
    kept: list[tuple[Path, RunRecord]] = []
    notes: list[str] = []
    for path, rec in found:
        name = (rec.sequence, rec.variant, rec.inpaint_method, rec.seed)
        label = f"{rec.sequence}/{rec.display_variant()}/seed{rec.seed}"
        if name not in by_name:
            by_name[name] = (path, rec)
            kept.append((path, rec))
            continue
        first_path, first = by_name[name]
        key, first_key = rec.extra.get("input_key"), first.extra.get("input_key")
        if key != first_key:
            raise AgrivioError(f"{label} appears twice with different inputs (input key {first_key} in "
                               f"{_short(first_path)}, {key} in {_short(path)}); compare runs of one set of inputs")
        if _outcome(rec) != _outcome(first):
            raise AgrivioError(f"{label} appears twice with the same inputs but different results: "
                               f"{_short(first_path)} and {_short(path)}")
        notes.append(f"{label}: duplicate record {path} (same run as {first_path}) counted once")
    return kept, notes


def inputs_section(found: Sequence[tuple[Path, RunRecord]]) -> tuple[str, str] | None:
    """The report section listing each sequence × variant's input key(s) and each sequence's data quality."""
    from pipeline.data_quality import summary_lines

    keys: dict[tuple[str, str], set[str]] = {}
    quality: dict[str, dict[str, Any]] = {}
    for _, rec in found:
        key = rec.extra.get("input_key")
        if key:
            keys.setdefault((rec.sequence, rec.display_variant()), set()).add(str(key))
        dq = rec.extra.get("data_quality")
        if isinstance(dq, dict) and rec.sequence not in quality:
            quality[rec.sequence] = dq
    if not keys and not quality:
        return None
    lines: list[str] = []
    for seq in sorted({s for s, _ in keys} | set(quality)):
        lines.append(f"**{seq}**")
        lines.append("")
        for (s, variant), ks in sorted(keys.items()):
            if s == seq:
                lines.append(f"- input key of {variant}: `{', '.join(sorted(ks))}`")
        if seq in quality:
            try:
                lines += [f"- data quality: {line}" for line in summary_lines(quality[seq])]
            except (KeyError, TypeError):
                lines.append("- data quality: (unreadable summary)")
        lines.append("")
    return "Run inputs and data quality", "\n".join(lines).rstrip() + "\n"


__all__ = ["collapse_duplicates", "inputs_section"]
