"""Stereo depth stage: rectify → StereoSGBM (left and right) → left-right check → depth in metres + validity.

Invalid pixels are holes (NaN depth, ``valid == False``); this stage never fills them — filling is the
inpainting stage's job. Depth lives in the rectified left camera frame (OpenCV optical: x right, y down,
z forward) and is the Z coordinate in metres: ``Z = fx_rect · baseline / disparity``.

Why these SGBM parameters (672×376 ZED frames of soybean rows; see references/inpaint.md §6):

* ``num_disparities = 64``: with fx·b = 351.06 px × 0.1187 m = 41.7 px·m, 64 px reaches down to Z = 0.65 m —
  the nearest canopy (≈0.5 m tall rows, camera ≈1 m high, 7–19° down) sits at Z ≈ 0.7–1.6 m. More disparities
  would widen the unmatched left border band (``num_disparities`` columns, 9.5 % of the frame at 64) and cost time.
* ``block_size = 5``: leaves at this resolution are 5–30 px; a 5×5 window keeps leaf edges (a larger window
  fattens foreground leaves over the soil behind them) while still averaging sensor noise.
* ``P1 = 8·bs²``, ``P2 = 32·bs²`` (OpenCV's suggested smoothness penalties for one channel): P2 ≫ P1 allows
  the depth jumps between leaves and soil only where the image supports them.
* ``uniqueness_ratio = 10``: repetitive leaf texture gives several near-equal cost minima; 10 % rejects the
  ambiguous ones (they become holes rather than wrong depth).
* ``speckle_window_size = 100``, ``speckle_range = 2``: removes isolated disparity blobs < 100 px whose
  disparity varies by ≤ 2 px — typical mismatches on leaf specularities and soil clods.
* ``pre_filter_cap = 63``: OpenCV's maximum; keeps the x-derivative prefilter from saturating on high-contrast
  sunlit leaves.
* Left-right check: the matcher runs again on the horizontally flipped pair (right as reference), and a left
  pixel survives only if the right disparity at its match differs by at most ``lr_max_diff_px = 1``.
  OpenCV's internal ``disp12MaxDiff`` is disabled because it is an approximation computed from the left
  cost volume only.
* ``min_valid_disparity_px = 1``: depth beyond fx·b/1 ≈ 42 m is noise for a 12 cm baseline and is a hole.
* ``mode = SGBM_3WAY``: the fast 3-direction variant (2 cores); quality close to 5-direction SGBM.

Matching runs on grey images (BGR → grey before rectification, so only one channel is remapped).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from functools import lru_cache

import cv2
import numpy as np

from msckf.camera import StereoRig
from pipeline.depth_mm_kernels import mm_to_metres

#: Bump when the algorithm changes in a way that changes outputs (invalidates depth caches).
DEPTH_STAGE_VERSION = 1

_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
          "hh": cv2.STEREO_SGBM_MODE_HH, "hh4": cv2.STEREO_SGBM_MODE_HH4}


@dataclass(frozen=True)
class DepthParams:
    """Parameters of the depth stage (see the module docstring for why each value).

    Attributes:
        min_disparity: smallest disparity searched, px.
        num_disparities: disparity search range, px (multiple of 16).
        block_size: SGBM matching window side, px (odd).
        p1_per_px2, p2_per_px2: smoothness penalties divided by block_size² (P1 = p1_per_px2·bs²).
        uniqueness_ratio: margin (%) by which the best cost must beat the second best.
        speckle_window_size: largest speckle region (px) removed; 0 disables.
        speckle_range: largest disparity variation (px) inside a connected speckle region.
        pre_filter_cap: clip of the x-derivative prefilter.
        mode: ``"sgbm"``, ``"sgbm_3way"``, ``"hh"`` or ``"hh4"``.
        lr_check: run the left-right consistency check.
        lr_max_diff_px: largest |d_left − d_right| for a pixel to survive the check, px.
        min_valid_disparity_px: smaller disparities (farther than fx·b/this) are holes.
    """

    min_disparity: int = 0
    num_disparities: int = 64
    block_size: int = 5
    p1_per_px2: int = 8
    p2_per_px2: int = 32
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    pre_filter_cap: int = 63
    mode: str = "sgbm_3way"
    lr_check: bool = True
    lr_max_diff_px: float = 1.0
    min_valid_disparity_px: float = 1.0

    def __post_init__(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 1, got {self.block_size}")
        if self.p2_per_px2 <= self.p1_per_px2:
            raise ValueError("P2 must be larger than P1")
        if self.mode not in _MODES:
            raise ValueError(f"mode must be one of {sorted(_MODES)}, got {self.mode!r}")

    def key(self) -> str:
        """Short hash of the parameters, the stage version and the OpenCV version (the depth-cache key)."""
        blob = json.dumps({"params": asdict(self), "version": DEPTH_STAGE_VERSION, "opencv": cv2.__version__},
                          sort_keys=True)
        return hashlib.blake2b(blob.encode(), digest_size=8).hexdigest()


@dataclass(frozen=True)
class DepthFrame:
    """Depth of one stereo frame in the rectified left camera.

    Attributes:
        stamp_ns: left image stamp, ns.  index: stereo frame index in the sequence.
        depth_m: (H, W) float32 depth Z in metres, NaN in holes.
        valid: (H, W) bool, True where depth is measured (== ``isfinite(depth_m)``).
        left_rect_grey: (H, W) uint8 rectified left grey image (what the inpainting sees), or None for a frame
            read from the cache without it (``DepthCache.get(index, grey=False)``).
    """

    stamp_ns: int
    index: int
    depth_m: np.ndarray
    valid: np.ndarray
    left_rect_grey: np.ndarray | None

    @property
    def hole_ratio(self) -> float:
        """Fraction of pixels without depth."""
        return float(1.0 - self.valid.mean())


@lru_cache(maxsize=8)
def _matcher(params: DepthParams) -> cv2.StereoSGBM:
    bs = params.block_size
    return cv2.StereoSGBM_create(
        minDisparity=params.min_disparity, numDisparities=params.num_disparities, blockSize=bs,
        P1=params.p1_per_px2 * bs * bs, P2=params.p2_per_px2 * bs * bs, disp12MaxDiff=-1,
        preFilterCap=params.pre_filter_cap, uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window_size, speckleRange=params.speckle_range, mode=_MODES[params.mode])


def disparity_sgbm(left_grey: np.ndarray, right_grey: np.ndarray, params: DepthParams) -> np.ndarray:
    """Left-reference disparity of a rectified grey pair, (H, W) float32 px, NaN where SGBM gives no match."""
    raw = _matcher(params).compute(left_grey, right_grey)  # int16, 16 × disparity, invalid = (minDisp − 1)·16
    disp = raw.astype(np.float32) / 16.0
    disp[raw < params.min_disparity * 16] = np.nan
    return disp


def disparity_right(left_grey: np.ndarray, right_grey: np.ndarray, params: DepthParams) -> np.ndarray:
    """Right-reference disparity (positive, px, NaN where none): the matcher run on the flipped pair.

    A point at ``x_l`` in the left image and ``x_r = x_l − d`` in the right one; after a horizontal flip the
    right image is on the left and the match has the same positive disparity ``d``.
    """
    flipped = disparity_sgbm(np.ascontiguousarray(right_grey[:, ::-1]), np.ascontiguousarray(left_grey[:, ::-1]),
                             params)
    return np.ascontiguousarray(flipped[:, ::-1])


def left_right_check(disp_left: np.ndarray, disp_right: np.ndarray, max_diff_px: float) -> np.ndarray:
    """Boolean (H, W): True where the left disparity is consistent with the right one at its match.

    Each left pixel ``(y, x)`` with disparity ``d`` is matched to right pixel ``(y, round(x − d))``; it passes if
    that pixel has a disparity and ``|d − d_right| <= max_diff_px``. NaN disparities fail.
    """
    h, w = disp_left.shape
    x = np.arange(w, dtype=np.float32)[None, :]
    xr = np.rint(x - np.nan_to_num(disp_left, nan=-1e6)).astype(np.int64)
    inside = (xr >= 0) & (xr < w) & np.isfinite(disp_left)
    d_r = np.take_along_axis(disp_right, np.clip(xr, 0, w - 1), axis=1)
    with np.errstate(invalid="ignore"):
        return inside & np.isfinite(d_r) & (np.abs(disp_left - d_r) <= max_diff_px)


def depth_from_rectified(left_grey: np.ndarray, right_grey: np.ndarray, fx: float, baseline_m: float,
                         params: DepthParams = DepthParams()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth of an already rectified grey pair.

    Args:
        left_grey, right_grey: (H, W) uint8 rectified images.
        fx: rectified focal length, px.  baseline_m: rectified baseline, m.
    Returns:
        ``(depth_m, valid, disparity)``: (H, W) float32 metres with NaN in holes, bool mask, float32 px
        (NaN in holes).
    """
    if left_grey.shape != right_grey.shape or left_grey.ndim != 2 or left_grey.dtype != np.uint8:
        raise ValueError(f"expected two equal (H, W) uint8 images, got {left_grey.shape} {left_grey.dtype} and "
                         f"{right_grey.shape} {right_grey.dtype}")
    disp = disparity_sgbm(left_grey, right_grey, params)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(disp) & (disp >= params.min_valid_disparity_px)
    if params.lr_check:
        valid &= left_right_check(disp, disparity_right(left_grey, right_grey, params), params.lr_max_diff_px)
    disp = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = (np.float32(fx * baseline_m) / disp).astype(np.float32)
    return depth, valid, disp


