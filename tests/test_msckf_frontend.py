"""MSCKF front end on exactly rendered synthetic scenes (pipeline/plane_scene.py).

Truth comes from the renderer: the 3-D point behind a feature's first pixel is re-projected into later frames and
into the right camera, so tracking, stereo matching and depth conversion are checked against geometry, not
against the front end's own output.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msckf.errors import MsckfInputError
from msckf.frontend import DepthFrontend, StereoFrontend
from msckf.frontend_config import FrontendConfig
from msckf.frontend_depth import DepthReject, depth_to_stereo, sample_depth
from msckf.frontend_geometry import (
    GyroBuffer,
    camera_rotation,
    epipolar_distance,
    rotate_normalised,
    triangulated_depths,
)
from msckf.frontend_grid import cell_index, top_per_group
from msckf.frontend_replay import RecordedDepthFrontend
from msckf.types import DepthSource
from pipeline.plane_scene import (
    Plane,
    gyro_samples,
    make_texture,
    pose_from,
    rectified_depth,
    render,
    scene_rig,
    stereo_pose,
    world_points,
)

RATE = 15.0
_CFG = FrontendConfig()
#: two_point_ransac's settings as the front end passes them (the config is their one home).
_RANSAC = dict(iterations=_CFG.ransac_iterations, max_motion_px=_CFG.ransac_max_motion_px,
               min_inlier_fraction=_CFG.ransac_min_inlier_fraction,
               degenerate_motion_px=_CFG.ransac_degenerate_motion_px)


def _wall_motion(t: float) -> np.ndarray:
    """T_cam0_world: sideways/forward sway with yaw and roll, in front of a wall 4 m ahead."""
    R = Rotation.from_rotvec([0.01 * np.sin(2 * t), 0.12 * np.sin(1.5 * t), 0.03 * t]).as_matrix()
    return pose_from(R, (0.5 * np.sin(1.2 * t), 0.03 * t, 0.3 * t))


class _Sequence:
    """Rendered frames of a scene + gyro samples, fed into a front end on demand."""

    def __init__(self, planes, pose_fn, frames: int):
        self.rig = scene_rig()
        self.planes = planes
        self.pose_fn = pose_fn
        self.stamps = [k / RATE for k in range(frames)]
        self.poses = [pose_fn(t) for t in self.stamps]
        self.left = [render(self.rig.left, T, planes) for T in self.poses]
        self.right = [render(self.rig.right, stereo_pose(self.rig, T), planes) for T in self.poses]
        self.depth = [rectified_depth(self.rig, T, planes) for T in self.poses]
        self.imu = gyro_samples(pose_fn, -0.05, self.stamps[-1], 150.0, self.rig.T_left_imu[:3, :3])

    def run(self, fe, frames: int | None = None, depth: bool = False, right=None, depth_maps=None, left=None):
        """Feed the sequence; returns [(obs, debug)] per frame. ``depth_maps``: (depth, valid) per frame; ``left`` /
        ``right``: images replacing the rendered ones."""
        out, j = [], 0
        for k, t in enumerate(self.stamps[:frames]):
            while j < len(self.imu) and self.imu[j][0] <= t:
                fe.add_imu(*self.imu[j])
                j += 1
            if depth_maps is not None:
                obs = fe.process(t, (left or self.left)[k], *depth_maps[k])
            elif depth:
                d = self.depth[k]
                obs = fe.process(t, (left or self.left)[k], np.nan_to_num(d), np.isfinite(d))
            else:
                obs = fe.process(t, (left or self.left)[k], (right or self.right)[k])
            out.append((obs, fe.last_debug))
        return out


@pytest.fixture(scope="module")
def wall_seq() -> _Sequence:
    return _Sequence([Plane.wall(4.0, make_texture(3, 2048), 0.004)], _wall_motion, 8)


def _truth_pixels(seq: _Sequence, first: dict, k: int, ids: np.ndarray) -> np.ndarray:
    pts = np.array([first[i] for i in ids])
    T = seq.poses[k]
    return seq.rig.left.project(pts @ T[:3, :3].T + T[:3, 3])


# ---- config --------------------------------------------------------------------------------------------------------
def test_config_defaults_are_the_rosario_launch_values_and_bad_values_are_rejected():
    c = FrontendConfig()
    assert (c.grid_row, c.grid_col, c.grid_min_feature_num, c.grid_max_feature_num) == (4, 5, 30, 50)
    assert (c.pyramid_levels, c.patch_size, c.fast_threshold, c.max_iteration) == (3, 15, 10, 30)
    assert (c.track_precision, c.ransac_threshold, c.stereo_threshold) == (0.01, 3.0, 5.0)
    assert c.ransac_iterations == 7
    assert FrontendConfig.from_mapping({"grid_row": 2}).grid_row == 2
    with pytest.raises(MsckfInputError, match="grid_max_feature_num"):
        FrontendConfig(grid_min_feature_num=10, grid_max_feature_num=5)
    with pytest.raises(MsckfInputError, match="patch_size"):
        FrontendConfig(patch_size=14)
    with pytest.raises(MsckfInputError, match="cfg.yaml.*grid_rows"):
        FrontendConfig.from_mapping({"grid_rows": 2}, source="cfg.yaml")
    with pytest.raises(MsckfInputError, match="depth_sampling"):
        FrontendConfig(depth_sampling="cubic")


# ---- geometry units --------------------------------------------------------------------------------------------------
def test_gyro_integration_of_a_constant_rate_is_the_exponential_and_rotates_into_the_camera():
    buf = GyroBuffer()
    w = np.array([0.3, -0.2, 0.5])
    for t in np.arange(0.0, 1.0, 1 / 142):
        buf.add(t, w)
    R = buf.rotation_imu(0.1234, 0.1234 + 1 / 15)
    assert np.allclose(R, Rotation.from_rotvec(w / 15).as_matrix(), atol=1e-12)
    # A camera rotated w.r.t. the IMU sees the rate rotated into its frame; R_c_p is the inverse motion.
    R_ci = Rotation.from_rotvec([0.4, 1.0, -0.3]).as_matrix()
    R_c_p = camera_rotation(R, R_ci)
    assert np.allclose(R_c_p, Rotation.from_rotvec(-(R_ci @ w) / 15).as_matrix(), atol=1e-12)
    buf.drop_before(0.5)
    assert len(buf) < 80 and np.allclose(buf.rotation_imu(0.6, 0.7), Rotation.from_rotvec(w * 0.1).as_matrix())
    with pytest.raises(ValueError):
        buf.add(0.1, w)


def test_infinite_homography_predicts_pure_rotation_exactly():
    rig = scene_rig()
    rng = np.random.default_rng(0)
    pts = rng.uniform([-2, -1, 2], [2, 1, 8], (50, 3))
    R = Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix()   # R_c_p: previous → current camera
    xy_prev = pts[:, :2] / pts[:, 2:]
    pred = rig.left.project(np.c_[rotate_normalised(xy_prev, R), np.ones(50)])
    assert np.allclose(pred, rig.left.project(pts @ R.T), atol=1e-9)


def test_epipolar_distance_and_triangulation_on_exact_stereo_points():
    rig = scene_rig()
    R, t = rig.T_right_left[:3, :3], rig.T_right_left[:3, 3]
    pts = np.random.default_rng(1).uniform([-2, -1, 1], [2, 1, 10], (40, 3))
    p1 = pts @ R.T + t
    xy0, xy1 = pts[:, :2] / pts[:, 2:], p1[:, :2] / p1[:, 2:]
    assert np.max(epipolar_distance(xy0, xy1, R, t)) < 1e-12
    z0, z1 = triangulated_depths(xy0, xy1, R, t)
    assert np.allclose(z0, pts[:, 2]) and np.allclose(z1, p1[:, 2])
    # A vertical shift of 5 px in cam1 is a 5 px epipolar error (the lines are near-horizontal).
    d = epipolar_distance(xy0, xy1 + [0.0, 5.0 / rig.right.fy], R, t) * rig.right.fy
    assert np.allclose(d, 5.0, atol=0.1)


def test_two_point_ransac_removes_injected_outliers_and_is_seeded():
    from msckf.frontend_geometry import two_point_ransac
    rng = np.random.default_rng(5)
    f = 350.0
    pts = rng.uniform([-3, -2, 2], [3, 2, 12], (300, 3))
    R = Rotation.from_rotvec([0.01, 0.04, -0.02]).as_matrix()
    t = np.array([0.15, 0.02, 0.3])
    xy_prev = pts[:, :2] / pts[:, 2:]
    pc = pts @ R.T + t
    xy_curr = pc[:, :2] / pc[:, 2:] + rng.normal(0, 0.3 / f, (300, 2))
    bad = rng.choice(300, 60, replace=False)
    xy_curr[bad] += rng.uniform(-25, 25, (60, 2)) / f
    # Outliers that happen to slide along their epipolar line cannot be detected: judge only the others.
    E_dist = epipolar_distance(rotate_normalised(xy_prev, R), xy_curr, np.eye(3), t) * f
    detectable = np.zeros(300, bool)
    detectable[bad] = E_dist[bad] > 6.0
    inl = two_point_ransac(xy_prev, xy_curr, R, f, 3.0, np.random.default_rng(0), **_RANSAC)
    good = np.setdiff1d(np.arange(300), bad)
    assert inl[good].mean() > 0.98
    assert not inl[detectable].any()
    assert detectable.sum() > 40
    again = two_point_ransac(xy_prev, xy_curr, R, f, 3.0, np.random.default_rng(0), **_RANSAC)
    assert np.array_equal(inl, again)
    # No translation (degenerate): points that moved more than the threshold are outliers.
    xy_rot = rotate_normalised(xy_prev, R)
    xy_rot[:10] += 10.0 / f
    inl = two_point_ransac(xy_prev, xy_rot, R, f, 3.0, np.random.default_rng(0), **_RANSAC)
    assert not inl[:10].any() and inl[10:].all()


def test_grid_helpers():
    px = np.array([[0.0, 0.0], [671.9, 375.9], [134.3, 93.9], [134.5, 94.0]])
    assert cell_index(px, 672, 376, 4, 5).tolist() == [0, 19, 0, 6]
    group = np.array([0, 0, 0, 1, 1, 2])
    key = np.array([1.0, 3.0, 2.0, 5.0, 5.0, 0.0])
    assert top_per_group(group, key, np.array([2, 1, 0])).tolist() == [1, 2, 3]


# ---- stereo front end --------------------------------------------------------------------------------------------
def test_tracks_follow_the_known_motion_to_subpixel(wall_seq):
    fe = StereoFrontend(FrontendConfig(), wall_seq.rig, wall_seq.rig.T_left_imu, seed=0)
    frames = wall_seq.run(fe)
    obs0, dbg0 = frames[0]
    assert len(obs0) > 400
    first = dict(zip(dbg0.ids, world_points(wall_seq.rig.left, wall_seq.poses[0], dbg0.cam0_px, wall_seq.planes)))
    for k in (1, len(frames) - 1):
        obs, dbg = frames[k]
        ids = np.array([i for i in obs.ids if i in first])
        assert len(ids) > 0.7 * len(obs0)
        sel = np.isin(obs.ids, ids)
        err = np.linalg.norm(dbg.cam0_px[sel] - _truth_pixels(wall_seq, first, k, obs.ids[sel]), axis=1)
        assert np.median(err) < 0.1 and np.percentile(err, 90) < 0.5
        # Published normalised coordinates are the undistorted pixels.
        assert np.allclose(obs.cam0_xy, wall_seq.rig.left.undistort_points(dbg.cam0_px), atol=1e-9)
        assert np.all(obs.track_length[sel] == k + 1)
    # Ids are unique and tracks only get longer.
    obs, _ = frames[-1]
    assert len(np.unique(obs.ids)) == len(obs.ids)


def test_stereo_matches_satisfy_the_epipolar_constraint_and_give_the_right_depth(wall_seq):
    rig = wall_seq.rig
    fe = StereoFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    for obs, dbg in wall_seq.run(fe, frames=3):  # noqa: B007 (the last frame's debug is checked below)
        assert np.all(obs.source == DepthSource.STEREO_MATCH) and np.all(np.isnan(obs.depth_m))
        R, t = rig.T_right_left[:3, :3], rig.T_right_left[:3, 3]
        epi = epipolar_distance(obs.cam0_xy, obs.cam1_xy, R, t) * 0.5 * (rig.right.fx + rig.right.fy)
        assert epi.max() <= 5.0 and np.median(epi) < 0.2
    # Depth of the last frame's matches against the rendered geometry.
    k = 2
    T = wall_seq.poses[k]
    pts = world_points(rig.left, T, dbg.cam0_px, wall_seq.planes)
    pc = pts @ T[:3, :3].T + T[:3, 3]
    z0, _ = triangulated_depths(obs.cam0_xy, obs.cam1_xy, R, t)
    rel = np.abs(z0 / pc[:, 2] - 1)
    assert np.median(rel) < 0.005 and np.percentile(rel, 95) < 0.03
    truth1 = rig.right.project(pc @ R.T + t)
    px_err = np.linalg.norm(dbg.cam1_px - truth1, axis=1)
    assert np.median(px_err) < 0.1


def test_ransac_in_the_front_end_drops_features_on_an_independently_moving_board():
    wall = Plane.wall(4.0, make_texture(3, 2048), 0.004)
    # A 1 m board 2 m ahead that slides down by 0.1 m between the frames: its corners do not move with the
    # camera, so they are outliers to the ego-motion (the camera moves mostly sideways, so the epipolar lines
    # are near-horizontal and a vertical slide leaves them; a sideways slide would be undetectable).
    board_tex = make_texture(4, 512)
    rig = scene_rig()
    fe = StereoFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    stamps = [0.0, 1 / RATE]
    poses = [_wall_motion(t) for t in stamps]
    shift = [0.0, 0.1]
    for t in gyro_samples(_wall_motion, -0.05, stamps[-1], 150.0, rig.T_left_imu[:3, :3]):
        fe.add_imu(*t)
    frames = []
    for t, T, s in zip(stamps, poses, shift):
        board = Plane(np.array([0.0, 0.0, 1.0]), 2.0, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                      board_tex, 0.002)
        Tb = T @ np.array([[1, 0, 0, 0], [0, 1, 0, s], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        left = _composite(rig.left, T, wall, Tb, board)
        right = _composite(rig.right, stereo_pose(rig, T), wall, stereo_pose(rig, Tb), board)
        fe.process(t, left, right)
        frames.append(fe.last_debug)
    d0, d1 = frames
    T0 = poses[0]
    on_board = _on_board(rig, T0, d0.cam0_px)
    board_ids = d0.ids[on_board]
    assert len(board_ids) > 40   # features well inside the board (its edges mix both motions)
    survived_board = np.isin(board_ids, d1.ids).mean()
    wall_ids = d0.ids[~on_board]
    survived_wall = np.isin(wall_ids, d1.ids).mean()
    assert survived_board < 0.1
    assert survived_wall > 0.9
    assert d1.counts["ransac_ok"] < d1.counts["stereo_ok"]


_BOARD_HALF = 0.5  # metres


def _composite(camera, T_cam_world, wall: Plane, T_cam_board, board: Plane) -> np.ndarray:
    """Wall + a 1 m × 1 m board at Z = 2 in the board's own frame (pose ``T_cam_board``), z-buffered."""
    img_wall = render(camera, T_cam_world, wall)
    img_board = render(camera, T_cam_board, board)
    # Board extent: rays hitting the board plane inside |x|, |y| < 0.5 m (board frame).
    from pipeline.plane_scene import _pixel_rays
    T_bc = np.linalg.inv(T_cam_board)
    dirs = _pixel_rays(camera) @ T_bc[:3, :3].T
    lam, pts = board.intersect(T_bc[:3, 3], dirs)
    inside = (lam > 0) & (np.abs(pts[..., 0]) < _BOARD_HALF) & (np.abs(pts[..., 1]) < _BOARD_HALF)
    return np.where(inside, img_board, img_wall)


