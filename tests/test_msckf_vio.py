"""The Msckf facade: wiring to a front end, variants, errors, and a smoke run with the real front ends."""

import numpy as np
import pytest

from msckf.config import MsckfConfig, load_config
from msckf.errors import MsckfInputError
from msckf.synthetic import FX, make_world
from msckf.vio import Msckf
from pipeline.plane_scene import Plane, make_texture, pose, rectified_depth, render, scene_rig, stereo_pose


class _ReplayFrontend:
    """Returns prepared observations in order and records what it was given."""

    def __init__(self, frames):
        self.frames = list(frames)
        self.gyro = []
        self.calls = []

    def add_imu(self, t_s, gyro_rad_s):
        self.gyro.append((t_s, gyro_rad_s))

    def process(self, stamp_s, left, other, valid=None):
        self.calls.append((stamp_s, left.shape, None if other is None else other.shape, valid is not None))
        return self.frames.pop(0)


def test_facade_drives_front_end_and_filter_from_arrays():
    rig = scene_rig()
    w = make_world(seed=1, duration=3.0, max_features=100)
    # the world's pixel noise is white 1 px: the gate's σ is the feature σ, not the 0.18 px calibrated on rendered
    # KLT tracks
    cfg = dict(gyro_noise=0.002, acc_noise=0.02, gyro_bias_noise=1e-4, acc_bias_noise=1e-3, feature_noise=1.0 / FX,
               stereo_gate_noise=1.0 / FX, stereo_feature_noise=1.0 / FX, stereo_track_drift_psd=0.0)
    fe = _ReplayFrontend(w.frames)
    vio = Msckf(cfg, rig, variant="stereo", seed=3, frontend=fe)
    # the sim world uses the same Rosario extrinsics as the rig (to ~1e-6)
    assert np.allclose(vio.filter._R_c_i0, w.T_cam0_imu[:3, :3], atol=1e-5)
    vio.filter.initialize(w.t0, w.R0, w.p0, w.v0, w.b_g0, w.b_a0, 9.81)
    img = np.zeros((rig.left.height, rig.left.width), np.uint8)
    i, poses = 0, []
    for obs in w.frames:
        while i < len(w.imu_t) and w.imu_t[i] <= obs.stamp_s:
            vio.add_imu(w.imu_t[i], w.gyro[i], w.acc[i])
            i += 1
        poses.append(vio.add_frame(obs.stamp_s, img, img))
    assert len(fe.gyro) == i and fe.calls[0][2] == img.shape
    assert vio.last_observations is w.frames[-1] and vio.n_frames == len(w.frames)
    assert np.linalg.norm(poses[-1].p_world - w.p_w[-1]) < 0.1
    assert vio.last_stats.n_clones > 0
    with pytest.raises(MsckfInputError, match="right image"):
        vio.add_frame(100.0, img)


def test_facade_rejects_bad_arguments():
    rig = scene_rig()
    with pytest.raises(MsckfInputError, match="variant"):
        Msckf(None, rig, variant="mono", frontend=_ReplayFrontend([]))
    with pytest.raises(MsckfInputError, match="StereoRig"):
        Msckf(None, "rig", frontend=_ReplayFrontend([]))
    vio = Msckf({"feature_noise": 0.01}, rig, variant="depth", frontend=_ReplayFrontend([]))
    assert vio.config.update.feature_noise == 0.01
    with pytest.raises(MsckfInputError, match="depth map"):
        vio.add_frame(0.0, np.zeros((376, 672), np.uint8), right_grey=np.zeros((376, 672), np.uint8))


@pytest.mark.parametrize("variant", ["stereo", "depth"])
def test_real_front_ends_on_a_static_scene(variant):
    """Static start in front of a textured wall: initialises, tracks, and stays put."""
    rig = scene_rig()
    T = pose()                                          # cam0 looks along world +Z, y down
    wall = Plane.wall(4.0, make_texture(0))
    left = render(rig.left, T, wall)
    right = render(rig.right, stereo_pose(rig, T), wall)
    depth = rectified_depth(rig, T, wall)
    R_c_i = rig.T_left_imu[:3, :3]
    f_imu = R_c_i.T @ np.array([0.0, -9.81, 0.0])      # at rest the accelerometer reads "up" = −y_cam
    cfg = load_config({"feature_noise": 1.5 / rig.fx})
    vio = Msckf(cfg, rig, variant=variant, seed=0)
    poses = []
    for k in range(1, 451):                             # 3 s of IMU at 150 Hz, images at 15 Hz
        t = k / 150.0
        vio.add_imu(t, np.zeros(3), f_imu)
        if k % 10 == 0:
            if variant == "stereo":
                poses.append(vio.add_frame(t, left, right))
            else:
                poses.append(vio.add_frame(t, left, depth=depth))
    assert poses[0] is None and poses[-1] is not None   # 200 samples (1.33 s) for the static initialisation
    assert vio.last_observations is not None and len(vio.last_observations) > 50
    assert np.linalg.norm(poses[-1].p_world) < 0.02
    assert np.linalg.norm(poses[-1].v_world) < 0.02
    assert vio.last_debug is not None


def test_load_config_from_yaml_and_errors(tmp_path):
    p = tmp_path / "vio.yaml"
    p.write_text("feature_noise: 0.01\nchi2_quantile: 0.99\nfrontend:\n  grid_min_feature_num: 10\n")
    c = load_config(p)
    assert c.update.feature_noise == 0.01 and c.update.chi2_quantile == 0.99 and c.frontend.grid_min_feature_num == 10
    assert load_config(c.to_dict()) == c                # round trip
    d = MsckfConfig()                                   # Rosario launch values (rosario.md §7)
    assert (d.window.max_cam_state_size, d.health.position_std_threshold, d.window.rotation_threshold,
            d.window.translation_threshold, d.window.tracking_rate_threshold,
            d.triangulation.feature_translation_threshold) == (20, 8.0, 0.2618, 0.4, 0.5, -1.0)
    n = d.imu_noise
    assert (n.gyro_noise, n.acc_noise, n.gyro_bias_noise, n.acc_bias_noise) == (0.005, 0.05, 0.001, 0.01)
    i = d.init
    assert (i.velocity_cov, i.gyro_bias_cov, i.acc_bias_cov, i.extrinsic_rotation_cov,
            i.extrinsic_translation_cov) == (0.25, 0.01, 0.01, 3.0462e-4, 2.5e-5)
    assert i.init_imu_samples == 200 and d.frontend.grid_min_feature_num == 30
    p.write_text("feature_nois: 0.01\n")
    with pytest.raises(MsckfInputError, match=r"vio.yaml.*feature_nois"):
        load_config(p)
    p.write_text("frontend:\n  grid_rows: 3\n")
    with pytest.raises(MsckfInputError, match=r"vio.yaml.*grid_rows"):
        load_config(p)
    p.write_text("max_cam_state_size: 2\n")
    with pytest.raises(MsckfInputError, match="max_cam_state_size"):
        load_config(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(MsckfInputError, match="mapping"):
        load_config(p)
    with pytest.raises(MsckfInputError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(MsckfInputError, match="chi2_dof"):
        load_config({"chi2_dof": "rows"})
    with pytest.raises(MsckfInputError, match="feature_noise"):
        load_config({"feature_noise": "a lot"})
