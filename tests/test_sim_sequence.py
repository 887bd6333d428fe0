"""A simulated sequence read back: the bag through the foundation reader (counts, stamps, calibration, IMU, GPS,
odometry, tf_static), the ground-truth files, the exact depth, and the EuRoC export."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from eval.trajectory import read_euroc_gt, read_tum
from pipeline.bag_reader import RosarioSequence
from pipeline.sim import open_sequence, simulate_sequence
from pipeline.sim.presets import get_preset
from pipeline.sim.render import LABEL_SKY
from pipeline.sim.sensors import geodetic_to_enu


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory):
    cfg = get_preset("tiny")
    cfg = dataclasses.replace(cfg, duration_s=2.6, gps=cfg.gps.ideal())
    out = tmp_path_factory.mktemp("sim") / "seq"
    simulate_sequence(cfg, out, seed=2, max_frames=3, export_euroc=True, progress=False, ae_warmup=1)
    return open_sequence(out)


def test_bag_read_back_matches_what_was_written(sim) -> None:
    truth = sim.truth
    with RosarioSequence(sim.bag_path, camchain=sim.camchain_path) as bag:
        counts = sim.meta["counts"]
        assert bag.count("/imu") == counts["imu"] == len(truth["imu_stamp_ns"])
        assert bag.count("/gps/fix") == bag.count("/gps/vel") == counts["gps"]
        assert bag.count("/odom") == bag.count("tf_static") == counts["odom"]
        assert bag.count("/stereo/left/image_raw") == bag.count("/stereo/right/camera_info") == counts["frames"] == 3
        frames = list(bag.stereo_frames())
        np.testing.assert_array_equal([f.stamp_ns for f in frames], truth["frame_stamp_ns"])
        assert frames[0].left_bgr.shape == (376, 672, 3) and frames[0].left_bgr.dtype == np.uint8
        imu = list(bag.imu())
        np.testing.assert_array_equal([s.stamp_ns for s in imu], truth["imu_stamp_ns"])
        np.testing.assert_array_equal(np.array([s.gyro for s in imu]), truth["gyro_meas"])
        np.testing.assert_array_equal(np.array([s.accel for s in imu]), truth["accel_meas"])
        # calibration from camera_info + camchain equals the rig the images were rendered with
        rig, written = bag.calibration, sim.rig()
        for a, b in ((rig.left.K, written.left.K), (rig.left.D, written.left.D), (rig.right.K, written.right.K),
                     (rig.R_left, written.R_left), (rig.P_left, written.P_left), (rig.R_right, written.R_right),
                     (rig.P_right, written.P_right), (rig.T_left_imu, written.T_left_imu),
                     (rig.T_right_left, written.T_right_left)):
            np.testing.assert_allclose(a, b, atol=1e-12)
        # tf_static: base_link→imu is the mounting the IMU truth used; imu→left is the camchain's inverse
        statics = bag.static_transforms()
        np.testing.assert_allclose(statics[("base_link", "imu")], truth["T_base_imu"], atol=1e-9)
        np.testing.assert_allclose(statics[("imu", "left")], np.linalg.inv(written.T_left_imu), atol=1e-9)
        np.testing.assert_allclose(statics[("base_link", "gps")][:3, 3], truth["antenna_base"], atol=1e-12)
        # GPS fixes decode to the simulated ENU positions (noise off: the true antenna)
        fixes = list(bag.gps_fixes())
        g = sim.config.gps
        enu = geodetic_to_enu(np.array([f.lat_deg for f in fixes]), np.array([f.lon_deg for f in fixes]),
                              np.array([f.alt_m for f in fixes]), g.origin_lat_deg, g.origin_lon_deg,
                              g.origin_alt_msl_m + g.geoid_separation_m)
        np.testing.assert_allclose(enu, truth["gps_true_enu"], atol=1e-6)
        assert all(f.status == 2 for f in fixes)
        np.testing.assert_array_equal([o.stamp_ns for o in bag.odometry()], truth["odom_stamp_ns"])


def test_ground_truth_files_agree_with_each_other(sim) -> None:
    truth = sim.truth
    gt = read_tum(sim.gt_path)  # Rosario style: antenna, identity quaternions, origin at the first fix
    true_ant = read_tum(sim.gt_antenna_true_path)
    body = read_tum(sim.body_gt_path)
    assert not gt.has_orientation and body.has_orientation
    np.testing.assert_allclose(gt.positions[0], 0.0, atol=1e-9)
    np.testing.assert_allclose(gt.positions, true_ant.positions, atol=2e-9)  # GPS noise is off here
    # antenna = body (IMU) pose ∘ lever arm (antenna in the IMU frame), body interpolated to the GPS stamps
    T_BI = truth["T_base_imu"]
    lever_I = T_BI[:3, :3].T @ (truth["antenna_base"] - T_BI[:3, 3])
    slerp = Slerp(body.stamps_s, Rotation.from_quat(body.quats_xyzw))
    pos = np.stack([np.interp(true_ant.stamps_s, body.stamps_s, body.positions[:, j]) for j in range(3)], 1)
    composed = pos + slerp(true_ant.stamps_s).apply(lever_I)
    np.testing.assert_allclose(composed, true_ant.positions, atol=1e-4)
    np.testing.assert_allclose(body.positions, truth["p_E"], atol=2e-9)


def test_exact_depth_is_stored_for_every_frame(sim) -> None:
    for i in range(sim.n_frames):
        d, lab = sim.depth(i), sim.labels(i)
        assert d.shape == lab.shape == (376, 672) and d.dtype == np.float32
        finite = np.isfinite(d)
        assert 0.5 < finite.mean() < 1.0
        assert np.all(~finite[lab == LABEL_SKY])
        assert np.nanmin(d) > 0.5 and np.nanmax(d) <= 65.535
    assert [s for _, s, _ in sim.iter_depth()] == list(sim.truth["frame_stamp_ns"])


def test_euroc_export(sim) -> None:
    mav = Path(sim.euroc_path) / "mav0"
    gt = read_euroc_gt(mav / "state_groundtruth_estimate0/data.csv")
    body = read_tum(sim.body_gt_path)
    np.testing.assert_allclose(gt.positions, body.positions, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(gt.quats_xyzw * body.quats_xyzw, axis=1)), 1.0, atol=1e-9)
    imu = np.loadtxt(mav / "imu0/data.csv", delimiter=",", comments="#")
    assert imu.shape == (sim.meta["counts"]["imu"], 7)
    np.testing.assert_allclose(imu[:, 1:4], sim.truth["gyro_meas"], rtol=1e-8, atol=1e-12)
    lines = (mav / "cam0/data.csv").read_text().splitlines()
    assert lines[0].startswith("#") and len(lines) - 1 == sim.n_frames
    name = lines[1].split(",")[1]
    img = cv2.imread(str(mav / "cam1/data" / name), cv2.IMREAD_UNCHANGED)
    assert img.shape == (376, 672) and img.dtype == np.uint8


def test_meta_records_the_run(sim) -> None:
    m = sim.meta
    assert m["preset"] == "tiny" and m["seed"] == 2 and m["counts"]["frames"] == 3
    assert m["config"]["camera"]["tilt_deg"] == 19.0
    assert sim.config.gps.white_m == 0.0
    assert {"code", "numpy", "opencv"} <= set(m["versions"])