def _on_board(rig, T_cam_board, px: np.ndarray, margin: float = 0.06) -> np.ndarray:
    T_bc = np.linalg.inv(T_cam_board)
    dirs = rig.left.unproject(px) @ T_bc[:3, :3].T
    board = Plane(np.array([0.0, 0.0, 1.0]), 2.0, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                  np.zeros((2, 2), np.float32), 1.0)
    lam, pts = board.intersect(T_bc[:3, 3], dirs)
    lim = _BOARD_HALF - margin
    return (lam > 0) & (np.abs(pts[:, 0]) < lim) & (np.abs(pts[:, 1]) < lim)


def test_failed_stereo_matches_are_dropped_or_kept_as_mono(wall_seq):
    rig = wall_seq.rig
    # Right images shifted 20 px down: KLT finds the texture but every match breaks the epipolar constraint.
    bad_right = [np.roll(img, 20, axis=0) for img in wall_seq.right]
    right = [wall_seq.right[0], bad_right[1]]
    fe = StereoFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    (o0, _), (o1, d1) = wall_seq.run(fe, frames=2, right=right)
    assert d1.counts["stereo_ok"] < 0.05 * len(o0)
    assert not np.isin(o0.ids, o1.ids).any()        # S-MSCKF: unmatched tracks are dropped
    fe = StereoFrontend(FrontendConfig(stereo_keep_mono=True), rig, rig.T_left_imu, seed=0)
    (o0, _), (o1, d1) = wall_seq.run(fe, frames=2, right=right)
    kept = np.isin(o1.ids, o0.ids)
    assert kept.sum() > 0.9 * len(o0)
    assert np.mean(o1.source[kept] == DepthSource.MONO) > 0.95
    mono = o1.source == DepthSource.MONO
    assert np.all(np.isnan(o1.cam1_xy[mono])) and np.all(np.isfinite(o1.cam1_xy[~mono]))


