"""pipeline.gate_power: the gate's verdicts on features whose depth errors are known."""

from __future__ import annotations

import numpy as np

from pipeline.depth_oracle_run import _pooled_gate_power
from pipeline.gate_power import GatePower


def _power(**kw) -> GatePower:
    p = GatePower(**kw)
    # track 1: one bad measured reading (6 px off, σ 0.5 px); track 2: every reading good; track 3: a bad fill
    # (8 px, σ 0.5 px) and a good measured reading; track 4: a bad reading whose stated σ (3 px) covers it;
    # track 5: no truth
    p.add_readings(1.0, np.array([1, 2, 3, 4, 5]), np.array([0.3, 0.2, 0.4, 0.1, np.nan]),
                   np.array([0.5, 0.5, 0.5, 3.0, 0.5]), np.array([False, False, False, False, False]))
    p.add_readings(2.0, np.array([1, 2, 3, 4, 5]), np.array([6.0, 1.0, 8.0, 7.0, np.nan]),
                   np.array([0.5, 0.5, 0.5, 3.0, 0.5]), np.array([False, False, True, False, False]))
    return p


def test_a_bad_reading_counts_as_passed_only_when_it_entered_the_update():
    for verdict, passed in ((1, 1.0), (0, 0.0), (2, 1.0)):     # the fallback keeps a measured bad reading
        p = _power(fills_only_unmeasured=False)
        p.add_verdicts(0.5, 2.0, np.array([1]), np.array([verdict]))
        s = p.stats()
        assert s["gate_bad_depth_features"] == 1 and s["gate_bad_depth_passed"] == passed, (verdict, s)


def test_the_fallback_drops_a_bad_fill_and_fills_are_not_offered_beside_a_measured_reading():
    p = _power(fills_only_unmeasured=False)
    p.add_verdicts(0.5, 2.0, np.array([3, 3]), np.array([2, 1]))
    s = p.stats()
    assert s["gate_bad_depth_features"] == 2 and s["gate_bad_depth_passed"] == 0.5
    # with the filter's default rule the fill of track 3 never reaches the gate: the track is a good one
    p = _power(fills_only_unmeasured=True)
    p.add_verdicts(0.5, 2.0, np.array([3]), np.array([0]))
    s = p.stats()
    assert s["gate_bad_depth_features"] == 0 and s["gate_good_depth_features"] == 1
    assert s["gate_good_depth_rejected"] == 1.0


def test_a_bad_reading_its_sigma_covers_is_flagged_not_bad_and_readings_outside_the_window_do_not_count():
    p = _power()
    p.add_verdicts(0.5, 2.0, np.array([4, 2, 5]), np.array([1, 1, 1]))
    s = p.stats()
    assert s["gate_flagged_depth_features"] == 1 and s["gate_flagged_depth_passed"] == 1.0
    assert s["gate_bad_depth_features"] == 0 and np.isnan(s["gate_bad_depth_passed"])
    assert s["gate_good_depth_features"] == 1 and s["gate_good_depth_rejected"] == 0.0   # track 5: no truth
    p = _power()
    p.add_verdicts(1.5, 2.0, np.array([1]), np.array([1]))        # the window holds only the 6 px reading
    assert p.stats()["gate_bad_depth_passed"] == 1.0
    p = _power()
    p.add_verdicts(0.5, 1.5, np.array([1]), np.array([1]))        # … or only the good one
    assert p.stats()["gate_bad_depth_features"] == 0 and p.stats()["gate_good_depth_features"] == 1
    p.forget_before(1.5)
    p.add_verdicts(0.0, 1.5, np.array([1]), np.array([1]))        # forgotten readings are gone
    assert p.stats()["gate_good_depth_features"] == 1


def test_pooling_over_seeds_weighs_each_seed_by_its_count():
    a = {"gate_bad_depth_features": 3.0, "gate_bad_depth_passed": 1 / 3, "gate_good_depth_features": 0.0,
         "gate_good_depth_rejected": float("nan")}
    b = {"gate_bad_depth_features": 1.0, "gate_bad_depth_passed": 1.0, "gate_good_depth_features": 4.0,
         "gate_good_depth_rejected": 0.25}
    out = _pooled_gate_power([a, b])
    assert out["gate_bad_depth_features"] == 4 and out["gate_bad_depth_passed"] == 0.5
    assert out["gate_good_depth_features"] == 4 and out["gate_good_depth_rejected"] == 0.25
    assert out["gate_flagged_depth_features"] == 0 and np.isnan(out["gate_flagged_depth_passed"])
