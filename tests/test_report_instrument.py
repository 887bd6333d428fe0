"""The report's table of the depth the filter was given and of its χ² gate, from the run records."""

from __future__ import annotations

from eval.instrument import instrument_table
from eval.records import RunRecord
from eval.report import build_report


def _rec(variant: str, seed: int, filled: float, gamma: float, status: str = "ok") -> RunRecord:
    return RunRecord("seq", variant, seed, status=status, inpaint_method="telea" if variant == "depth-inpainted"
                     else None, metrics={"ate_rmse_m": 0.02 + 0.001 * seed},
                     extra={"feature_depth": {"filled_fraction": filled, "sigma_rel_median_measured": 0.02,
                                              **({"sigma_rel_median_filled": 0.15,
                                                  "far_open_fill_fraction": 0.25,
                                                  "occlusion_edge_fill_fraction": 0.125} if filled else {})},
                            "chi2_gate": {"gamma_per_dof_median": gamma, "gamma_per_dof_mean": 10 * gamma,
                                          "chi2_noise_scale": 20 * gamma, "rejected_fraction": 0.01},
                            "input_key_parts": {"msckf": {"gate_depth_scale": 0.1 if seed == 1 else 0.03}}})


def test_instrument_table_gives_medians_per_variant_and_skips_failed_runs():
    recs = [_rec("depth-raw", s, 0.0, g) for s, g in enumerate([0.010, 0.012, 0.020])]
    recs += [_rec("depth-inpainted", s, f, 0.015) for s, f in enumerate([0.30, 0.40, 0.50])]
    recs.append(_rec("depth-inpainted", 9, 0.99, 9.0, status="failed"))
    md = instrument_table(recs)
    lines = {ln.split(" | ")[1]: ln for ln in md.splitlines() if ln.startswith("| seq |")}
    assert set(lines) == {"depth-raw", "depth-inpainted[telea]"}
    assert "| 3 | 0% | 2.0% | – | – | – | 0.012 |" in lines["depth-raw"]                 # median γ/dof of 3 runs
    assert "| 0.012 | 0.12 | 0.24 | 1.0% |" in lines["depth-raw"]       # then the mean, the χ² noise scale
    assert "| 3 | 40% | 2.0% | 15.0% | 25% | 12% | 0.015 |" in lines["depth-inpainted[telea]"]  # the failed run is out
    assert instrument_table([RunRecord("seq", "stereo", 0)]) is None
    assert "(`gate_depth_scale` 3%, 10% in these runs)" in md          # what the runs used, not today's default
    assert lines["depth-raw"].endswith("| – | – |")                  # no zero-velocity entry: no value claimed
    stood = [RunRecord("seq", "stereo", s, extra={"zero_velocity": {"frames": n, "last_s": 1.0 + s}})
             for s, n in enumerate([10, 14, 12])]
    assert instrument_table(stood).splitlines()[-1].endswith("| 12 | 2.0 |")   # medians over the runs
    bare = [RunRecord("seq", "depth-raw", 0, extra={"chi2_gate": {"gamma_per_dof_median": 0.2}})]
    assert "(`gate_depth_scale`)," in instrument_table(bare)           # not recorded: no value claimed


def test_report_carries_the_instrument_section_only_when_records_have_it():
    recs = [_rec("depth-raw", s, 0.0, 0.01) for s in range(2)] + [_rec("depth-inpainted", s, 0.4, 0.02)
                                                                    for s in range(2)]
    md = build_report(recs).markdown()
    assert "## Depth given to the filter and its χ² gate" in md and "γ/dof median" in md
    bare = [RunRecord("seq", v, s, metrics={"ate_rmse_m": 0.02}) for v in ("depth-raw", "depth-inpainted")
            for s in range(2)]
    assert "χ² gate" not in build_report(bare).markdown()