def test_same_seed_gives_bit_identical_output(wall_seq):
    def run(seed, variant):
        rig = wall_seq.rig
        if variant == "stereo":
            fe = StereoFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=seed)
            return wall_seq.run(fe, frames=4)
        fe = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=seed)
        return wall_seq.run(fe, frames=4, depth=True)

    for variant in ("stereo", "depth"):
        a, b = run(11, variant), run(11, variant)
        for (oa, _), (ob, _) in zip(a, b):
            for name in ("ids", "cam0_xy", "cam1_xy", "depth_m", "source", "track_length"):
                np.testing.assert_array_equal(getattr(oa, name), getattr(ob, name))   # NaN == NaN here


def test_grid_caps_and_detection_mask_are_respected(wall_seq):
    rig = wall_seq.rig
    cfg = FrontendConfig(grid_min_feature_num=6, grid_max_feature_num=8)
    fe = StereoFrontend(cfg, rig, rig.T_left_imu, seed=0)
    frames = wall_seq.run(fe)
    prev_ids = None
    for k, (obs, dbg) in enumerate(frames):
        counts = np.bincount(cell_index(dbg.cam0_px, rig.left.width, rig.left.height, 4, 5), minlength=20)
        assert counts.max() <= 8
        if k == 0:
            assert np.all(counts == 6)            # textured everywhere: every cell filled to the minimum
        else:
            new = ~np.isin(obs.ids, prev_ids)
            old_px = dbg.cam0_px[~new]
            if new.any() and len(old_px):
                # New corners keep S-MSCKF's 5x5 mask (Chebyshev distance > 2 on truncated pixels).
                a = dbg.cam0_px[new].astype(int)
                b = old_px.astype(int)
                cheb = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)
                assert cheb.min() > 2
            # Cells are only topped up to the minimum.
            new_counts = np.bincount(cell_index(dbg.cam0_px[new], rig.left.width, rig.left.height, 4, 5),
                                     minlength=20)
            old_counts = counts - new_counts
            assert np.all(new_counts <= np.maximum(6 - old_counts, 0))
        prev_ids = obs.ids


