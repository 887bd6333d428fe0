"""Where each logged feature's depth came from, for the replay: mono / measured depth / inpainted depth / stereo.

The VIO's frame log (``frames.npz``) stores msckf's :class:`~msckf.types.DepthSource` per feature: ``MONO``,
``STEREO_MATCH`` or ``DEPTH_MAP``. A depth-map feature of a ``depth-inpainted`` run read a *filled* depth when its
pixel was a hole of the raw SGBM map; that is decided here from the raw validity mask of the raw depth cache (the
depth maps live in the rectified left camera, the features in raw left pixels: rectified with the rig, nearest
pixel, as the front end samples the map).
"""

from __future__ import annotations

import numpy as np

from msckf.camera import StereoRig
from msckf.frontend_depth import nearest_pixel_values
from msckf.types import DepthSource
from pipeline import replay_layout as lay


def feature_classes(source: np.ndarray, uv_raw: np.ndarray, raw_valid: np.ndarray | None = None,
                    rig: StereoRig | None = None, measured: np.ndarray | None = None) -> np.ndarray:
    """(K,) replay feature classes (:data:`pipeline.replay_layout.FEATURE_CLASSES`) of K features.

    Args:
        source: (K,) msckf ``DepthSource`` per feature.
        uv_raw: (K, 2) raw left pixels.
        raw_valid: (h, w) bool validity of the raw depth map of the frame (rectified left camera), for runs whose
            depth map was inpainted; None: every depth-map feature counts as measured.
        rig: the stereo rig (needed with ``raw_valid``).
        measured: (K,) bool, the run's own per-feature "depth was measured" flags (``frames.npz:
            feature_depth_measured``); when given it decides instead of ``raw_valid``.
    """
    src = np.asarray(source).astype(np.int64).reshape(-1)
    out = np.full(src.shape, lay.MONO, dtype=np.uint16)
    out[src == DepthSource.STEREO_MATCH] = lay.STEREO
    dm = src == DepthSource.DEPTH_MAP
    out[dm] = lay.MEASURED_DEPTH
    if measured is not None:
        out[dm & ~np.asarray(measured, dtype=bool).reshape(-1)] = lay.INPAINTED_DEPTH
    elif raw_valid is not None and dm.any():
        if rig is None:
            raise ValueError("feature_classes: a raw validity mask needs the rig (raw → rectified pixels)")
        rect = rig.rectify_left_pixels(np.asarray(uv_raw, dtype=np.float64).reshape(-1, 2)[dm])
        was_hole = nearest_pixel_values(np.asarray(raw_valid, dtype=np.float64), rect) < 0.5
        out[np.flatnonzero(dm)[was_hole]] = lay.INPAINTED_DEPTH
    return out
