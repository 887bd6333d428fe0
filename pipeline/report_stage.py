"""The report stage: find the run records of a folder, collapse duplicates, add external estimates, evaluate one
representative run per group for the trajectory figures, build the report (:func:`eval.report.build_report`) and
write it (``report.md``, ``report.html``, ``summary.json``, ``figures/``). Returns objects; the commands print.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from eval.errors import EvalInputError
from eval.evaluate import EvalOptions, Evaluation, evaluate
from eval.records import RunRecord, is_run_record, variant_display_name
from eval.report import Report, build_report
from eval.trajectory import read_tum
from eval.variants import DEPTH_INPAINTED, ODOMETRY
from pipeline.atomic import atomic_path, write_json_atomic, write_text_atomic
from pipeline.errors import AgrivioError
from pipeline.external_tracks import evaluate_external, external_record, load_external
from pipeline.oracle_stage import read_ladder_markdown
from pipeline.run_identity import collapse_duplicates, inputs_section

BENCH_NAMES = ("inpaint_bench.md", "inpaint_bench.json")
DEFAULT_TITLE = "agrivio: does depth inpainting make the MSCKF VIO more accurate?"


def find_records(runs_dir: Path, exclude: Path | None = None) -> tuple[list[tuple[Path, RunRecord]], list[str]]:
    """All run records under ``runs_dir`` (sorted by path) and notes about files that could not be used."""
    records: list[tuple[Path, RunRecord]] = []
    notes: list[str] = []
    exclude_r = exclude.resolve() if exclude is not None else None
    for path in sorted(runs_dir.rglob("*.json")):
        if exclude_r is not None and exclude_r in path.resolve().parents:
            continue
        if path.name.startswith("."):  # temporary files of atomic writes
            continue
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            if "record" in path.name:
                notes.append(f"{path}: unreadable record ({type(exc).__name__}) — not counted")
            continue
        if not is_run_record(data):
            continue
        try:
            records.append((path, RunRecord.from_dict(data, source=str(path))))
        except EvalInputError as exc:
            notes.append(f"{exc} — not counted")
    return records, notes


def _resolve(base: Path, p: str) -> Path:
    q = Path(p)
    return q if q.is_absolute() else base / q


def _representative(items: Sequence[tuple[Path, RunRecord]]) -> tuple[Path, RunRecord] | None:
    """The ok run whose ATE RMSE is the median of its group (lower median; ties by seed)."""
    ok = [(p, r) for p, r in items if r.ok and r.estimate_path and r.gt_path and r.metric("ate_rmse_m") is not None]
    if not ok:
        return None
    ok.sort(key=lambda pr: (pr[1].metric("ate_rmse_m"), pr[1].seed))
    return ok[(len(ok) - 1) // 2]


def options_for(rec: RunRecord) -> EvalOptions:
    """The evaluation options a run record was evaluated with (so plots and replays match its metrics)."""
    opts = rec.extra.get("eval_options")
    if isinstance(opts, dict):
        return EvalOptions.from_dict(opts)
    if isinstance(rec.metrics.get("align"), str):
        return EvalOptions(align=rec.metrics["align"])
    return EvalOptions()


def external_records(specs: Sequence[str], found: Sequence[tuple[Path, RunRecord]]
                     ) -> tuple[list[tuple[Path, RunRecord]], list[str]]:
    """Evaluate each ``--external`` spec like the VIO runs of its sequence; records (keyed by the TUM path) and
    one note per external estimate. AgrivioError (one line) for a bad spec, file or sequence."""
    tracks = load_external(specs)
    if not tracks:
        return [], []
    sequences = sorted({r.sequence for _, r in found})
    out: list[tuple[Path, RunRecord]] = []
    notes: list[str] = []
    for track in tracks:
        seq = track.sequence
        if seq is None:
            if len(sequences) != 1:
                raise AgrivioError(f"--external {track.name}: the runs hold {len(sequences)} sequences "
                                   f"({', '.join(sequences)}); name one: {track.name}@SEQUENCE={track.path}")
            seq = sequences[0]
        # the template: an ok VIO run of the sequence with its GT (the same association, alignment, lever arm)
        candidates = [(p, r) for p, r in found if r.sequence == seq and r.ok and r.gt_path]
        vio = [(p, r) for p, r in candidates if r.variant != ODOMETRY]
        if not (vio or candidates):
            raise AgrivioError(f"--external {track.name}: no successful run of sequence {seq!r} with a ground truth "
                               f"to evaluate it against (sequences: {', '.join(sequences)})")
        path, template = (vio or candidates)[0]
        gt_path = _resolve(path.parent, template.gt_path or "")
        try:
            ref = read_tum(gt_path)
        except EvalInputError as exc:
            raise AgrivioError(str(exc)) from None
        opts = options_for(template)
        if template.variant == ODOMETRY:
            raise AgrivioError(f"--external {track.name}: sequence {seq!r} has only odometry runs; their lever arm "
                               f"(base_link) does not apply to an IMU-frame estimate")
        evaluation = evaluate_external(track, ref, opts)
        rec = external_record(track, seq, str(gt_path.resolve()), evaluation)
        out.append((track.path, rec))
        notes.append(f"`{track.label}` is an external estimate ({track.path}), evaluated like the `{template.variant}` "
                     f"runs of {seq}: {opts.align} alignment, {opts.max_diff_s * 1000:g} ms association"
                     + (", lever arm applied" if opts.lever_arm_m is not None else "") +
                     f"; ATE RMSE {evaluation.ate.trans.rmse:.3f} m over {len(evaluation.association)} pairs.")
    return out, notes


def load_evaluations(records: Sequence[tuple[Path, RunRecord]]) -> tuple[dict[tuple[str, str], Evaluation], list[str]]:
    """Evaluate one representative run per (sequence, variant) from its TUM files."""
    groups: dict[tuple[str, str], list[tuple[Path, RunRecord]]] = {}
    for path, rec in records:
        groups.setdefault((rec.sequence, rec.display_variant()), []).append((path, rec))
    evaluations: dict[tuple[str, str], Evaluation] = {}
    notes: list[str] = []
    chosen = [(key, _representative(items)) for key, items in sorted(groups.items())]
    chosen = [(key, pr) for key, pr in chosen if pr is not None]
    for key, (path, rec) in tqdm(chosen, desc="trajectories", unit="run", disable=len(chosen) < 2):
        est_path = _resolve(path.parent, rec.estimate_path or "")
        gt_path = _resolve(path.parent, rec.gt_path or "")
        try:
            evaluations[key] = evaluate(read_tum(gt_path), read_tum(est_path), options_for(rec))
        except EvalInputError as exc:
            notes.append(f"{key[0]}/{key[1]} seed {rec.seed}: trajectory plot skipped: {exc}")
    return evaluations, notes


def _bench_markdown(runs_dir: Path) -> str | None:
    for name in BENCH_NAMES:
        hits = sorted(runs_dir.rglob(name))
        if not hits:
            continue
        text = hits[0].read_text(encoding="utf-8")
        if name.endswith(".md"):
            return text
        try:
            data = json.loads(text)
        except json.JSONDecodeError:
            return f"_{hits[0]} is not valid JSON_"
        if isinstance(data, dict) and isinstance(data.get("markdown"), str):
            return data["markdown"]
        rows = data if isinstance(data, list) else data.get("rows") if isinstance(data, dict) else None
        if isinstance(rows, list) and rows and all(isinstance(r, dict) for r in rows):
            keys = list(dict.fromkeys(k for r in rows for k in r))
            lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
            for r in rows:
                lines.append("| " + " | ".join(_cell(r.get(k)) for k in keys) + " |")
            return "\n".join(lines)
        return "```\n" + json.dumps(data, indent=2)[:20000] + "\n```"
    return None


def _cell(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v).replace("|", "\\|")


@dataclass(frozen=True)
class Comparison:
    """A written comparison report: its folder, the built report, the records it counts and the notes."""

    out: Path
    report: Report
    records: list[tuple[Path, RunRecord]]
    notes: list[str]

    @property
    def tables(self) -> str:
        """The Markdown of the tables (the one-screen summary: everything before the figures)."""
        return self.report.markdown("figures").split("## Figures")[0].rstrip()


def _after_variant(method: str | None) -> str | None:
    """The displayed variant of ``depth-inpainted`` with ``method`` (as :meth:`RunRecord.display_variant`)."""
    return None if method is None else variant_display_name(DEPTH_INPAINTED, method)


def write_comparison_report(runs_dir: Path, out: Path | None = None, title: str = DEFAULT_TITLE,
                            trajectories: bool = True, external: Sequence[str] = (),
                            after_method: str | None = None) -> Comparison:
    """Build the comparison report of every run record under ``runs_dir`` (plus the ``external`` TUM specs,
    ``NAME[@SEQUENCE]=path``) and write ``report.md``, ``report.html``, ``summary.json`` and ``figures/`` into
    ``out`` (default ``runs_dir/report``), each atomically. Duplicate runs are collapsed with a warning on stderr.
    ``after_method``: the inpainting method of Table 2's "after" (default: the paper's when it ran). A depth oracle
    ladder written into ``runs_dir`` (``pipeline.oracle_stage.write_ladder``) is shown beside Table 2.

    Raises:
        AgrivioError: no folder, no run records, a conflicting duplicate, a bad external spec.
    """
    if not runs_dir.is_dir():
        raise AgrivioError(f"{runs_dir}: not a folder of run records")
    out = out if out is not None else runs_dir / "report"
    found, notes = find_records(runs_dir, exclude=out)
    if not found:
        raise AgrivioError(f"{runs_dir}: no run records found (*.json with \"record_type\": \"run\")")
    found, duplicates = collapse_duplicates(found)  # a copied run folder is one run, not two samples
    notes += duplicates
    for line in duplicates:
        print(f"warning: {line}", file=sys.stderr)
    section = inputs_section(found)
    ext, ext_notes = external_records(external, found)
    found = [*found, *ext]
    notes += ext_notes
    evaluations: dict[tuple[str, str], Evaluation] = {}
    if trajectories:
        evaluations, more = load_evaluations(found)
        notes += more
    report = build_report([r for _, r in found], evaluations, _bench_markdown(runs_dir), title=title, notes=notes,
                          sections=[section] if section else [], after=_after_variant(after_method),
                          ladder_md=read_ladder_markdown(runs_dir))
    fig_dir = out / "figures"
    for fig in report.figures:
        with atomic_path(fig_dir / f"{fig.name}.png", suffix=".png") as tmp:
            tmp.write_bytes(fig.png)
    write_text_atomic(out / "report.md", report.markdown("figures"))
    write_text_atomic(out / "report.html", report.html())
    write_json_atomic(out / "summary.json", report.summary())
    return Comparison(out, report, found, notes)