def test_pruning_keeps_the_longest_lived_features_of_a_full_cell():
    from msckf.frontend import _Tracks
    rig = scene_rig()
    fe = StereoFrontend(FrontendConfig(grid_min_feature_num=2, grid_max_feature_num=3), rig, rig.T_left_imu, 0)
    px = np.array([[10.0, 10], [20, 20], [30, 30], [40, 40], [50, 50], [300, 300]])   # five in cell 0, one in 18
    life = np.array([4, 9, 1, 9, 7, 1], np.int32)
    tr = _Tracks(np.arange(6), px, np.zeros((6, 2)), np.zeros((6, 2)), np.zeros((6, 2)), life)
    kept, n_pruned = fe._prune(tr)
    assert n_pruned == 2 and kept.ids.tolist() == [1, 3, 4, 5]


def test_bad_inputs_raise_msckf_input_errors(wall_seq):
    rig = wall_seq.rig
    fe = StereoFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    left = wall_seq.left[0]
    with pytest.raises(MsckfInputError, match="calibration expects 672x376"):
        fe.process(0.0, left[:-1], wall_seq.right[0])
    with pytest.raises(MsckfInputError, match="uint8"):
        fe.process(0.0, left.astype(np.float32), wall_seq.right[0])
    fe.process(1.0, left, wall_seq.right[0])
    with pytest.raises(MsckfInputError, match="not after"):
        fe.process(1.0, left, wall_seq.right[0])
    with pytest.raises(MsckfInputError, match="gyro"):
        fe.add_imu(1.0, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(MsckfInputError, match="T_cam0_imu"):
        StereoFrontend(FrontendConfig(), rig, np.eye(3), seed=0)
    fd = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    with pytest.raises(MsckfInputError, match="depth map"):
        fd.process(0.0, left, np.zeros((10, 10), np.float32), np.zeros((10, 10), bool))
    with pytest.raises(MsckfInputError, match="validity"):
        fd.process(0.0, left, np.zeros(left.shape, np.float32), np.zeros(left.shape, np.uint8))


# ---- depth front end -----------------------------------------------------------------------------------------------
def test_depth_to_stereo_is_exact_for_a_known_point():
    rig = scene_rig()
    p0 = np.random.default_rng(2).uniform([-2, -1, 1], [2, 1, 12], (30, 3))
    xy0 = p0[:, :2] / p0[:, 2:]
    z_rect = (p0 @ rig.R_left.T)[:, 2]
    z0, xy1 = depth_to_stereo(xy0, z_rect, rig.R_left, rig.T_right_left)
    p1 = p0 @ rig.T_right_left[:3, :3].T + rig.T_right_left[:3, 3]
    assert np.allclose(z0, p0[:, 2], rtol=1e-12)
    assert np.allclose(xy1, p1[:, :2] / p1[:, 2:], atol=1e-12)
    # The rectified pixel used for the look-up is the rig's own rectification of the raw pixel.
    raw = rig.left.project(p0)
    assert np.allclose(rig.rectify_left_normalised(xy0), rig.rectify_left_pixels(raw),
                       atol=1e-6)


def test_depth_frontend_gives_the_exact_cam1_coordinate_of_the_true_point(wall_seq):
    rig = wall_seq.rig
    fd = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    for k, (obs, dbg) in enumerate(wall_seq.run(fd, frames=3, depth=True)):
        has = obs.source == DepthSource.DEPTH_MAP
        assert has.mean() > 0.6
        T = wall_seq.poses[k]
        pc = world_points(rig.left, T, dbg.cam0_px[has], wall_seq.planes) @ T[:3, :3].T + T[:3, 3]
        p1 = pc @ rig.T_right_left[:3, :3].T + rig.T_right_left[:3, 3]
        assert np.allclose(obs.depth_m[has], pc[:, 2], rtol=1e-5)
        assert np.allclose(obs.cam1_xy[has], p1[:, :2] / p1[:, 2:], atol=1e-6)
        # Without depth: MONO, NaN, and the reason is that the rectified pixel is off the (cropped) depth map.
        assert np.all(np.isnan(obs.cam1_xy[~has])) and np.all(np.isnan(obs.depth_m[~has]))
        assert np.all(dbg.depth_reject[~has] == DepthReject.OUTSIDE)


def test_depth_frontend_tracks_do_not_depend_on_the_depth_map(wall_seq):
    rig = wall_seq.rig
    a = wall_seq.run(DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=4), frames=3, depth=True)
    empty = [(np.zeros(d.shape, np.float32), np.zeros(d.shape, bool)) for d in wall_seq.depth[:3]]
    b = [o for o, _ in wall_seq.run(DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=4), frames=3,
                                    depth_maps=empty)]
    for (oa, _), ob in zip(a, b):
        assert np.array_equal(oa.ids, ob.ids) and np.array_equal(oa.cam0_xy, ob.cam0_xy)
        assert np.all(ob.source == DepthSource.MONO)


