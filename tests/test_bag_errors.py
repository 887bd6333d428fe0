"""Bad input gives a BagError naming the file and the problem; the CLI prints it without a traceback (exit 2)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eval.errors import EvalInputError
from msckf.camera import StereoRig
from pipeline import rosario_layout as L
from pipeline.bag_reader import RosarioSequence
from pipeline.bag_writer import RosarioBagWriter
from pipeline.cli import main
from pipeline.errors import BagError

BLACK = np.zeros((376, 672, 3), np.uint8)


def _write(path: Path, rig: StereoRig, *, imu: bool = True, frames: int = 2, strict: bool = True) -> Path:
    with RosarioBagWriter(path, strict=strict) as w:
        w.set_camera_info(rig)
        for i in range(frames):
            w.write_stereo(1_000_000_000 + i * 66_666_667, BLACK, BLACK)
        if imu:
            w.write_imu(1_000_000_000, np.zeros(3), np.array([9.8, 0.0, 0.0]))
    return path


def _bag_error(path: Path) -> str:
    with pytest.raises(BagError) as info:
        RosarioSequence(path)
    message = str(info.value)
    assert str(path) in message
    return message


def test_missing_topic(tmp_path, rosario_rig):
    msg = _bag_error(_write(tmp_path / "noimu.bag", rosario_rig, imu=False))
    assert "missing required topic" in msg and "/imu" in msg


def test_truncated_file(tmp_path, small_bag):
    data = small_bag[0].read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    assert "truncated" in _bag_error(cut)
    cut_index = tmp_path / "cut_index.bag"
    cut_index.write_bytes(data[:-40])  # the index region at the end is damaged
    assert "truncated or corrupt" in _bag_error(cut_index)


def test_missing_split_part(tmp_path, small_bag):
    data = small_bag[0].read_bytes()
    (tmp_path / "s.bag.00").write_bytes(data[:1000])
    (tmp_path / "s.bag.01").write_bytes(data[1000:5000])  # .02 never downloaded
    msg = _bag_error(tmp_path / "s.bag")
    assert "truncated" in msg and "split part" in msg


def test_empty_and_not_a_bag(tmp_path, rosario_rig):
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    assert "empty (0 bytes)" in _bag_error(empty)
    nomsg = tmp_path / "nomsg.bag"
    with RosarioBagWriter(nomsg):
        pass
    assert "no messages" in _bag_error(nomsg)
    text = tmp_path / "notes.bag"
    text.write_text("hello\n")
    assert "not a ROS1 v2.0 bag" in _bag_error(text)
    assert "no such bag" in _bag_error(tmp_path / "absent.bag")


def test_camera_info_size_differs_from_images(tmp_path, rosario_rig):
    small = dataclasses.replace(rosario_rig.left, width=640, height=360)
    rig = StereoRig(small, dataclasses.replace(rosario_rig.right, width=640, height=360), rosario_rig.T_right_left,
                    rosario_rig.T_left_imu, rosario_rig.R_left, rosario_rig.R_right, rosario_rig.P_left,
                    rosario_rig.P_right)
    msg = _bag_error(_write(tmp_path / "size.bag", rig, strict=False))
    assert "image is 672x376 but camera_info says 640x360" in msg


def test_non_bgr8_image(tmp_path, rosario_rig):
    path = tmp_path / "mono.bag"
    with RosarioBagWriter(path) as w:
        w.set_camera_info(rosario_rig)
        w.write_right(1_000_000_000, BLACK)
        w.write_imu(1_000_000_000, np.zeros(3), np.zeros(3))
        ts = w._ts  # write a mono8 left image by hand (the writer only writes bgr8)
        img = ts.types[L.MSG_IMAGE](header=w._header(1_000_000_000, L.FRAME_LEFT_IMAGE), height=376, width=672,
                                    encoding="mono8", is_bigendian=0, step=672, data=np.zeros(376 * 672, np.uint8))
        w._write(L.TOPIC_LEFT_IMAGE, 1_000_000_000, img)
        w._write(L.TOPIC_LEFT_INFO, 1_000_000_000, w._camera_info("left", 1_000_000_000, 0))
    assert "encoding 'mono8'; expected 'bgr8'" in _bag_error(path)


def test_ground_truth_crlf_and_malformed_line(tmp_path):
    gt = tmp_path / "sequence01_gt.txt"
    gt.write_bytes(b"1600000000.000000000 0 0 0 0 0 0 1\r\n1600000000.200000000 0.1 -0.02 0.003 0 0 0 1\r\n")
    traj = RosarioSequence.ground_truth(gt)
    assert traj.stamps_s.tolist() == [1600000000.0, 1600000000.2]
    assert traj.positions[1].tolist() == [0.1, -0.02, 0.003] and not traj.has_orientation
    bad = tmp_path / "bad_gt.txt"
    bad.write_text("1.0 0 0 0 0 0 0 1\r\n2.0 1 0 0 0 0 0 1\r\n3.0 oops 0 0 0 0 1\r\n")
    with pytest.raises(EvalInputError) as info:
        RosarioSequence.ground_truth(bad)
    assert f"{bad}:3" in str(info.value)


def test_cli_prints_error_without_traceback(tmp_path, rosario_rig, capsys):
    bad = _write(tmp_path / "noimu.bag", rosario_rig, imu=False)
    for command in ("info", "depth"):
        assert main([command, str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("agrivio: error: ") and str(bad) in err and "/imu" in err
        assert "Traceback" not in err


def test_cli_subprocess_exit_code(tmp_path):
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "info", str(empty)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and str(empty) in proc.stderr and "empty" in proc.stderr
