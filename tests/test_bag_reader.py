"""RosarioSequence reads back exactly what RosarioBagWriter wrote: plain, BZ2, LZ4 and byte-split bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline import rosario_layout as L
from pipeline.bag_parts import ChainedParts, resolve_bag_parts
from pipeline.bag_reader import RosarioSequence
from pipeline.bag_writer import RosarioBagWriter
from pipeline.synthetic_scene import StereoRenderer, write_synthetic_bag


def _split(path: Path, out_dir: Path, n_parts: int) -> list[Path]:
    data = path.read_bytes()
    size = -(-len(data) // n_parts)
    parts = []
    for i in range(n_parts):
        p = out_dir / f"{path.name}.{i:02d}"
        p.write_bytes(data[i * size:(i + 1) * size])
        parts.append(p)
    return parts


@pytest.fixture(scope="module")
def bz2_bag(tmp_path_factory, rosario_rig):
    path = tmp_path_factory.mktemp("bz2") / "seq_bz2.bag"
    truth = write_synthetic_bag(path, n_frames=3, rig=rosario_rig, seed=5, compression="bz2")
    return path, truth


@pytest.fixture(scope="module")
def split_bag(tmp_path_factory, small_bag):
    path, truth = small_bag
    out = tmp_path_factory.mktemp("split")
    _split(path, out, 3)
    return out / path.name, truth


def _check_streams(seq: RosarioSequence, truth, rig) -> None:
    n = len(truth.frame_stamps_ns)
    assert seq.count(L.TOPIC_LEFT_IMAGE) == n and seq.count("tf_static") == len(truth.odom_stamps_ns)
    assert seq.count("/tf_static") == seq.count("tf_static")
    renderer = StereoRenderer(rig)
    frames = list(seq.stereo_frames())
    assert [f.stamp_ns for f in frames] == truth.frame_stamps_ns.tolist()
    assert [f.index for f in frames] == list(range(n))
    for f in (frames[0], frames[-1]):  # pixels are exactly what was rendered
        pose = np.eye(4)
        pose[:3, 3] = truth.positions_left[f.index]
        left, right = renderer.render(pose)
        assert np.array_equal(f.left_bgr, left) and np.array_equal(f.right_bgr, right)
    assert seq.stats.unpaired_left == seq.stats.unpaired_right == 0

    imu = seq.imu_array()
    assert imu.shape == (len(truth.imu_stamps_ns), 7)
    assert np.array_equal(seq.imu_stamps_ns(), truth.imu_stamps_ns)
    np.testing.assert_array_equal(imu[:, 1:4], truth.imu_gyro)
    np.testing.assert_array_equal(imu[:, 4:7], truth.imu_accel)

    fixes = list(seq.gps_fixes())
    assert [g.stamp_ns for g in fixes] == truth.gps_stamps_ns.tolist()
    np.testing.assert_array_equal(seq.gps_fix_array()[:, 1:4], truth.gps)
    assert all(g.status == 2 for g in fixes)
    np.testing.assert_array_equal(seq.gps_velocity_array()[:, 1:], truth.gps_vel)
    odom = seq.odom_array()
    assert [o.stamp_ns for o in seq.odometry()] == truth.odom_stamps_ns.tolist()
    np.testing.assert_allclose(odom[:, 1:], truth.odom, atol=1e-12)

    statics = seq.static_transforms()
    assert len(statics) == 4
    for parent, child, T in truth.static_transforms:
        np.testing.assert_allclose(statics[(parent, child)], T, atol=1e-6)  # via a quaternion: R re-orthonormalised
    assert len(list(seq.tf_static())) == 4 * len(truth.odom_stamps_ns)

    cal = seq.calibration
    for name in ("P_left", "P_right", "R_left", "R_right", "T_right_left", "T_left_imu"):
        np.testing.assert_allclose(getattr(cal, name), getattr(rig, name), atol=1e-12)
    np.testing.assert_allclose(cal.left.D, rig.left.D)
    assert cal.left.K.tolist() == rig.left.K.tolist()


def test_plain_bag_round_trip(small_bag, rosario_rig):
    path, truth = small_bag
    _check_streams(RosarioSequence(path), truth, rosario_rig)


def test_bz2_bag_round_trip(bz2_bag, rosario_rig):
    path, truth = bz2_bag
    seq = RosarioSequence(path)
    _check_streams(seq, truth, rosario_rig)


def test_split_bag_read_in_place_by_stem_or_first_part(split_bag, small_bag, rosario_rig):
    stem, truth = split_bag
    assert not stem.exists()  # only the parts exist; nothing is concatenated on disk
    for given in (stem, stem.with_name(stem.name + ".00")):
        seq = RosarioSequence(given)
        assert len(seq.parts) == 3 and seq.size_bytes == small_bag[0].stat().st_size
        _check_streams(seq, truth, rosario_rig)
    assert sorted(p.name for p in stem.parent.iterdir()) == [f"{stem.name}.{i:02d}" for i in range(3)]
    assert RosarioSequence(stem).identity().split("-")[1] == RosarioSequence(small_bag[0]).identity().split("-")[1]


def test_chained_parts_behaves_like_one_file(tmp_path):
    data = bytes(range(256)) * 40
    parts = []
    for i, (a, b) in enumerate(((0, 1000), (1000, 1003), (1003, len(data)))):
        p = tmp_path / f"f.bin.{i:02d}"
        p.write_bytes(data[a:b])
        parts.append(p)
    assert resolve_bag_parts(tmp_path / "f.bin") == tuple(parts)
    import io
    with io.BufferedReader(ChainedParts(parts), buffer_size=64) as fh:
        assert fh.read() == data
        fh.seek(998)
        assert fh.read(10) == data[998:1008]  # crosses two boundaries
        fh.seek(-5, 2)
        assert fh.read() == data[-5:]


def test_missing_partner_is_skipped_and_counted(tmp_path, rosario_rig):
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, (376, 672, 3), dtype=np.uint8) for _ in range(6)]
    t = [1_000_000_000 + i * 66_666_667 for i in range(6)]
    path = tmp_path / "gaps.bag"
    with RosarioBagWriter(path, compression="lz4") as w:
        w.set_camera_info(rosario_rig)
        w.write_stereo(t[0], imgs[0], imgs[1])
        w.write_left(t[1], imgs[1])                      # right missing
        w.write_stereo(t[2], imgs[2], imgs[3])
        w.write_right(t[3], imgs[3])                     # left missing
        w.write_left(t[4], imgs[4])
        w.write_right(t[4] + 2_000_000, imgs[5])         # 2 ms apart: still a pair (tolerance 5 ms)
        w.write_left(t[5], imgs[5])                      # last left without a partner
        w.write_imu(t[0], np.zeros(3), np.zeros(3))
    seq = RosarioSequence(path)
    frames = list(seq.stereo_frames())
    assert [f.stamp_ns for f in frames] == [t[0], t[2], t[4]]
    assert [f.index for f in frames] == [0, 1, 2]
    assert np.array_equal(frames[1].left_bgr, imgs[2]) and np.array_equal(frames[1].right_bgr, imgs[3])
    assert (seq.stats.unpaired_left, seq.stats.unpaired_right, seq.stats.stereo_pairs) == (2, 1, 3)
    assert [f.index for f in seq.stereo_frames(start_index=1, stop_index=2)] == [1]
    strict = RosarioSequence(path, pair_tolerance_ns=1_000_000)
    assert len(list(strict.stereo_frames())) == 2


def test_repeated_imu_stamps(tmp_path, rosario_rig):
    """Original Rosario bags repeat IMU stamps; the covariance arrays hold [-1, 0, ...]."""
    stamps = [0, 7, 7, 7, 14, 21, 21]
    path = tmp_path / "imu.bag"
    with RosarioBagWriter(path) as w:
        w.set_camera_info(rosario_rig)
        w.write_stereo(0, np.zeros((376, 672, 3), np.uint8), np.zeros((376, 672, 3), np.uint8))
        for k, t in enumerate(stamps):
            w.write_imu(1_000_000_000 + t * 1_000_000, np.array([k, 0.0, 0.0]), np.array([9.8, 0.0, k]))
    ms = lambda seq: [(s.stamp_ns - 1_000_000_000) / 1e6 for s in seq.imu()]  # noqa: E731
    spread = RosarioSequence(path)
    assert ms(spread) == pytest.approx([0, 7, 7 + 7 / 3, 7 + 14 / 3, 14, 21, 28], abs=1e-6)  # last run: last period
    assert spread.stats.imu_repeated_stamps == 3 and spread.stats.imu_samples == 7
    assert [s.gyro[0] for s in spread.imu()] == list(range(7))  # order and values kept
    assert ms(RosarioSequence(path, imu_stamps="keep")) == stamps
    dropped = RosarioSequence(path, imu_stamps="drop")
    assert ms(dropped) == [0, 7, 14, 21]
    assert [s.accel[2] for s in dropped.imu()] == [0, 1, 4, 5]


def test_interleaved_streams_and_ranges(small_bag):
    path, truth = small_bag
    seq = RosarioSequence(path)
    frames, imu = seq.stereo_frames(), seq.imu()
    got = [(next(frames).index, next(imu).stamp_ns) for _ in range(3)]  # two open streams at once
    assert [g[0] for g in got] == [0, 1, 2] and [g[1] for g in got] == truth.imu_stamps_ns[:3].tolist()
    t0, t1 = int(truth.imu_stamps_ns[10]), int(truth.imu_stamps_ns[20])
    part = seq.imu_array(start_ns=t0, stop_ns=t1)
    assert part.shape[0] == 10
    assert seq.duration_s == pytest.approx((seq.end_ns - seq.start_ns) / 1e9)


def test_left_only_frames_are_the_same_pairs_without_decoding_the_right(small_bag):
    """Depth runs read the left image only: the same pairs, indices and left images, no right image."""
    path, _ = small_bag
    seq = RosarioSequence(path)
    both = list(seq.stereo_frames())
    left = list(seq.stereo_frames(right=False))
    assert [(f.index, f.stamp_ns) for f in left] == [(f.index, f.stamp_ns) for f in both]
    assert all(f.right_bgr is None and np.array_equal(f.left_bgr, g.left_bgr) for f, g in zip(left, both))