def test_invalid_edge_and_out_of_range_depth_give_no_depth():
    h, w = 100, 120
    depth = np.full((h, w), 3.0, np.float32)
    valid = np.ones((h, w), bool)
    valid[:, :30] = False                 # a hole
    depth[:, 80:] = 6.0                   # a depth step at column 80
    depth[70:, 40:60] = 50.0              # too far
    px = np.array([[10.0, 10.0],          # in the hole
                   [30.2, 50.0],          # bilinear needs column 30 and 31: 30 is valid, 29 not touched -> OK
                   [29.5, 50.0],          # bilinear touches column 29 (invalid)
                   [79.0, 20.0],          # 1 px left of the step: edge
                   [60.0, 20.0],          # far from the step: OK
                   [95.0, 20.0],          # beyond the step, far from it: OK at 6 m
                   [50.0, 85.0],          # 50 m: out of range
                   [-3.0, 20.0],          # outside the map
                   [np.nan, 1.0]])
    z, why = sample_depth(depth, valid, px, "bilinear", 5, 0.15, 0.3, 20.0)
    assert why.tolist() == [DepthReject.INVALID, DepthReject.OK, DepthReject.INVALID, DepthReject.EDGE,
                            DepthReject.OK, DepthReject.OK, DepthReject.RANGE, DepthReject.OUTSIDE,
                            DepthReject.OUTSIDE]
    assert np.allclose(z[[1, 4, 5]], [3.0, 3.0, 6.0]) and np.all(np.isnan(z[why != DepthReject.OK]))
    # Bilinear interpolation on a ramp is exact; "nearest" reads the rounded pixel.
    ramp = np.tile(np.linspace(2.0, 2.99, w, dtype=np.float32), (h, 1))
    z, why = sample_depth(ramp, np.ones((h, w), bool), np.array([[10.25, 5.0]]), "bilinear", 5, 0.15, 0.3, 20.0)
    assert z[0] == pytest.approx(ramp[5, 10] + 0.25 * (ramp[5, 11] - ramp[5, 10]), rel=1e-6)
    z, _ = sample_depth(ramp, np.ones((h, w), bool), np.array([[10.25, 5.0]]), "nearest", 5, 0.15, 0.3, 20.0)
    assert z[0] == pytest.approx(ramp[5, 10])


def test_patch_depth_sampling_is_the_inverse_mean_depth_of_the_klt_window():
    """``"patch"``: accepted and rejected exactly as ``"bilinear"``; valued ``1 / mean(1 / Z)`` over the valid
    pixels of the KLT window around the rounded pixel — on a plane (1/Z affine in the pixel coordinates) that is
    the plane's depth at the window centre, next to a step it is pulled towards the other side."""
    h, w = 60, 80
    vv, uu = np.mgrid[0:h, 0:w]
    inv = (0.4 + 0.002 * uu + 0.001 * vv).astype(np.float64)               # a slanted plane: 1/Z affine
    plane = (1.0 / inv).astype(np.float32)
    valid = np.ones((h, w), bool)
    valid[20:23, 30:33] = False                                              # a few holes inside one window
    px = np.array([[40.3, 30.0], [31.0, 24.0], [2.0, 2.0], [31.0, 21.0]])
    zb, why_b = sample_depth(plane, valid, px, "bilinear", 5, 0.15, 0.3, 20.0)
    zp, why_p = sample_depth(plane, valid, px, "patch", 5, 0.15, 0.3, 20.0, patch_size=15)
    assert np.array_equal(why_b, why_p) and np.array_equal(np.isnan(zb), np.isnan(zp))
    assert zp[0] == pytest.approx(plane[30, 40], rel=1e-6)                  # full window: the centre pixel's depth
    mask = valid[17:32, 24:39]                                               # window of (31, 24), holes skipped
    assert zp[1] == pytest.approx(1.0 / np.mean(1.0 / plane[17:32, 24:39].astype(np.float64)[mask]), rel=1e-6)
    assert np.isnan(zp[3]) and why_p[3] == DepthReject.INVALID              # a hole at the centre: no depth
    step = np.full((h, w), 2.0, np.float32)
    step[:, 45:] = 2.2                                                       # 10 % step: below the edge threshold
    z_near, _ = sample_depth(step, np.ones((h, w), bool), np.array([[42.0, 30.0]]), "patch", 5, 0.15, 0.3, 20.0,
                             patch_size=15)
    assert 2.0 < z_near[0] < 2.2                                             # the far side is in the window
    with pytest.raises(ValueError, match="patch_size"):
        sample_depth(plane, valid, px, "patch", 5, 0.15, 0.3, 20.0)


