"""The shared camera model: projection round trips and the Rosario rectification."""

import numpy as np
import pytest
import yaml

from msckf.camera import PinholeRadtan, StereoRig
from pipeline.paths import ROSARIO_CAMCHAIN


def _rosario_rig() -> StereoRig:
    chain = yaml.safe_load(ROSARIO_CAMCHAIN.read_text())

    def cam(c):
        fx, fy, cx, cy = c["intrinsics"]
        return PinholeRadtan(*c["resolution"], fx, fy, cx, cy, tuple(c["distortion_coeffs"]))

    return StereoRig.from_extrinsics(cam(chain["cam0"]), cam(chain["cam1"]),
                                     np.array(chain["cam1"]["T_cn_cnm1"]), np.array(chain["cam0"]["T_cam_imu"]))


def test_rectification_matches_published_rosario_values():
    rig = _rosario_rig()
    # Values recomputed with OpenCV by the dataset's users (references/rosario.md §4.2).
    assert rig.fx == pytest.approx(351.06, abs=0.01)
    assert rig.cx == pytest.approx(340.7338447570801, abs=1e-6)
    assert rig.cy == pytest.approx(201.70985984802246, abs=1e-6)
    assert rig.P_right[0, 3] == pytest.approx(-41.677, abs=0.01)
    assert rig.baseline == pytest.approx(0.1187186, abs=1e-6)
    assert rig.R_left[0, 2] == pytest.approx(0.015891668631757446, abs=1e-9)


def test_project_unproject_round_trip_with_distortion():
    rig = _rosario_rig()
    pts = np.random.default_rng(0).uniform([-1, -0.5, 2], [1, 0.5, 8], (50, 3))
    px = rig.left.project(pts)
    assert np.all(np.isfinite(px))
    assert np.allclose(rig.left.unproject(px, pts[:, 2]), pts, atol=1e-9)
    rect = rig.rectify_left_pixels(px)
    assert np.allclose(rig.rectified_left_to_raw(rect), px, atol=1e-6)


def test_rectified_stereo_points_share_a_row_and_disparity_gives_depth():
    rig = _rosario_rig()
    pts_left = np.random.default_rng(1).uniform([-1, -0.5, 2], [1, 0.5, 8], (20, 3))
    pts_right = (rig.T_right_left[:3, :3] @ pts_left.T).T + rig.T_right_left[:3, 3]
    rect_l = (pts_left @ rig.R_left.T) @ rig.P_left[:, :3].T
    rect_r = (pts_right @ rig.R_right.T) @ rig.P_right[:, :3].T  # right point in the rectified right frame
    # Equivalently, P_right projects rectified *left*-frame points into the rectified right image.
    rect_r2 = (pts_left @ rig.R_left.T) @ rig.P_right[:, :3].T + rig.P_right[:, 3]
    assert np.allclose(rect_r[:, :2] / rect_r[:, 2:], rect_r2[:, :2] / rect_r2[:, 2:], atol=1e-6)
    ul, vl = rect_l[:, 0] / rect_l[:, 2], rect_l[:, 1] / rect_l[:, 2]
    ur, vr = rect_r[:, 0] / rect_r[:, 2], rect_r[:, 1] / rect_r[:, 2]
    assert np.allclose(vl, vr, atol=1e-6)
    z_rect = (pts_left @ rig.R_left.T)[:, 2]
    # rtol: the published T_cn_cnm1 rotation is rounded to 1e-8, so R is only orthonormal to ~1e-6.
    assert np.allclose(rig.depth_from_disparity(ul - ur), z_rect, rtol=1e-4)


def test_bad_calibration_is_rejected():
    with pytest.raises(ValueError, match="distortion"):
        PinholeRadtan(672, 376, 300, 300, 336, 188, (0.1, 0.2))
    cam = PinholeRadtan(672, 376, 300, 300, 336, 188)
    bad = np.eye(4)
    bad[:3, :3] *= 2
    with pytest.raises(ValueError, match="rotation"):
        StereoRig.from_extrinsics(cam, cam, bad, np.eye(4))
