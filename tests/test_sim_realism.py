"""Realism measurements: SGBM on a rendered pair agrees with the exact depth where it gives depth (the two
images are geometrically consistent), hole causes partition the holes, and KLT track lengths are measured."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.calibration import rig_from_camchain
from pipeline.depth import DepthParams
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.sim.mount import mount_transform
from pipeline.sim.presets import get_preset
from pipeline.sim.realism import HOLE_CLASSES, analyse_frame, gallery_png, klt_track_lengths
from pipeline.sim.render import LABEL_SKY
from pipeline.sim.trajectory import RobotTrajectory
from pipeline.sim.workers import FrameJob, FrameRenderer

RIG = rig_from_camchain(ROSARIO_CAMCHAIN)


@pytest.fixture(scope="module")
def rendered():
    cfg = get_preset("rosario-like-03")
    fr = FrameRenderer(RIG, cfg, world_seed=2, seed=2)
    fr.right_depth = True
    traj = RobotTrajectory(cfg, fr.renderer.terrain, mount_transform(RIG, cfg.camera.tilt_deg,
                                                                     cfg.camera.imu_position_m), 2)
    out, _ = fr.render(FrameJob(0, 6.0, traj.pose_imu(6.0), 0.45))
    return out


def test_sgbm_agrees_with_exact_depth_and_holes_are_classified(rendered) -> None:
    params = DepthParams()
    fr, d, causes = analyse_frame(0, RIG, rendered.left_bgr, rendered.right_bgr, rendered.depth, rendered.label,
                                  rendered.glare, params, rendered.right_depth)
    # stereo consistency of the renderer: sub-pixel disparity agreement where SGBM gives depth ...
    assert np.median(fr.disp_err_px) < 0.5
    # ... and, away from depth edges and leaves' fattening (locally planar truth), no bias and few outliers
    fb = RIG.fx * RIG.baseline
    gt_disp = np.where(np.isfinite(rendered.depth), fb / rendered.depth, 0).astype(np.float32)
    planar = cv2.dilate(np.abs(cv2.Laplacian(gt_disp, cv2.CV_32F, ksize=1)), np.ones((7, 7), np.uint8)) < 0.3
    m = d.valid & planar & np.isfinite(rendered.depth)
    err = fb / d.depth_m[m] - gt_disp[m]
    assert m.sum() > 5000
    assert abs(np.median(err)) < 0.1 and np.median(np.abs(err)) < 0.3 and np.mean(np.abs(err) > 1) < 0.08
    # every hole pixel has exactly one cause, no valid pixel has one
    assert sum(fr.hole_causes.values()) == pytest.approx(fr.hole_ratio, abs=1e-12)
    assert np.all((causes >= 0) == ~d.valid)
    sky_holes = (rendered.label == LABEL_SKY) & ~d.valid
    assert np.all(causes[sky_holes] == HOLE_CLASSES.index("sky"))
    band = ~d.valid[:, : params.num_disparities] & (rendered.label[:, : params.num_disparities] != LABEL_SKY)
    assert np.all(np.isin(causes[:, : params.num_disparities][band],
                          [HOLE_CLASSES.index("far"), HOLE_CLASSES.index("border")]))
    assert 0.1 < fr.hole_ratio < 0.8
    assert fr.fast_corners > 200
    png = gallery_png(rendered.left_bgr, rendered.right_bgr, rendered.depth, d.depth_m, causes, "test")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_klt_track_lengths_on_a_sliding_texture() -> None:
    rng = np.random.default_rng(0)
    base = (rng.random((420, 760)) * 255).astype(np.uint8)
    base = cv2.GaussianBlur(base, (0, 0), 1.5)
    frames = [np.ascontiguousarray(base[20:396, 40 + k:712 + k]) for k in range(12)]  # 1 px/frame to the left
    stats = klt_track_lengths(frames)
    assert stats["tracks"] > 100
    assert stats["median"] >= 10  # almost every corner survives the whole 12-frame run
    static = klt_track_lengths([frames[0]] * 5)
    assert static["median"] == 5