def test_depth_frontend_marks_features_on_holes_and_edges_as_mono(wall_seq):
    rig = wall_seq.rig
    d = np.nan_to_num(wall_seq.depth[0])
    valid = np.isfinite(wall_seq.depth[0])
    valid[:, :336] = False                          # left half of the rectified map is a hole
    d = d.copy()
    d[:, 500:] *= 2.0                              # a depth step at rectified column 500
    fd = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    obs = fd.process(0.0, wall_seq.left[0], d, valid)
    dbg = fd.last_debug
    rect = rig.rectify_left_pixels(dbg.cam0_px)
    in_hole = rect[:, 0] < 335.0
    near_step = np.abs(rect[:, 0] - 500) < 1.5
    clear = (rect[:, 0] > 338) & (np.abs(rect[:, 0] - 500) > 3.5) & (rect[:, 0] < 660) & (rect[:, 1] > 3) & \
        (rect[:, 1] < 372)
    assert in_hole.sum() > 50 and near_step.sum() > 0 and clear.sum() > 50
    assert np.all(obs.source[in_hole] == DepthSource.MONO)
    assert np.all(obs.source[near_step] == DepthSource.MONO)
    assert np.all(dbg.depth_reject[near_step] == DepthReject.EDGE)
    assert np.all(obs.source[clear] == DepthSource.DEPTH_MAP)


def test_gyro_prediction_carries_tracks_through_a_fast_rotation():
    # Pure yaw of 12 degrees between two frames (~75 px of flow): the gyro-predicted initial flow puts KLT on the
    # right spot; without IMU samples the tracks are lost (or rejected as > 50 px motions).
    def motion(t: float) -> np.ndarray:
        return pose_from(Rotation.from_rotvec([0.0, np.radians(12.0) * t * RATE, 0.0]).as_matrix(), (0, 0, 0))

    seq = _Sequence([Plane.wall(4.0, make_texture(3, 2048), 0.004)], motion, 2)
    fe = StereoFrontend(FrontendConfig(), seq.rig, seq.rig.T_left_imu, seed=0)
    (o0, d0), (o1, d1) = seq.run(fe)
    first = dict(zip(d0.ids, world_points(seq.rig.left, seq.poses[0], d0.cam0_px, seq.planes)))
    kept = np.isin(o1.ids, o0.ids)
    assert kept.sum() > 0.8 * len(o0)
    err = np.linalg.norm(d1.cam0_px[kept] - _truth_pixels(seq, first, 1, o1.ids[kept]), axis=1)
    assert np.median(err) < 0.1
    seq.imu = []
    fe = StereoFrontend(FrontendConfig(), seq.rig, seq.rig.T_left_imu, seed=0)
    (o0, _), (o1, _) = seq.run(fe)
    assert np.isin(o1.ids, o0.ids).sum() < 0.2 * len(o0)


def test_matching_candidates_in_rounds_selects_what_matching_all_would(wall_seq):
    # S-MSCKF stereo-matches every FAST candidate and keeps the strongest matched ones per cell; the front end
    # matches in rounds. With a right image that breaks about half of the matches, both must pick the same.
    from msckf.frontend import _Tracks
    rig = wall_seq.rig
    cfg = FrontendConfig(grid_min_feature_num=12, grid_max_feature_num=20)
    fe = StereoFrontend(cfg, rig, rig.T_left_imu, seed=0)
    left = wall_seq.left[0]
    right = wall_seq.right[0].copy()
    right[:, ::2] = np.roll(right, 12, axis=0)[:, ::2]   # vertical stripes of a shifted image: many matches fail
    right[::40] = 0
    px, resp, cell = fe._detect_candidates(left, _Tracks.empty())
    cand = fe._new_tracks(px, undistort=False)
    ok_rounds = fe._match_candidates(left, right, _Tracks.empty(), cand, cell)
    _, _, ok_all = fe._stereo_match(left, right, fe._new_tracks(px))
    assert 0.2 < ok_all.mean() < 0.9
    quota = np.full(20, 12)
    pick_all = np.flatnonzero(ok_all)[top_per_group(cell[ok_all], resp[ok_all], quota)]
    pick_rounds = np.flatnonzero(ok_rounds)[top_per_group(cell[ok_rounds], resp[ok_rounds], quota)]
    assert np.array_equal(pick_all, pick_rounds)
    # The first round's width follows the last frame's match rate; whatever the rate, the selection is the same.
    for rate in (0.25, 0.5, 1.0):
        fe._candidate_match_rate = rate
        ok_r = fe._match_candidates(left, right, _Tracks.empty(), fe._new_tracks(px, undistort=False), cell)
        pick_r = np.flatnonzero(ok_r)[top_per_group(cell[ok_r], resp[ok_r], quota)]
        assert np.array_equal(pick_all, pick_r)
    # With a good right image (and the rate it gives), at most two KLT calls and fewer points than matching every
    # candidate.
    calls = []
    klt = fe._klt
    fe._klt = lambda *a: (calls.append(len(a[2])), klt(*a))[1]
    fe._candidate_match_rate = 1.0
    fe._match_candidates(left, wall_seq.right[0], _Tracks.empty(), fe._new_tracks(px, undistort=False), cell)
    assert 1 <= len(calls) <= 2 and sum(calls) < len(px)


