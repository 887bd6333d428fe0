"""EBM baseline: exemplar-based inpainting of Criminisi, Pérez, Toyama (IEEE TIP 2004), on depth.

Faithful to the paper: patch Ψ 9×9; priority P(p) = C(p)·D(p) on the fill front; confidence
C(p) = Σ_{q ∈ Ψp ∩ known} C(q) / |Ψp| (C = 1 on known, 0 in the hole at the start); data term
D(p) = |∇I⊥_p · n_p| / α with the isophote ∇I⊥ (the gradient rotated by 90°) taken as the largest-magnitude
gradient within Ψp ∩ known, n_p the unit normal of the front, α = the depth range of the known pixels (the
analogue of 255 for 8-bit images); a small ε = 0.001 is added to D, as common implementations do, so that
flat fronts are not stuck at P = 0. One patch per iteration: the highest-priority patch Ψp̂ is filled with the
exemplar Ψq̂ minimising the sum of squared differences over the already filled pixels of Ψp̂, among patches lying
entirely in the source region (the originally known pixels); only its hole pixels are copied, and they inherit
C(p̂). Depth values are copied as they are (no offset correction: that is the paper's method applied to depth).

Vectorised: the exemplar search is one masked ``cv2.matchTemplate(TM_SQDIFF)`` over a bounded window
(± ``window`` px around p̂, default 40; the paper allows restricting the source to a band around the hole), and
priorities are updated incrementally around each filled patch instead of recomputed over the whole image.
"""

from __future__ import annotations

import cv2
import numpy as np

from inpaint.errors import InpaintInputError
from inpaint.validate import check_inputs, finish


def inpaint_ebm(depth: np.ndarray, mask: np.ndarray, guide: np.ndarray | None = None, patch: int = 9,
                window: int = 40, **options: object) -> np.ndarray:
    """Criminisi exemplar-based inpainting of ``depth`` (float32 H×W metres) in ``mask`` (see module docstring)."""
    if options:
        raise InpaintInputError(f"unknown option(s) for method 'ebm': {sorted(options)}")
    if patch < 3 or patch % 2 == 0:
        raise InpaintInputError(f"patch must be odd and ≥ 3, got {patch}")
    if window < 1:
        raise InpaintInputError(f"window must be ≥ 1, got {window}")
    chk = check_inputs(depth, mask, guide)
    if not chk.hole.any():
        return depth.copy()
    return finish(_Criminisi(chk.depth, chk.hole, patch, window).run(), chk, depth)


