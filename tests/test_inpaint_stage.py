"""The pipeline's inpainting stage: known pixels kept, holes filled, the paper's method runs through it."""

import numpy as np

from pipeline.depth import DepthFrame
from pipeline.inpaint_stage import InpaintParams, inpaint_frame


def _frame(h: int = 96, w: int = 128) -> DepthFrame:
    rng = np.random.default_rng(3)
    v = np.arange(h, dtype=np.float32)[:, None]
    depth = np.broadcast_to(2.0 + 0.02 * v, (h, w)).astype(np.float32).copy()  # a slanted ground plane
    valid = np.ones((h, w), bool)
    valid[30:50, 40:70] = False
    valid[rng.random((h, w)) < 0.03] = False
    grey = rng.integers(0, 255, (h, w), dtype=np.uint8)
    return DepthFrame(0, 0, np.where(valid, depth, np.nan).astype(np.float32), valid, grey), depth


def test_paper_method_through_the_stage_fills_holes_and_keeps_known_pixels():
    frame, truth = _frame()
    out = inpaint_frame(frame, InpaintParams(method="paper"))
    assert out.valid.all()
    assert np.array_equal(out.depth_m[frame.valid], frame.depth_m[frame.valid])
    hole = ~frame.valid
    assert np.sqrt(np.mean((out.depth_m[hole] - truth[hole]) ** 2)) < 0.1  # a plane is filled near-exactly


def test_cache_keys_differ_by_method():
    assert InpaintParams(method="paper").key() != InpaintParams(method="telea").key()


def test_inpainted_frames_carry_no_grey_image():
    """Issue 15.5: no method reads the grey guide, and inpainted frames are read for their depth only."""
    frame, _ = _frame()
    assert inpaint_frame(frame, InpaintParams(method="telea")).left_rect_grey is None
