"""The bag stream seams that hold logic of their own: the IMU repeated-stamp policy and the first tf_static set."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bag_messages import ReaderStats, StaticTransform
from pipeline.bag_streams import apply_imu_stamp_policy, first_static_transforms


def _raw(stamps: list[int]) -> list[tuple[int, np.ndarray, np.ndarray]]:
    return [(s, np.full(3, float(i)), np.full(3, -float(i))) for i, s in enumerate(stamps)]


@pytest.mark.parametrize(("policy", "expected"), [
    ("keep", [100, 100, 100, 130, 140, 140]),
    ("drop", [100, 130, 140]),
    ("spread", [100, 110, 120, 130, 140, 150]),  # the final run is spread by the last known period (130 → 140)
])
def test_imu_stamp_policy(policy, expected):
    # samples: a run of 3 at 100, one at 130, one going backwards (dropped), a run of 2 at 140 at the end
    raw = _raw([100, 100, 100, 130, 120, 140, 140])
    stats = ReaderStats(imu_samples=99)
    out = list(apply_imu_stamp_policy(raw, policy, stats))
    assert [s.stamp_ns for s in out] == expected
    assert all(isinstance(s.stamp_ns, int) for s in out)
    assert stats.imu_samples == len(expected) and stats.imu_repeated_stamps == 3 and stats.imu_out_of_order == 1
    kept = [0, 1, 2, 3, 5, 6] if policy != "drop" else [0, 3, 5]
    np.testing.assert_array_equal([s.gyro[0] for s in out], kept)  # the data stay with their samples


def test_imu_stamp_policy_empty_stream():
    stats = ReaderStats()
    assert list(apply_imu_stamp_policy([], "spread", stats)) == [] and stats.imu_samples == 0


def test_first_static_transforms_stops_at_the_first_repeat():
    T1, T2, T3 = (np.eye(4) * k for k in (1.0, 2.0, 3.0))
    trs = [StaticTransform(0, "base_link", "imu", T1), StaticTransform(0, "imu", "left", T2),
           StaticTransform(10, "base_link", "imu", T3), StaticTransform(10, "base_link", "gps", T3)]
    out = first_static_transforms(trs)
    assert list(out) == [("base_link", "imu"), ("imu", "left")]
    assert out[("base_link", "imu")] is T1
