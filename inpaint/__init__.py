"""Depth-map inpainting: the paper's method and classical baselines behind one interface.

Every method has the signature ``f(depth, mask, guide=None, **options) -> filled``: ``depth`` float32 H×W in
metres, ``mask`` bool H×W (True = hole), ``guide`` an optional H×W or H×W×3 image; the result is float32 H×W,
finite, with every known pixel returned unchanged. Bad input raises ``inpaint.errors.InpaintInputError``.

``METHODS`` maps names to methods; ``inpaint(depth, mask, guide=None, method="paper", **options)`` dispatches.
Methods: ``paper`` (the paper's multi-scale block search + anisotropic gradient + neural PLIP fusion, coarse-to-fine:
greedy priority-ordered fill of the coarsest level, parallel PatchMatch refinement passes at the finer ones,
``inpaint.c2f``), ``paper-greedy`` (the same components in the original greedy fill at full resolution, dozens of
sequential rounds, ``inpaint.method``; slow, kept as the quality reference),
``ebm`` (Criminisi 2004), ``telea`` and ``ns`` (OpenCV), ``biharmonic`` (scikit-image), ``ipbasic``
(IP-Basic-style morphology). DeepFill v2 and EdgeConnect are not included: they need downloaded pretrained weights.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from inpaint.baselines import inpaint_biharmonic, inpaint_ipbasic, inpaint_ns, inpaint_telea
from inpaint.c2f import C2FOptions, inpaint_paper_c2f
from inpaint.ebm import inpaint_ebm
from inpaint.errors import InpaintInputError
from inpaint.method import PaperOptions, inpaint_paper

InpaintMethod = Callable[..., np.ndarray]

METHODS: dict[str, InpaintMethod] = {
    "paper": inpaint_paper_c2f,
    "paper-greedy": inpaint_paper,
    "ebm": inpaint_ebm,
    "telea": inpaint_telea,
    "ns": inpaint_ns,
    "biharmonic": inpaint_biharmonic,
    "ipbasic": inpaint_ipbasic,
}


def inpaint(depth: np.ndarray, mask: np.ndarray, guide: np.ndarray | None = None, method: str = "paper",
            **options: object) -> np.ndarray:
    """Fill the holes of ``depth`` with ``method`` (a key of ``METHODS``); see the module docstring."""
    try:
        fn = METHODS[method]
    except KeyError:
        raise InpaintInputError(f"unknown inpainting method {method!r}; available: {sorted(METHODS)}") from None
    return fn(depth, mask, guide, **options)


__all__ = ["METHODS", "C2FOptions", "InpaintInputError", "PaperOptions", "inpaint", "inpaint_biharmonic",
           "inpaint_ebm", "inpaint_ipbasic", "inpaint_ns", "inpaint_paper", "inpaint_paper_c2f", "inpaint_telea"]
