"""The report's "depth given to the filter and χ² gate" table: per sequence × variant, medians over runs of what
each run record states about the depth its features carried (measured vs filled, stated σ_Z/Z) and about the
filter's χ² gate (γ/dof, and the χ² noise scale c of :mod:`eval.gate_calibration`, which is 1 when the residual
covariance the filter states is right whatever the features' degrees of freedom — the median γ/dof of a calibrated
gate is 0.79 at dof 3; rejected fraction) and about its zero-velocity updates (how many images, the last one's
time).

Reads only the records' ``feature_depth``, ``chi2_gate`` and ``zero_velocity`` entries (written by the pipeline's
run stage); runs without them are skipped, so the table is absent for old records. The caption names the depth
gate's scale allowance the runs used (``input_key_parts.msckf.gate_depth_scale``), not a default that may have
changed since.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from eval.records import RunRecord
from eval.statistics import variant_sort_key

__all__ = ["instrument_table"]

_COLUMNS = (("feature_depth", "filled_fraction", "filled share of feature depths", "{:.0%}"),
            ("feature_depth", "sigma_rel_median_measured", "σ_Z/Z measured", "{:.1%}"),
            ("feature_depth", "sigma_rel_median_filled", "σ_Z/Z filled", "{:.1%}"),
            ("feature_depth", "far_open_fill_fraction", "fill pixels open to the far field", "{:.0%}"),
            ("feature_depth", "occlusion_edge_fill_fraction", "fill pixels at occlusion edges", "{:.0%}"),
            ("chi2_gate", "gamma_per_dof_median", "γ/dof median", "{:.3f}"),
            ("chi2_gate", "gamma_per_dof_mean", "γ/dof mean", "{:.2f}"),
            ("chi2_gate", "chi2_noise_scale", "χ² noise scale c (1 = calibrated)", "{:.2f}"),
            ("chi2_gate", "rejected_fraction", "gate rejected", "{:.1%}"),
            ("zero_velocity", "frames", "zero-velocity updates (images)", "{:.0f}"),
            ("zero_velocity", "last_s", "last zero-velocity update (s)", "{:.1f}"))


def instrument_table(records: Sequence[RunRecord]) -> str | None:
    """Markdown table (medians over the successful runs of each sequence × variant), or None when no record
    carries the statistics."""
    values: dict[tuple[str, str], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    scales: set[float] = set()
    for rec in records:
        if rec.status != "ok":
            continue
        scale = ((rec.extra.get("input_key_parts") or {}).get("msckf") or {}).get("gate_depth_scale")
        if isinstance(scale, (int, float)):
            scales.add(float(scale))
        for section, key, _, _ in _COLUMNS:
            v = (rec.extra.get(section) or {}).get(key)
            if isinstance(v, (int, float)) and np.isfinite(v):
                values[(rec.sequence, rec.display_variant())][key].append(float(v))
    if not values:
        return None
    scale_note = ("`gate_depth_scale` " + ", ".join(f"{v:.0%}" for v in sorted(scales)) + " in these runs"
                  if scales else "`gate_depth_scale`")
    head = "| sequence | variant | runs | " + " | ".join(c[2] for c in _COLUMNS) + " |"
    lines = [head, "|" + "---|" * (3 + len(_COLUMNS))]
    for (seq, var) in sorted(values, key=lambda sv: (sv[0], variant_sort_key(sv[1]))):
        vals = values[(seq, var)]
        n = max((len(v) for v in vals.values()), default=0)
        cells = [fmt.format(float(np.median(vals[key]))) if vals.get(key) else "–" for _, key, _, fmt in _COLUMNS]
        lines.append(f"| {seq} | {var} | {n} | " + " | ".join(cells) + " |")
    return ("Per sequence and variant, medians over runs. *Filled share*: feature depths read from inpainted "
            "pixels (raw SGBM hole). *Fill pixels open to the far field*: inpainted pixels given no depth because "
            "their hole reaches a measurement stereo cannot tell from infinity (pipeline/depth_sigma.py, `far_open`); "
            "*at occlusion edges*: the other fills dropped by the occlusion-edge rule (`occlusion_edge`: measured "
            "disparities in the tracker's window further apart than SGBM's noise explains). "
            "*σ_Z/Z*: the depth uncertainty the filter was given (pipeline/depth_sigma.py). "
            "*γ/dof*: the χ² statistic per degree of freedom of every gated feature (its mean is ≈ 1 for a "
            "calibrated gate, its median the χ² median: 0.79 at 3 dof, where most depth features sit). *χ² noise "
            "scale c*: the factor the filter's residual covariance would need for the statistics to sit at their χ² "
            "medians, whatever their dof; 1 = calibrated, below 1 = the filter states more uncertainty than its "
            "residuals show (eval/gate_calibration.py). "
            "Both front ends gate their pixels with σ ≈ 0.18 px (`gate_noise`, `stereo_gate_noise`); the depth front "
            f"end's gate also allows one scale error shared by a feature's depth readings ({scale_note}), "
            "and its c stays near 0.3 (the filter's own covariance dominates, half of it from its IMU noise; see "
            "the README). "
            "*Zero-velocity updates*: images that got one (the robot standing at the start: `zupt_max_flow`, "
            "`zupt_only_at_start`) and the last of them, in seconds after the run's first image.\n\n"
            + "\n".join(lines))