def to_grey(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR → (H, W) uint8 grey (OpenCV's BT.601 weights); an (H, W) image is returned as is."""
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def rectify_grey(rig: StereoRig, left_bgr: np.ndarray, right_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw BGR (or grey) pair → rectified grey pair, (H, W) uint8 each."""
    return rig.rectify(to_grey(left_bgr), to_grey(right_bgr))


def compute_depth(rig: StereoRig, left_bgr: np.ndarray, right_bgr: np.ndarray, params: DepthParams = DepthParams(),
                  stamp_ns: int = 0, index: int = 0) -> DepthFrame:
    """Depth of one raw stereo frame: rectify with ``rig``, SGBM, LR check, disparity → metres.

    Args:
        rig: calibration (raw intrinsics/distortion, rectification R/P).
        left_bgr, right_bgr: (H, W, 3) uint8 raw BGR images (grey (H, W) also accepted).
    """
    left_rect, right_rect = rectify_grey(rig, left_bgr, right_bgr)
    depth, valid, _ = depth_from_rectified(left_rect, right_rect, rig.fx, rig.baseline, params)
    return DepthFrame(int(stamp_ns), int(index), depth, valid, left_rect)


# ---- compact storage ---------------------------------------------------------------------------------------------
MM_PER_M = 1000.0
MAX_DEPTH_MM = 65535


def encode_depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """Depth (metres, NaN holes) → uint16 millimetres with 0 = hole (depth ≥ 65.535 m also becomes a hole)."""
    with np.errstate(invalid="ignore"):
        mm = np.rint(np.nan_to_num(depth_m, nan=0.0) * MM_PER_M)
        mm[(mm < 1) | (mm > MAX_DEPTH_MM)] = 0
    return mm.astype(np.uint16)


def decode_depth_mm(depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """uint16 millimetres (0 = hole) → ``(depth_m float32 with NaN holes, valid bool)``, both (H, W).

    depth = float32(mm) / float32(1000), computed in one compiled pass (:mod:`pipeline.depth_mm_kernels`).
    """
    mm = np.asarray(depth_mm)
    if mm.ndim != 2 or mm.dtype != np.uint16:
        raise ValueError(f"a depth map in millimetres must be a 2-D uint16 array, got {mm.dtype} {mm.shape}")
    return mm_to_metres(mm, np.float32(MM_PER_M))


def quantize_mm(frame: DepthFrame) -> tuple[DepthFrame, np.ndarray]:
    """The frame as it comes back from the cache (depth rounded to whole millimetres), and its (H, W) uint16
    millimetre map (0 = hole): what the cache stores, so a caller that stores the frame need not round again."""
    mm = encode_depth_mm(frame.depth_m)
    depth, valid = decode_depth_mm(mm)
    return DepthFrame(frame.stamp_ns, frame.index, depth, valid, frame.left_rect_grey), mm


def quantize(frame: DepthFrame) -> DepthFrame:
    """The frame as it comes back from the cache (depth rounded to whole millimetres).

    ``depth_stream`` yields quantised frames whether they were just computed or read from disk, so results do
    not depend on the cache's state.
    """
    return quantize_mm(frame)[0]
