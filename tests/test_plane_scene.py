"""The exact plane renderer of pipeline/plane_scene.py: a rendered point lands on its projection, and the rectified
depth of a wall matches the geometry."""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.plane_scene import Plane, make_texture, pose, rectified_depth, render, scene_rig, world_points


def test_rendered_point_lands_on_its_projection():
    rig = scene_rig()
    plane = Plane.wall(3.0, make_texture(0, 1024), 0.02)   # < 1 texel per pixel: plain bilinear sampling
    T0 = pose((0.02, -0.03, 0.01), (0.1, 0.0, 0.2))
    img0 = render(rig.left, T0, plane)
    px = np.array([[100.0, 80.0], [340.0, 200.0], [600.0, 300.0]])
    pts = world_points(rig.left, T0, px, plane)
    # The same world points re-projected must give the pixels back, and the texture value there is the pixel's.
    pc = pts @ T0[:3, :3].T + T0[:3, 3]
    assert np.allclose(rig.left.project(pc), px, atol=1e-6)
    tex = plane.texel(pts)
    expected = cv2.remap(plane.texture, tex[:, :1].astype(np.float32), tex[:, 1:].astype(np.float32),
                         cv2.INTER_LINEAR).ravel()
    assert np.allclose(img0[px[:, 1].astype(int), px[:, 0].astype(int)], np.rint(expected), atol=1)


def test_rectified_depth_of_a_wall_matches_the_geometry():
    rig = scene_rig()
    plane = Plane.wall(4.0, make_texture(0, 256), 0.05)
    depth = rectified_depth(rig, np.eye(4), plane)
    # At the identity pose the wall is Z = 4 in cam0; in the rectified frame Z varies slightly with R_left.
    px = np.array([[50.0, 60.0], [300.0, 200.0]])
    rays = np.concatenate([(px - [rig.cx, rig.cy]) / rig.fx, np.ones((2, 1))], axis=1) @ rig.R_left
    z_cam0 = 4.0
    z_rect = z_cam0 / rays[:, 2]
    assert np.allclose(depth[px[:, 1].astype(int), px[:, 0].astype(int)], z_rect, rtol=1e-6)