def test_depth_frontend_reports_each_features_sigma_and_whether_its_depth_was_measured(wall_seq):
    """The replay and the report tell measured from filled depth per feature: the front end reads the caller's
    measured mask and σ map at the same pixel as the depth (left half measured, right half 'filled')."""
    rig = wall_seq.rig
    d = wall_seq.depth[0]
    valid = np.isfinite(d)
    measured = valid.copy()
    measured[:, d.shape[1] // 2:] = False
    sigma = np.where(measured, 0.01, 0.5).astype(np.float32)
    fd = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    fd.process(wall_seq.stamps[0], wall_seq.left[0], np.nan_to_num(d), valid, sigma, measured)
    dbg = fd.last_debug
    has = np.isfinite(dbg.depth_m)
    assert has.sum() > 20 and dbg.depth_measured is not None
    rect = rig.rectify_left_pixels(dbg.cam0_px)
    right_half = np.rint(rect[:, 0]) >= d.shape[1] // 2
    assert np.all(dbg.depth_measured[has] == ~right_half[has])
    assert np.all(~dbg.depth_measured[~has])                          # no depth: never "measured"
    rel = dbg.depth_sigma_m[has] / dbg.depth_m[has] * d[np.clip(np.rint(rect[has, 1]).astype(int), 0, d.shape[0] - 1),
                                                        np.clip(np.rint(rect[has, 0]).astype(int), 0, d.shape[1] - 1)]
    assert np.allclose(rel, np.where(right_half[has], 0.5, 0.01), rtol=1e-3)
    assert np.all(np.isnan(dbg.depth_sigma_m[~has]))
    fd2 = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=0)
    fd2.process(wall_seq.stamps[0], wall_seq.left[0], np.nan_to_num(d), valid)
    assert fd2.last_debug.depth_measured is None and fd2.last_debug.depth_sigma_m is None


def _sample_depth_loop(depth, valid, px, sampling, window, threshold, lo_m, hi_m):
    """Reference: sample_depth's rules, one feature at a time."""
    h, w = depth.shape
    out, why = np.full(len(px), np.nan), np.full(len(px), DepthReject.OUTSIDE, np.uint8)
    for i, (u, v) in enumerate(px):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        if sampling == "bilinear":
            x0, y0 = int(np.floor(u)), int(np.floor(v))
            if not (x0 >= 0 and y0 >= 0 and x0 + 1 < w and y0 + 1 < h):
                continue
            ax, ay = u - x0, v - y0
            taps = [(y0, x0, (1 - ax) * (1 - ay)), (y0, x0 + 1, ax * (1 - ay)), (y0 + 1, x0, (1 - ax) * ay),
                    (y0 + 1, x0 + 1, ax * ay)]
        else:
            x, y = int(np.rint(u)), int(np.rint(v))
            if not (0 <= x < w and 0 <= y < h):
                continue
            taps = [(y, x, 1.0)]
        why[i] = DepthReject.INVALID
        if not all(valid[y, x] and np.isfinite(depth[y, x]) and depth[y, x] > 0 for y, x, _ in taps):
            continue
        z = sum(float(depth[y, x]) * a for y, x, a in taps)
        cx, cy, half = int(np.clip(np.rint(u), 0, w - 1)), int(np.clip(np.rint(v), 0, h - 1)), window // 2
        win = [float(depth[y, x]) for y in np.clip(np.arange(cy - half, cy + half + 1), 0, h - 1)
               for x in np.clip(np.arange(cx - half, cx + half + 1), 0, w - 1)
               if valid[y, x] and np.isfinite(depth[y, x]) and depth[y, x] > 0]
        if win and (max(win) - min(win)) / z > threshold:
            why[i] = DepthReject.EDGE
        elif not lo_m <= z <= hi_m:
            why[i] = DepthReject.RANGE
        else:
            why[i], out[i] = DepthReject.OK, z
    return out, why


@pytest.mark.parametrize("sampling", ["bilinear", "nearest"])
def test_sample_depth_matches_a_per_feature_reference(sampling):
    """The vectorised depth read (edge window gathered only for features whose depth is good) gives the same
    depth (to rounding) and the same reject reason as the rules applied feature by feature."""
    rng = np.random.default_rng(3)
    h, w = 60, 80
    depth = (2.0 + 0.02 * np.arange(w)[None, :] + 0.01 * np.arange(h)[:, None]).astype(np.float32)
    depth[20:30, 30:50] = 9.0                       # a step: depth edges around it
    depth[:, 70:] = 25.0                            # beyond max_depth_m
    valid = rng.random((h, w)) > 0.15               # holes
    depth[5, 5] = np.nan
    px = np.column_stack([rng.uniform(-3, w + 2, 400), rng.uniform(-3, h + 2, 400)])
    px[:3] = np.nan
    args = (sampling, 5, 0.15, 0.3, 20.0)
    z, why = sample_depth(depth, valid, px, *args)
    z_ref, why_ref = _sample_depth_loop(depth, valid, px, *args)
    assert np.array_equal(why, why_ref)
    assert np.array_equal(np.isnan(z), np.isnan(z_ref)) and np.allclose(z, z_ref, equal_nan=True, rtol=1e-12)
    assert {DepthReject.OK, DepthReject.OUTSIDE, DepthReject.INVALID, DepthReject.EDGE, DepthReject.RANGE} \
        <= set(why.tolist())


