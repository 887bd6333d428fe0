"""The long-sequence table: relative pose error at fixed travelled distances (10 / 50 / 100 m), per sequence and
variant, over the successful runs of each group.

The ATE of a long sequence is decided by drift; the RPE over a distance Δ says how much the estimate drifts over
Δ metres of path, wherever it starts (pairs on the reference's travelled distance, :func:`eval.metrics.rpe`), and
its drift percentage (error / Δ · 100) compares sequences of different lengths.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from eval.compare import Table
from eval.metrics import DEFAULT_RPE_DISTANCES_M
from eval.records import RunRecord
from eval.statistics import variant_sort_key

__all__ = ["rpe_items", "rpe_table"]


def rpe_items(record: RunRecord) -> dict[float, Mapping]:
    """The record's RPE entries by segment length (m); entries without a numeric ``delta_m`` are skipped."""
    rpe = record.metrics.get("rpe")
    if not isinstance(rpe, Mapping):
        return {}
    out = {}
    for item in rpe.values():
        if isinstance(item, Mapping) and isinstance(item.get("delta_m"), (int, float)):
            out[float(item["delta_m"])] = item
    return out


def _finite(values: Sequence[object]) -> np.ndarray:
    return np.asarray([float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)])


def _cell(rmse: np.ndarray, drift: np.ndarray) -> str:
    if not rmse.size:
        return "–"
    std = f" ± {rmse.std(ddof=1):.3f}" if rmse.size > 1 else ""
    pct = f" ({drift.mean():.2f} %)" if drift.size else ""
    return f"{rmse.mean():.3f}{std}{pct}"


def rpe_table(records: Sequence[RunRecord], distances_m: Sequence[float] = DEFAULT_RPE_DISTANCES_M
              ) -> Table | None:
    """Sequence × variant rows: ok runs, mean path length (m), then per distance the RPE translation RMSE (m,
    mean ± sample std over runs) with the mean drift (% of distance). None when no run has any of ``distances_m``
    (short clips: their RPE is at fractions of the path, in the RPE figure)."""
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for r in records:
        if r.ok:
            groups.setdefault((r.sequence, r.display_variant()), []).append(r)
    present = sorted({d for rs in groups.values() for r in rs for d in rpe_items(r)} & set(map(float, distances_m)))
    if not present:
        return None
    header = ["Sequence", "Variant", "runs", "path (m)"] + [f"RPE {d:g} m (m, drift %)" for d in present]
    body = []
    for seq, variant in sorted(groups, key=lambda k: (k[0], variant_sort_key(k[1]))):
        rs = groups[(seq, variant)]
        path = _finite([r.metrics.get("ref_path_length_m") for r in rs])
        row = [seq, variant, str(len(rs)), f"{path.mean():.0f}" if path.size else "–"]
        for d in present:
            items = [i for i in (rpe_items(r).get(d) for r in rs) if i is not None]
            row.append(_cell(_finite([i.get("trans_rmse_m") for i in items]),
                             _finite([i.get("drift_mean_pct") for i in items])))
        body.append(row)
    return header, body
