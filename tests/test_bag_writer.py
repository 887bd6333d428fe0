"""RosarioBagWriter writes the exact Rosario v1 layout (rosario.md §3), checked with rosbags' own reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Reader

from pipeline import rosario_layout as L
from pipeline.bag_typestore import rosario_typestore
from pipeline.bag_writer import RosarioBagWriter

# md5sums of the ROS1 definitions (rosario.md §3; TFMessage: apis/rosario notes).
EXPECTED_MD5 = {
    L.MSG_IMAGE: "060021388200f6f0f447d0fcd9c64743",
    L.MSG_IMU: "6a62c6daae103f4ff57a132d6f95cec2",
    L.MSG_CAMERA_INFO: "c9a58c1b0b154e0e6da7578cb991d214",
    L.MSG_NAVSATFIX: "2d3a8cd499b9b4a0249fb98fd05cfa48",
    L.MSG_TWIST_STAMPED: "98d34b0043a2093cf9d9345ab6eef12e",
    L.MSG_ODOMETRY: "cd5e73d190d741a2f92e81eda573aca7",
    L.MSG_TF: "94810edda583a504dfda3829e70d7eec",
}


def _read_all(path: Path) -> dict[str, list[tuple[int, object]]]:
    ts = rosario_typestore()
    out: dict[str, list[tuple[int, object]]] = {}
    with Reader(path) as r:
        for conn, t, raw in r.messages():
            out.setdefault(conn.topic, []).append((t, ts.deserialize_ros1(raw, conn.msgtype)))
    return out


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_small_bag_has_exact_topics_types_and_md5(small_bag):
    path, _ = small_bag
    with Reader(path) as r:
        conns = {c.topic: c for c in r.connections}
    assert set(conns) == set(L.TOPIC_TYPES)  # includes the literal "tf_static" without a slash
    assert "tf_static" in conns and "/tf_static" not in conns
    for topic, conn in conns.items():
        assert conn.msgtype == L.TOPIC_TYPES[topic]
        assert conn.digest == EXPECTED_MD5[conn.msgtype], topic


def test_bag_time_equals_header_stamp_and_frame_ids(small_bag):
    path, truth = small_bag
    msgs = _read_all(path)
    frame_ids = {L.TOPIC_LEFT_IMAGE: "/stereo/left", L.TOPIC_RIGHT_IMAGE: "/stereo/right",
                 L.TOPIC_LEFT_INFO: "left", L.TOPIC_RIGHT_INFO: "right", L.TOPIC_IMU: "imu",
                 L.TOPIC_GPS_FIX: "gps", L.TOPIC_GPS_VEL: "gps", L.TOPIC_ODOM: "odom"}
    for topic, items in msgs.items():
        if topic == L.TOPIC_TF_STATIC:
            for t, m in items:
                assert all(_stamp(tr) == t for tr in m.transforms)
            continue
        for seq, (t, m) in enumerate(items):
            assert _stamp(m) == t, topic
            assert m.header.frame_id == frame_ids[topic]
            assert m.header.seq == seq  # seq counts from 0 per topic
    stamps = [t for t, _ in msgs[L.TOPIC_LEFT_IMAGE]]
    assert stamps == truth.frame_stamps_ns.tolist()
    assert msgs[L.TOPIC_ODOM][0][1].child_frame_id == "base_link"


def test_images_camera_info_and_imu_fields(small_bag, rosario_rig):
    path, truth = small_bag
    msgs = _read_all(path)
    img = msgs[L.TOPIC_LEFT_IMAGE][0][1]
    assert (img.height, img.width, img.encoding, img.step) == (376, 672, "bgr8", 672 * 3)
    for (t_img, im), (t_info, info) in zip(msgs[L.TOPIC_RIGHT_IMAGE], msgs[L.TOPIC_RIGHT_INFO]):
        assert t_img == t_info and im.header.seq == info.header.seq  # one camera_info per image
    info = msgs[L.TOPIC_RIGHT_INFO][0][1]
    assert info.distortion_model == "plumb_bob" and len(info.D) == 5
    np.testing.assert_allclose(np.reshape(info.K, (3, 3)), rosario_rig.right.K)
    np.testing.assert_allclose(np.reshape(info.R, (3, 3)), rosario_rig.R_right)
    np.testing.assert_allclose(np.reshape(info.P, (3, 4)), rosario_rig.P_right)
    assert info.P[3] == pytest.approx(-rosario_rig.fx * rosario_rig.baseline)
    imu = msgs[L.TOPIC_IMU][0][1]
    for cov in (imu.orientation_covariance, imu.angular_velocity_covariance, imu.linear_acceleration_covariance):
        assert list(cov) == [-1.0] + [0.0] * 8
    assert (imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w) == (0, 0, 0, 1)
    assert imu.linear_acceleration.x == pytest.approx(truth.imu_accel[0, 0])
    assert imu.linear_acceleration.x > 9.0  # Rosario IMU x points up: gravity reaction on +x
    fix = msgs[L.TOPIC_GPS_FIX][0][1]
    assert fix.status.status == 2 and fix.status.service == 1 and fix.position_covariance_type == 1
    assert fix.position_covariance[0] == pytest.approx(0.64) and fix.position_covariance[8] == pytest.approx(2.56)
    tf = msgs[L.TOPIC_TF_STATIC][0][1]
    assert [(tr.header.frame_id, tr.child_frame_id) for tr in tf.transforms] == \
        [("base_link", "imu"), ("imu", "left"), ("imu", "right"), ("base_link", "gps")]


def test_writer_is_atomic_and_refuses_overwrite(tmp_path, rosario_rig):
    path = tmp_path / "x.bag"
    with pytest.raises(RuntimeError, match="boom"):
        with RosarioBagWriter(path) as w:
            w.set_camera_info(rosario_rig)
            w.write_imu(1, np.zeros(3), np.zeros(3))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []  # neither the bag nor a temp file is left
    with RosarioBagWriter(path, compression="lz4") as w:
        w.write_imu(1, np.zeros(3), np.zeros(3))
    assert path.is_file() and list(tmp_path.iterdir()) == [path]
    with pytest.raises(FileExistsError):
        with RosarioBagWriter(path):
            pass


def test_writer_checks_images(tmp_path, rosario_rig):
    with RosarioBagWriter(tmp_path / "y.bag") as w:
        with pytest.raises(RuntimeError, match="set_camera_info"):
            w.write_left(0, np.zeros((376, 672, 3), np.uint8))
        w.set_camera_info(rosario_rig)
        with pytest.raises(ValueError, match="camera_info says 672x376"):
            w.write_left(0, np.zeros((100, 200, 3), np.uint8))
        with pytest.raises(ValueError, match="uint8 BGR"):
            w.write_left(0, np.zeros((376, 672), np.uint8))
    with pytest.raises(ValueError, match="compression"):
        RosarioBagWriter(tmp_path / "z.bag", compression="zip")
