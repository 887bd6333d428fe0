"""A bag's IMU samples are read once and served from the cache to later runs, unchanged."""

from __future__ import annotations

import numpy as np

from pipeline.bag_reader import RosarioSequence
from pipeline.imu_cache import cached_imu_samples, imu_cache_path


def _no_bag_read(*args, **kwargs):
    raise AssertionError("the IMU was read from the bag although it is cached")


def test_cached_samples_equal_the_bag_and_are_not_read_again(small_bag, tmp_path, monkeypatch):
    seq = RosarioSequence(small_bag[0])
    direct = seq.imu_samples()
    first = cached_imu_samples(seq, tmp_path)
    assert imu_cache_path(seq, tmp_path).is_file()
    again_seq = RosarioSequence(small_bag[0])
    monkeypatch.setattr(again_seq, "imu_samples", _no_bag_read)
    second = cached_imu_samples(again_seq, tmp_path)
    for got in (first, second):
        assert got[0].dtype == np.int64 and got[1].dtype == np.float64 and len(got[0]) > 10
        np.testing.assert_array_equal(got[0], direct[0])
        np.testing.assert_array_equal(got[1], direct[1])


def test_stamp_policy_selects_its_own_file_and_a_garbled_file_is_read_again(small_bag, tmp_path, capsys):
    spread, keep = RosarioSequence(small_bag[0]), RosarioSequence(small_bag[0], imu_stamps="keep")
    assert imu_cache_path(spread, tmp_path) != imu_cache_path(keep, tmp_path)
    path = imu_cache_path(spread, tmp_path)
    cached_imu_samples(spread, tmp_path)
    path.write_bytes(b"not an npz")
    stamps, data = cached_imu_samples(spread, tmp_path)
    assert "unreadable IMU cache" in capsys.readouterr().err
    np.testing.assert_array_equal(stamps, spread.imu_samples()[0])
    np.testing.assert_array_equal(np.load(path)["data"], data)  # written again
