"""Input checks shared by every inpainting method.

Contract (all methods): ``depth`` is a float32 H×W map in metres, ``mask`` a bool H×W map (True = hole), ``guide``
an optional H×W (grey) or H×W×3 (colour) image of the same size. Pixels outside the mask that are not finite
(NaN/inf) or not positive (0 is a common "no depth" code) cannot be used as data either; they are added to the
hole so that the output is finite and positive everywhere. Known pixels (finite, positive, outside the mask) are
never changed by any method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inpaint.errors import InpaintInputError


@dataclass(frozen=True)
class CheckedInput:
    """Validated input. ``hole``: bool H×W, True where a value must be produced (mask ∪ non-finite).
    ``depth``: float32 H×W copy with hole pixels set to 0. ``guide``: float32 H×W grey in [0, 1] or None."""

    depth: np.ndarray
    hole: np.ndarray
    guide: np.ndarray | None


def check_inputs(depth: object, mask: object, guide: object | None = None) -> CheckedInput:
    """Validate the common inputs; raise ``InpaintInputError`` with a clear message on bad input."""
    if not isinstance(depth, np.ndarray):
        raise InpaintInputError(f"depth must be a numpy array, got {type(depth).__name__}")
    if depth.ndim != 2:
        raise InpaintInputError(f"depth must be a 2-D H×W map, got shape {depth.shape}")
    if depth.dtype != np.float32:
        raise InpaintInputError(f"depth must be float32 metres, got dtype {depth.dtype} "
                                "(convert with depth.astype(np.float32); millimetre uint16 → divide by 1000)")
    if not isinstance(mask, np.ndarray):
        raise InpaintInputError(f"mask must be a numpy array, got {type(mask).__name__}")
    if mask.dtype != np.bool_:
        raise InpaintInputError(f"mask must be bool (True = hole), got dtype {mask.dtype}")
    if mask.shape != depth.shape:
        raise InpaintInputError(f"mask shape {mask.shape} does not match depth shape {depth.shape}")
    if min(depth.shape) < 2:
        raise InpaintInputError(f"depth map too small: {depth.shape}")
    finite = np.isfinite(depth)
    if not finite.any():
        raise InpaintInputError("depth map is all NaN/inf: nothing to inpaint from")
    with np.errstate(invalid="ignore"):
        usable = finite & (depth > 0)
    hole = mask | ~usable
    if hole.all():
        raise InpaintInputError("every pixel is a hole (mask all True, or no finite positive depth outside it): "
                                "nothing to inpaint from")
    clean = np.where(hole, np.float32(0.0), depth).astype(np.float32, copy=False)
    return CheckedInput(depth=clean, hole=hole, guide=_check_guide(guide, depth.shape))


def _check_guide(guide: object | None, shape: tuple[int, ...]) -> np.ndarray | None:
    if guide is None:
        return None
    if not isinstance(guide, np.ndarray):
        raise InpaintInputError(f"guide must be a numpy array or None, got {type(guide).__name__}")
    if guide.shape[:2] != shape or guide.ndim not in (2, 3) or (guide.ndim == 3 and guide.shape[2] not in (1, 3)):
        raise InpaintInputError(f"guide shape {guide.shape} must be H×W or H×W×3 with H×W = {shape}")
    g = guide.astype(np.float32)
    if g.ndim == 3:
        g = g.mean(axis=2) if g.shape[2] == 3 else g[..., 0]
    if guide.dtype == np.uint8:
        g = g / 255.0
    elif guide.dtype == np.uint16:
        g = g / 65535.0
    if not np.isfinite(g).all():
        raise InpaintInputError("guide image contains NaN/inf")
    return np.ascontiguousarray(g, dtype=np.float32)


def finish(result: np.ndarray, checked: CheckedInput, original: np.ndarray) -> np.ndarray:
    """Return float32 output with known pixels restored bit-exactly from ``original``."""
    out = np.where(checked.hole, result.astype(np.float32, copy=False), original).astype(np.float32, copy=False)
    return out