class _Criminisi:
    def __init__(self, depth: np.ndarray, hole: np.ndarray, patch: int, window: int) -> None:
        self.hp = patch // 2
        self.window = window
        pad = self.hp + window
        self.pad = pad
        h, w = depth.shape
        self.h, self.w = h, w
        # Padded working arrays (pad = unknown, outside the source).
        self.img = np.zeros((h + 2 * pad, w + 2 * pad), np.float32)
        self.img[pad:pad + h, pad:pad + w] = depth
        self.hole = np.ones(self.img.shape, bool)
        self.hole[pad:pad + h, pad:pad + w] = hole
        self.inside = np.zeros(self.img.shape, bool)
        self.inside[pad:pad + h, pad:pad + w] = True
        self.conf = (~self.hole).astype(np.float32)
        src = (~self.hole).astype(np.uint8)
        self.source_ok = cv2.erode(src, np.ones((patch, patch), np.uint8), borderType=cv2.BORDER_CONSTANT,
                                   borderValue=0) > 0
        known = depth[~hole]
        self.alpha = float(max(known.max() - known.min(), 1e-3))
        self.gy = np.zeros(self.img.shape, np.float32)
        self.gx = np.zeros(self.img.shape, np.float32)
        self.prio = np.full(self.img.shape, -1.0)
        self._update_gradient(0, self.img.shape[0], 0, self.img.shape[1])
        self._update_priority(0, self.img.shape[0], 0, self.img.shape[1])

    def _update_gradient(self, y0: int, y1: int, x0: int, x1: int) -> None:
        """Sobel gradient of the known pixels (zero where any pixel of the 3×3 stencil is unknown)."""
        y0, x0 = max(y0 - 1, 0), max(x0 - 1, 0)
        y1, x1 = min(y1 + 1, self.img.shape[0]), min(x1 + 1, self.img.shape[1])
        img = self.img[y0:y1, x0:x1]
        kn = (~self.hole[y0:y1, x0:x1]).astype(np.uint8)
        full = cv2.erode(kn, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        sl = (slice(y0 + 1 if y0 > 0 else y0, y1 - 1 if y1 < self.img.shape[0] else y1),
              slice(x0 + 1 if x0 > 0 else x0, x1 - 1 if x1 < self.img.shape[1] else x1))
        inner = (slice(sl[0].start - y0, sl[0].stop - y0), slice(sl[1].start - x0, sl[1].stop - x0))
        self.gx[sl] = np.where(full, gx, 0.0)[inner]
        self.gy[sl] = np.where(full, gy, 0.0)[inner]

    def _update_priority(self, y0: int, y1: int, x0: int, x1: int) -> None:
        """Recompute front and priority inside [y0, y1) × [x0, x1) (padded coordinates), from a margin-extended crop."""
        hp = self.hp
        m = hp + 3
        cy0, cy1 = max(0, y0 - m), min(self.img.shape[0], y1 + m)
        cx0, cx1 = max(0, x0 - m), min(self.img.shape[1], x1 + m)
        hole = self.hole[cy0:cy1, cx0:cx1]
        inside = self.inside[cy0:cy1, cx0:cx1]
        known = (~hole).astype(np.uint8)
        front = hole & inside & (cv2.dilate(known, np.ones((3, 3), np.uint8)) > 0)
        ps = 2 * hp + 1
        conf = cv2.boxFilter(self.conf[cy0:cy1, cx0:cx1], -1, (ps, ps), normalize=True,
                             borderType=cv2.BORDER_CONSTANT)
        sm = cv2.GaussianBlur(known.astype(np.float32), (5, 5), 1.0)
        ny = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3)
        nx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3)
        nn = np.hypot(nx, ny)
        nn[nn < 1e-9] = 1.0
        ny, nx = ny / nn, nx / nn
        # Largest-magnitude known gradient within the patch: dilate the magnitude, then pick that vector.
        gx, gy = self.gx[cy0:cy1, cx0:cx1], self.gy[cy0:cy1, cx0:cx1]
        mag = np.hypot(gx, gy)
        pts = np.argwhere(front)
        prio = np.full(hole.shape, -1.0)
        if len(pts):
            offs = np.arange(-hp, hp + 1)
            ys = np.clip(pts[:, 0, None, None] + offs[None, :, None], 0, hole.shape[0] - 1)
            xs = np.clip(pts[:, 1, None, None] + offs[None, None, :], 0, hole.shape[1] - 1)
            ys, xs = np.broadcast_arrays(ys, xs)
            mg = mag[ys, xs].reshape(len(pts), -1)
            j = np.argmax(mg, axis=1)
            yy, xx = ys.reshape(len(pts), -1)[np.arange(len(pts)), j], xs.reshape(len(pts), -1)[np.arange(len(pts)), j]
            iso_y, iso_x = gx[yy, xx], -gy[yy, xx]  # isophote = gradient rotated by 90°
            d = np.abs(iso_y * ny[pts[:, 0], pts[:, 1]] + iso_x * nx[pts[:, 0], pts[:, 1]]) / self.alpha + 1e-3
            prio[pts[:, 0], pts[:, 1]] = conf[pts[:, 0], pts[:, 1]] * d
        iy0, ix0 = y0 - cy0, x0 - cx0
        self.prio[y0:y1, x0:x1] = prio[iy0:iy0 + (y1 - y0), ix0:ix0 + (x1 - x0)]

    def run(self) -> np.ndarray:
        hp, r = self.hp, self.window
        ps = 2 * hp + 1
        remaining = int((self.hole & self.inside).sum())
        while remaining > 0:
            j = int(np.argmax(self.prio))
            py, px = divmod(j, self.prio.shape[1])
            if self.prio[py, px] < 0:  # no front left inside (cannot happen while holes remain) — safety
                break
            tpl = self.img[py - hp:py + hp + 1, px - hp:px + hp + 1]
            m = (~self.hole[py - hp:py + hp + 1, px - hp:px + hp + 1]).astype(np.float32)
            wy0, wx0 = py - r - hp, px - r - hp
            win = self.img[wy0:py + r + hp + 1, wx0:px + r + hp + 1]
            ok = self.source_ok[py - r:py + r + 1, px - r:px + r + 1]
            if ok.any():
                ssd = cv2.matchTemplate(win, tpl, cv2.TM_SQDIFF, mask=m)
                ssd = np.where(ok, ssd, np.inf)
                k = int(np.argmin(ssd))
                qy, qx = py - r + k // ssd.shape[1], px - r + k % ssd.shape[1]
                src = self.img[qy - hp:qy + hp + 1, qx - hp:qx + hp + 1]
            else:  # no source patch within the window: global fallback over the whole source region
                src = self._global_best(tpl, m)
            holes = self.hole[py - hp:py + hp + 1, px - hp:px + hp + 1] & self.inside[py - hp:py + hp + 1,
                                                                                      px - hp:px + hp + 1]
            c_hat = float((self.conf[py - hp:py + hp + 1, px - hp:px + hp + 1]).sum()) / (ps * ps)
            self.img[py - hp:py + hp + 1, px - hp:px + hp + 1][holes] = src[holes]
            self.conf[py - hp:py + hp + 1, px - hp:px + hp + 1][holes] = c_hat
            self.hole[py - hp:py + hp + 1, px - hp:px + hp + 1][holes] = False
            remaining -= int(holes.sum())
            self._update_gradient(py - hp - 1, py + hp + 2, px - hp - 1, px + hp + 2)
            self._update_priority(py - ps - 2, py + ps + 3, px - ps - 2, px + ps + 3)
        p = self.pad
        return self.img[p:p + self.h, p:p + self.w].copy()

    def _global_best(self, tpl: np.ndarray, m: np.ndarray) -> np.ndarray:
        hp = self.hp
        ssd = cv2.matchTemplate(self.img, tpl, cv2.TM_SQDIFF, mask=m)
        ok = self.source_ok[hp:hp + ssd.shape[0], hp:hp + ssd.shape[1]]
        if not ok.any():  # no complete source patch anywhere: fill with the mean of the known pixels
            return np.full(tpl.shape, float((tpl * m).sum() / max(m.sum(), 1)), np.float32)
        ssd = np.where(ok, ssd, np.inf)
        k = int(np.argmin(ssd))
        qy, qx = hp + k // ssd.shape[1], hp + k % ssd.shape[1]
        return self.img[qy - hp:qy + hp + 1, qx - hp:qx + hp + 1]
