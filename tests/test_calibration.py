"""Kalibr camchain and camera_info → StereoRig, camchain writing, and errors naming the file."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from pipeline.calibration import (
    CalibrationError,
    camchain_yaml,
    camera_info_from_rig,
    read_camchain,
    rig_from_camchain,
    rig_from_camera_info,
    write_camchain,
)
from pipeline.paths import ROSARIO_CAMCHAIN


def test_shipped_camchain_gives_published_rectification():
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    assert rig.left.size == (672, 376)
    assert rig.left.fx == 348.522264 and rig.right.cy == 206.105440
    assert rig.left.distortion == (-0.174497, 0.027127, -0.000359, 0.000457)
    assert rig.fx == pytest.approx(351.0571, abs=0.01)       # rosario.md §4.2 (authors' configs: 351.0571182)
    assert rig.P_right[0, 3] == pytest.approx(-41.677, abs=0.01)
    R_left = [0.999873448071739, 0.0007366880139693224, 0.015891668631757446, -0.0007117643758229365,
              0.9999985080430129, -0.0015739451138449111, -0.01589280442857141, 0.0015624348044513143,
              0.9998724806518465]
    np.testing.assert_allclose(rig.R_left.ravel(), R_left, atol=1e-9)
    assert rig.T_left_imu[0, 3] == 0.07585973485189132
    assert rig.T_right_left[0, 3] == -0.118718331
    chain = read_camchain(ROSARIO_CAMCHAIN)
    assert chain.topics == ("/stereo/left/image_raw", "/stereo/right/image_raw")
    assert chain.T_right_imu[0, 3] == -0.04365571656478627  # cam1/T_cam_imu is read, not used for the rig


def test_camchain_write_read_round_trip(tmp_path):
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    out = tmp_path / "chain.yaml"
    write_camchain(rig, out)
    data = yaml.safe_load(out.read_text())
    assert data["cam0"]["distortion_model"] == "radtan" and data["cam1"]["resolution"] == [672, 376]
    back = rig_from_camchain(out)
    for name in ("T_left_imu", "T_right_left", "R_left", "R_right", "P_left", "P_right"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rig, name))
    assert back.left == rig.left and back.right == rig.right


def test_rig_from_camera_info_takes_R_and_P_as_given():
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    left, right = camera_info_from_rig(rig)
    # A camera_info P different from what stereoRectify would give (e.g. the ORB-SLAM3 Rosario_1 set).
    P_l = left.P.copy()
    P_l[0, 0] = P_l[1, 1] = 347.6564367181238
    P_r = P_l.copy()
    P_r[0, 3] = -41.273302096641586
    from dataclasses import replace
    got = rig_from_camera_info(replace(left, P=P_l), replace(right, P=P_r), ROSARIO_CAMCHAIN)
    assert got.fx == 347.6564367181238 and got.baseline == pytest.approx(41.273302096641586 / 347.6564367181238)
    np.testing.assert_array_equal(got.R_left, rig.R_left)
    np.testing.assert_array_equal(got.T_left_imu, rig.T_left_imu)  # extrinsics from the camchain


def test_camera_info_errors_name_the_source():
    left, right = camera_info_from_rig(rig_from_camchain(ROSARIO_CAMCHAIN))
    from dataclasses import replace
    with pytest.raises(CalibrationError, match=r"seq\.bag: left camera_info distortion_model is 'equidistant'"):
        rig_from_camera_info(replace(left, distortion_model="equidistant"), right, ROSARIO_CAMCHAIN, source="seq.bag")
    with pytest.raises(CalibrationError, match=r"seq\.bag: right camera_info P must have shape \(3, 4\)"):
        rig_from_camera_info(left, replace(right, P=np.zeros((3, 3))), ROSARIO_CAMCHAIN, source="seq.bag")


@pytest.mark.parametrize("edit, problem", [
    (lambda d: d["cam0"].pop("T_cam_imu"), "missing key cam0/T_cam_imu"),
    (lambda d: d["cam1"].pop("T_cn_cnm1"), "missing key cam1/T_cn_cnm1"),
    (lambda d: d.pop("cam1"), "missing key cam1"),
    (lambda d: d["cam0"].update(intrinsics=[1.0, 2.0, 3.0]), r"cam0/intrinsics must have shape \(4,\), got \(3,\)"),
    (lambda d: d["cam1"].update(T_cn_cnm1=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), r"cam1/T_cn_cnm1 must have shape"),
    (lambda d: d["cam0"].update(T_cam_imu=np.diag([2.0, 1, 1, 1]).tolist()), "does not hold a rotation"),
    (lambda d: d["cam1"].update(distortion_model="equidistant"), "only 'radtan'"),
    (lambda d: d["cam1"].update(resolution=[640, 480]), "differs from cam1 resolution"),
])
def test_camchain_errors_name_file_and_problem(tmp_path, edit, problem):
    data = yaml.safe_load(ROSARIO_CAMCHAIN.read_text())
    edit(data)
    path = tmp_path / "bad_chain.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match=problem) as info:
        rig_from_camchain(path)
    assert str(path) in str(info.value)


def test_camchain_file_problems(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        read_camchain(tmp_path / "none.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("cam0: [unclosed\n")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        read_camchain(bad)


def test_camchain_yaml_rejects_k3():
    rig = rig_from_camchain(ROSARIO_CAMCHAIN)
    from dataclasses import replace
    rig5 = type(rig)(replace(rig.left, distortion=(0.1, 0.0, 0.0, 0.0, 0.01)), rig.right, rig.T_right_left,
                     rig.T_left_imu, rig.R_left, rig.R_right, rig.P_left, rig.P_right)
    with pytest.raises(ValueError, match="k3"):
        camchain_yaml(rig5)