def test_fast_detection_per_cell_crops_and_whole_image_agree(wall_seq):
    """detect_fast_in_cells crops the requested cells (few cells) or detects once over the whole image (more
    than half the cells): both give the same corners, responses, cells and order as a plain whole-image FAST
    kept where the mask allows and the cell was requested, grouped cell by cell in the requested order."""
    import cv2

    from msckf.frontend_grid import _detect_fast_whole_image, detect_fast_in_cells, exclusion_mask

    img = wall_seq.left[0]
    h, w = img.shape
    fast = cv2.FastFeatureDetector_create(threshold=10, nonmaxSuppression=True)
    rng = np.random.default_rng(5)
    mask = exclusion_mask(rng.uniform([0, 0], [w, h], (300, 2)), w, h, 2)
    kps = fast.detect(img)
    ref_px = cv2.KeyPoint_convert(kps).astype(np.float64)
    ref_resp = np.array([k.response for k in kps])
    ref_cell = cell_index(ref_px, w, h, 4, 5)
    allowed = mask[ref_px[:, 1].astype(int), ref_px[:, 0].astype(int)] > 0
    many = np.array([2, 5, 6, 8, 9, 10, 11, 12, 13, 17, 18])
    for cells in (np.array([3]), np.array([0, 7, 19]), np.arange(20), many):
        crops = [np.zeros((0, 2))], [np.zeros(0)], [np.zeros(0, np.int64)]
        for c in cells:                                       # one crop-path call per cell, concatenated
            for acc, part in zip(crops, detect_fast_in_cells(fast, img, np.array([c]), mask, 4, 5)):
                acc.append(part)
        crops = [np.concatenate(a) for a in crops]
        whole = _detect_fast_whole_image(fast, img, cells, mask, 4, 5)
        chosen = detect_fast_in_cells(fast, img, cells, mask, 4, 5)
        sel = np.concatenate([np.flatnonzero((ref_cell == c) & allowed) for c in cells])
        for a, b, c, ref in zip(crops, whole, chosen, (ref_px[sel], ref_resp[sel], ref_cell[sel])):
            assert np.array_equal(a, ref) and np.array_equal(b, ref) and np.array_equal(c, ref)
        assert len(sel) > 0


class _Recording:
    """Wraps a DepthFrontend and keeps each frame's ``last_tracks``."""

    def __init__(self, fe: DepthFrontend, out: list) -> None:
        self.fe, self.out = fe, out

    def add_imu(self, *args) -> None:
        self.fe.add_imu(*args)

    def process(self, *args):
        obs = self.fe.process(*args)
        self.out.append(self.fe.last_tracks)
        return obs

    @property
    def last_debug(self):
        return self.fe.last_debug


def test_recorded_tracks_replay_to_identical_observations(wall_seq):
    """A RecordedDepthFrontend fed one seed's recorded tracks gives exactly the live front end's observations,
    with another depth map too (the depth is read at replay); a recording of other images is refused."""
    rig = wall_seq.rig
    live = DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=4)
    recorded = []
    recorder = _Recording(live, recorded)
    wall_seq.run(recorder, frames=5, depth=True)
    noisy = [(np.nan_to_num(d) * 1.02).astype(np.float32) for d in wall_seq.depth[:5]]
    maps = [(z, np.isfinite(d) & (z > 0)) for z, d in zip(noisy, wall_seq.depth[:5])]
    want = wall_seq.run(DepthFrontend(FrontendConfig(), rig, rig.T_left_imu, seed=4), frames=5, depth_maps=maps)
    got = wall_seq.run(RecordedDepthFrontend(FrontendConfig(), rig, rig.T_left_imu, 4, recorded), frames=5,
                       depth_maps=maps)
    assert sum(len(o.ids) for o, _ in want) > 100
    assert sum(int((o.source == DepthSource.DEPTH_MAP).sum()) for o, _ in want) > 100
    for (ow, dw), (og, dg) in zip(want, got):
        for name in ("ids", "cam0_xy", "cam1_xy", "depth_m", "source", "track_length"):
            np.testing.assert_array_equal(getattr(og, name), getattr(ow, name), err_msg=name)
        np.testing.assert_array_equal(dg.cam0_px, dw.cam0_px)
        assert {k: v for k, v in dg.counts.items()} == dw.counts
    shifted = [replace(tr, stamp_s=tr.stamp_s + 1e-3) for tr in recorded]
    fe = RecordedDepthFrontend(FrontendConfig(), rig, rig.T_left_imu, 4, shifted)
    with pytest.raises(MsckfInputError, match="recorded from other images"):
        fe.process(wall_seq.stamps[0], None, *maps[0])
    fe = RecordedDepthFrontend(FrontendConfig(), rig, rig.T_left_imu, 4, recorded[:1])
    fe.process(wall_seq.stamps[0], None, *maps[0])
    with pytest.raises(MsckfInputError, match="end after 1 frame"):
        fe.process(wall_seq.stamps[1], None, *maps[1])


def test_forward_backward_check_drops_tracks_onto_a_surface_that_replaced_theirs():
    # Frame 2: the left half of the image shows another textured wall (a sudden occluder) instead of the one the
    # tracks followed. KLT still "finds" some of them there and a few survive RANSAC; the round trip back into
    # frame 1 does not return to where they came from, so the check drops them all, and keeps the tracks on the
    # unoccluded right half.
    frames = 3
    seq = _Sequence([Plane.wall(4.0, make_texture(3, 2048), 0.004)], _wall_motion, frames)
    occluder = _Sequence([Plane.wall(4.0, make_texture(7, 2048), 0.004)], _wall_motion, frames).left
    half = seq.left[0].shape[1] // 2
    left = [img.copy() for img in seq.left]
    left[-1][:, :half] = occluder[-1][:, :half]
    survived = {}
    for fb_max in (0.0, 0.5):
        fe = DepthFrontend(FrontendConfig(klt_fb_max_px=fb_max), seq.rig, seq.rig.T_left_imu, seed=0)
        (_, before), (_, after) = seq.run(fe, depth=True, left=left)[-2:]
        occluded = before.cam0_px[:, 0] < half - 20     # clear of the seam (KLT window 15 px)
        clear = before.cam0_px[:, 0] > half + 20
        kept = np.isin(before.ids, after.ids)
        survived[fb_max] = (kept[occluded].mean(), kept[clear].mean())
        assert occluded.sum() > 100 and clear.sum() > 100
    assert survived[0.0][0] > 0.03          # without the check, wrong tracks get through
    assert survived[0.5][0] == 0.0          # with it, none
    assert survived[0.5][1] > 0.85          # the unoccluded tracks stay
    assert survived[0.5][1] > survived[0.0][1] - 0.05
