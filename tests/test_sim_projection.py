"""Renderer geometry: a 3-D point lands where the calibration says in both raw images (sub-pixel), the exact
depth there equals its depth, and every ground-truth depth pixel lies on the surface it claims to show."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.calibration import rig_from_camchain
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.sim.mount import camera_poses, mount_transform
from pipeline.sim.presets import get_preset
from pipeline.sim.render import LABEL_LEAF, LABEL_SKY, LABEL_SOIL, FieldRenderer
from pipeline.sim.world import MAT_WEED, PolySet

RIG = rig_from_camchain(ROSARIO_CAMCHAIN)


@pytest.fixture(scope="module")
def scene():
    cfg = get_preset("tiny")
    r = FieldRenderer(RIG, cfg.field, cfg.lighting, cfg.camera, cfg.render, seed=4, threads=1)
    T_BI = mount_transform(RIG, cfg.camera.tilt_deg, cfg.camera.imu_position_m)
    T_FB = np.eye(4)
    yaw = np.radians(80.0)
    T_FB[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    T_FB[:3, 3] = (24 * 0.52 + 0.1, 6.0, 0.0)
    T_FI = T_FB @ T_BI
    T_L, T_R = camera_poses(T_FI, RIG)
    # magenta squares 1.6-1.9 m away, facing the rectified cameras, at 3 x 3 directions around 5° above the left
    # optical axis (so their edges fall at different sub-pixel phases); the first one is the reference point
    points = []
    for x_rect, elev_deg, dist in ((0.08, 5, 1.6), (0.0, 5, 1.7), (0.16, 5, 1.8), (0.08, 2, 1.75), (0.08, 8, 1.65),
                                   (0.0, 2, 1.6), (0.16, 8, 1.7), (0.0, 8, 1.85), (0.16, 2, 1.6)):
        ray = np.array([x_rect, -np.sin(np.radians(elev_deg)), np.cos(np.radians(elev_deg))])
        points.append(T_L[:3, :3] @ (dist * ray) + T_L[:3, 3])
    e1, e2 = T_L[:3, 0], T_L[:3, 1]
    half = 0.025
    verts = np.array([[q - half * e1 - half * e2, q + half * e1 - half * e2, q + half * e1 + half * e2,
                       q - half * e1 + half * e2] for q in points])
    n = len(points)
    r.extra_polys = PolySet(verts, np.array(points), np.tile(e1, (n, 1)), np.tile(e2, (n, 1)),
                            np.tile(np.cross(e1, e2), (n, 1)), np.full(n, 0.1),
                            np.tile(np.array([[0.8, 0.0, 0.8]], np.float32), (n, 1)), np.full(n, MAT_WEED, np.uint8),
                            np.zeros(n, np.float32), np.zeros(n))
    p = points[0]
    zeros = np.zeros((376, 672, 3), np.float32)
    frame = r.render_frame(T_FI, 1.0, 0.6, 3.0, zeros, zeros, right_depth=True)
    return r, frame, p, T_FI, T_L, T_R, np.array(points)


def _magenta_centroid(bgr: np.ndarray, near: np.ndarray, radius: int = 11) -> np.ndarray:
    """Magenta-weighted centroid (column, row) of the pixels within ``radius`` px of ``near``."""
    img = bgr.astype(np.float64)
    m = np.clip(np.minimum(img[..., 0], img[..., 2]) - img[..., 1] - 20.0, 0, None)
    ys, xs = np.mgrid[:m.shape[0], :m.shape[1]]
    m[(np.abs(xs - near[0]) > radius) | (np.abs(ys - near[1]) > radius)] = 0
    assert m.sum() > 0, "marker not visible"
    ys, xs = np.nonzero(m)
    w = m[ys, xs]
    return np.array([np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()])


def test_point_projects_where_the_calibration_says(scene) -> None:
    """Each marker's centroid lies within pixel quantisation of its projection, in the raw images and in the
    exact rectified depth, and the mean offset over nine markers whose edges fall at different sub-pixel phases
    (a systematic projection error) is a fraction of a pixel.

    The renderer point-samples without anti-aliasing, twice: the polygon raster is filled at rectified pixel
    centres and each raw pixel reads its nearest raster pixel, so one marker's centroid can move by up to about
    half a pixel (measured: up to 0.69 px in the raw images, 0.45 px in the rectified depth, the same before and
    after the renderer's kernels were compiled). Measured mean offsets: depth (-0.06, 0.00) px left and
    (-0.12, 0.00) px right; raw images (-0.19, -0.07) px and (-0.37, -0.15) px (shading and the optics blur move
    the magenta-weighted centroid too). A half-pixel convention error or a wrong distortion model would shift all
    nine the same way by more.
    """
    r, frame, p, T_FI, T_L, T_R, points = scene
    for bgr, T_cam_imu, cam in ((frame.left_bgr, RIG.T_left_imu, RIG.left),
                                (frame.right_bgr, RIG.T_right_imu, RIG.right)):
        T_cam_F = T_cam_imu @ np.linalg.inv(T_FI)
        expected = cam.project(points @ T_cam_F[:3, :3].T + T_cam_F[:3, 3])
        err = np.array([_magenta_centroid(bgr, e) - e for e in expected])
        assert np.all(np.linalg.norm(err, axis=1) < 0.8), err
        assert np.linalg.norm(err.mean(axis=0)) < 0.5, err.mean(axis=0)
    ys, xs = np.mgrid[:376, :672]
    for depth, T in ((frame.depth, T_L), (frame.right_depth, T_R)):
        T_rect_F = np.linalg.inv(T)
        err = []
        for q in points @ T_rect_F[:3, :3].T + T_rect_F[:3, 3]:
            u = RIG.fx * q[0] / q[2] + RIG.cx
            v = RIG.P_left[1, 1] * q[1] / q[2] + RIG.cy
            m = (np.abs(depth - q[2]) < 1e-3) & (np.abs(xs - u) < 11) & (np.abs(ys - v) < 11)
            err.append([xs[m].mean() - u, ys[m].mean() - v])
        err = np.array(err)
        assert np.all(np.linalg.norm(err, axis=1) < 0.6), err
        assert np.linalg.norm(err.mean(axis=0)) < 0.25, err.mean(axis=0)


def test_exact_depth_at_the_point_equals_its_depth(scene) -> None:
    r, frame, p, T_FI, T_L, T_R, points = scene
    for depth, label, T in ((frame.depth, frame.label, T_L), (frame.right_depth, frame.right_label, T_R)):
        q = np.linalg.inv(T)[:3, :3] @ p + np.linalg.inv(T)[:3, 3]  # point in the rectified camera
        u = RIG.fx * q[0] / q[2] + RIG.cx
        v = RIG.P_left[1, 1] * q[1] / q[2] + RIG.cy
        ui, vi = int(round(u)), int(round(v))
        assert label[vi, ui] == LABEL_LEAF  # the marker is drawn as a leaf-like polygon
        # the square faces the rectified cameras: its depth is constant, equal to the point's Z
        assert depth[vi - 2:vi + 3, ui - 2:ui + 3] == pytest.approx(np.full((5, 5), q[2]), abs=1e-5)
    # stereo: the rectified disparity of the point is fx·b/Z
    ql = np.linalg.inv(T_L)[:3, :3] @ p + np.linalg.inv(T_L)[:3, 3]
    qr = np.linalg.inv(T_R)[:3, :3] @ p + np.linalg.inv(T_R)[:3, 3]
    assert RIG.fx * (ql[0] / ql[2] - qr[0] / qr[2]) == pytest.approx(RIG.fx * RIG.baseline / ql[2], rel=1e-5)


def test_every_depth_pixel_lies_on_the_surface_it_shows(scene) -> None:
    r, frame, p, T_FI, T_L, T_R, points = scene
    v, u = np.nonzero(np.isfinite(frame.depth))
    z = frame.depth[v, u].astype(np.float64)
    pts = np.stack([(u - RIG.cx) / RIG.fx * z, (v - RIG.cy) / RIG.P_left[1, 1] * z, z], 1)
    world = pts @ T_L[:3, :3].T + T_L[:3, 3]
    soil = frame.label[v, u] == LABEL_SOIL
    mid = 0.5 * (T_L[:3, 3] + T_R[:3, 3])
    dist = np.hypot(world[:, 0] - mid[0], world[:, 1] - mid[1])
    near = soil & (dist < 30)
    wu, wr = r.terrain.lod_weights(dist[near])
    h, _, _ = r.terrain.height_grad(world[near, 0], world[near, 1], (wu, wr))
    err = np.abs(world[near, 2] - h)
    assert near.sum() > 10_000
    assert np.percentile(err, 99) < 1e-3 and err.max() < 5e-3
    assert np.all(frame.label[np.isinf(frame.depth)] == LABEL_SKY)


def test_raw_rays_reproject_to_their_pixels() -> None:
    cfg = get_preset("tiny")
    r = FieldRenderer(RIG, cfg.field, cfg.lighting, cfg.camera, cfg.render, seed=4, threads=1)
    for view, cam in ((r.left, RIG.left), (r.right, RIG.right)):
        rays = view.raw_bundle.rays[::17, ::23].reshape(-1, 3).astype(np.float64)
        raw_dirs = rays @ view.R_rect  # back to the raw camera frame (R^T applied to row vectors)
        px = cam.project(raw_dirs)
        vv, uu = np.mgrid[0:376:17, 0:672:23]
        np.testing.assert_allclose(px, np.stack([uu.ravel(), vv.ravel()], 1), atol=2e-3)
