"""Anisotropic (paper) and isotropic (Sobel) gradients of a depth map, computed on known pixels only.

Anisotropic gradient (paper §2): around each pixel, the mean of a central region M_c and of eight directional
regions M_i (i = 0..7 at 0°, 45°, …, 315°, counter-clockwise as seen on screen: 0 = east/+x, 2 = north/−y) is
taken for each of three structural templates; G_i^t = M_i^t − M_c^t; G_i^avg = (1/3) Σ_t G_i^t;
edge strength G_final = max_i |G_i^avg|. The paper's Figure 2 (the three templates) is not in the text we have;
our three templates are:

- ``grid``: 3×3-pixel centre, eight 3×3 cells around it (a 9×9 window);
- ``star``: a 5-pixel "plus" centre, eight thin rays of 3 pixels at distances 2–4 along each direction;
- ``wide``: 5×5 centre, 4×5 / 5×4 side blocks and 4×4 corner blocks (a 13×13 window).

Means are taken over known pixels only (normalised convolution: Σ K·I / Σ K with K the known mask; outside the
image counts as unknown). A region with no known pixel contributes G = 0. Every region is a small kernel applied
with one OpenCV filter call on a zero-padded image, so the whole map costs a few dozen vectorised filters.

Direction: the gradient vector g = A⁻¹ Σ_i G_i^avg u_i with u_i the unit vector of direction i (image axes, x right,
y down) and A = Σ_i u_i c̄_iᵀ from the regions' centroid offsets c̄_i (averaged over templates). On a linear ramp
I = a·x + b·y this returns exactly (a, b) in depth units per pixel; on a step it points across the edge towards
the higher side.

The isotropic ablation uses a masked Sobel: gx = (M_right − M_left)/2, gy = (M_down − M_up)/2 with the Sobel column
weights (1, 2, 1); its feature channels are (gx, gy).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, lru_cache

import cv2
import numpy as np

from inpaint.errors import InpaintInputError

GRADIENT_KINDS = ("anisotropic", "sobel")
_DIRS = [(int(round(np.cos(np.pi / 4 * i))), int(round(-np.sin(np.pi / 4 * i)))) for i in range(8)]  # (sx, sy)


@dataclass(frozen=True)
class Region:
    """A weighted region of offsets. ``weights`` (h×w float32) placed with its top-left at offset (oy, ox) from
    the pixel; ``box`` True when all weights are 1 (uses a box filter)."""

    oy: int
    ox: int
    weights: np.ndarray
    box: bool

    @property
    def centroid(self) -> np.ndarray:
        """Weighted centroid (x, y) of the region, in pixels relative to the pixel."""
        ys, xs = np.mgrid[0:self.weights.shape[0], 0:self.weights.shape[1]]
        w = self.weights
        return np.array([(w * (xs + self.ox)).sum() / w.sum(), (w * (ys + self.oy)).sum() / w.sum()])


def _rect(x0: int, x1: int, y0: int, y1: int) -> Region:
    return Region(y0, x0, np.ones((y1 - y0 + 1, x1 - x0 + 1), np.float32), True)


def _points(pts: list[tuple[int, int]]) -> Region:
    xs = [p[0] for p in pts]
    ys = [p[1] for p in pts]
    w = np.zeros((max(ys) - min(ys) + 1, max(xs) - min(xs) + 1), np.float32)
    for x, y in pts:
        w[y - min(ys), x - min(xs)] = 1.0
    return Region(min(ys), min(xs), w, bool(w.all()))


def _grid_template(cell: int, centre_half: int) -> list[Region]:
    """Centre square of half-size ``centre_half``; 8 cells: axis cells ``cell`` deep × centre wide, corner
    cells ``cell``×``cell``, adjacent to the centre."""
    c = centre_half
    regions = [_rect(-c, c, -c, c)]
    for sx, sy in _DIRS:
        xr = (c + 1, c + cell) if sx > 0 else ((-c - cell, -c - 1) if sx < 0 else (-c, c))
        yr = (c + 1, c + cell) if sy > 0 else ((-c - cell, -c - 1) if sy < 0 else (-c, c))
        regions.append(_rect(xr[0], xr[1], yr[0], yr[1]))
    return regions


def _star_template() -> list[Region]:
    regions = [_points([(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)])]
    for sx, sy in _DIRS:
        regions.append(_points([(k * sx, k * sy) for k in (2, 3, 4)]))
    return regions


@cache
def templates(kind: str) -> tuple[tuple[Region, ...], ...]:
    """The structural templates of ``kind``: each is (centre, dir0, …, dir7) for the anisotropic gradient;
    for ``sobel`` one template (left, right, up, down)."""
    if kind == "anisotropic":
        return (tuple(_grid_template(3, 1)), tuple(_star_template()), tuple(_grid_template(4, 2)))
    if kind == "sobel":
        col = np.array([[1.0], [2.0], [1.0]], np.float32)
        return ((Region(-1, -1, col, False), Region(-1, 1, col, False),
                 Region(-1, -1, col.T.copy(), False), Region(1, -1, col.T.copy(), False)),)
    raise InpaintInputError(f"unknown gradient kind {kind!r}; expected one of {GRADIENT_KINDS}")


@cache
def template_radius(kind: str) -> int:
    """Largest |offset| any region of ``kind`` reaches (pixels): the support radius of the features."""
    r = 0
    for tpl in templates(kind):
        for reg in tpl:
            h, w = reg.weights.shape
            r = max(r, abs(reg.oy), abs(reg.ox), abs(reg.oy + h - 1), abs(reg.ox + w - 1))
    return r


@cache
def _direction_matrix() -> np.ndarray:
    """A⁻¹ with A = Σ_i u_i c̄_iᵀ (2×2), c̄_i = centroid offset of direction i minus the centre's, template mean."""
    tpls = templates("anisotropic")
    a = np.zeros((2, 2))
    for i in range(8):
        u = np.array([np.cos(np.pi / 4 * i), -np.sin(np.pi / 4 * i)])
        c = np.mean([t[1 + i].centroid - t[0].centroid for t in tpls], axis=0)
        a += np.outer(u, c)
    return np.linalg.inv(a)


def n_channels(kind: str) -> int:
    """Number of feature channels of ``kind``: 8 directional gradients (anisotropic) or 2 (Sobel gx, gy)."""
    return 8 if kind == "anisotropic" else 2


@dataclass(frozen=True)
class GradientField:
    """Gradient of an H×W map. ``channels``: H×W×C float32 (anisotropic: G_i^avg, i = 0..7, depth units;
    Sobel: gx, gy per pixel). ``gx``, ``gy``: H×W gradient vector (depth units per pixel, x right, y down).
    ``strength``: H×W edge strength (anisotropic: G_final = max_i |G_i^avg|; Sobel: |g|)."""

    channels: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    strength: np.ndarray


def gradient_field(image: np.ndarray, known: np.ndarray | None = None, kind: str = "anisotropic") -> GradientField:
    """Gradient of ``image`` (float32 H×W) using only ``known`` pixels (bool H×W; None = all known)."""
    ch = gradient_channels(image, known, kind)
    gx, gy = vector_from_channels(ch, kind)
    strength = np.abs(ch).max(axis=2) if kind == "anisotropic" else np.hypot(gx, gy)
    return GradientField(ch, gx, gy, strength.astype(np.float32))


def vector_from_channels(ch: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """Gradient vector (gx, gy) in depth units per pixel from feature channels (…×C)."""
    if kind == "sobel":
        return ch[..., 0], ch[..., 1]
    u = np.array([[np.cos(np.pi / 4 * i), -np.sin(np.pi / 4 * i)] for i in range(8)], np.float32)  # 8×2
    s = ch @ u  # Σ_i G_i u_i, …×2
    v = s @ _direction_matrix().T.astype(np.float32)
    return v[..., 0], v[..., 1]


def _region_filter(a: np.ndarray, reg: Region) -> np.ndarray:
    """Σ over ``reg``'s weights placed with their top-left at each pixel of ``a`` (zero outside)."""
    if reg.box:
        kh, kw = reg.weights.shape
        return cv2.boxFilter(a, -1, (kw, kh), anchor=(0, 0), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return cv2.filter2D(a, -1, reg.weights, anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)


def gradient_channels(image: np.ndarray, known: np.ndarray | None = None, kind: str = "anisotropic") -> np.ndarray:
    """Feature channels (H×W×C float32) of ``image`` over ``known`` pixels; see the module docstring.

    The anisotropic kind runs the compiled form (``_anisotropic_compiled``: the same float32 operations in the same
    order, bit-identical, tested against ``gradient_channels_reference``)."""
    if kind == "anisotropic":
        return _anisotropic_compiled(np.asarray(image, np.float32), known)
    return gradient_channels_reference(image, known, kind)


def gradient_channels_reference(image: np.ndarray, known: np.ndarray | None = None,
                                kind: str = "anisotropic") -> np.ndarray:
    """``gradient_channels`` as whole-image numpy operations (the reference of the compiled form)."""
    img = np.asarray(image, np.float32)
    k = np.ones(img.shape, np.float32) if known is None else known.astype(np.float32)
    r = template_radius(kind)
    num_pad = cv2.copyMakeBorder(np.where(k > 0, img, 0).astype(np.float32), r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    den_pad = cv2.copyMakeBorder(k, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    h, w = img.shape
    cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    def region_sums(reg: Region) -> tuple[np.ndarray, np.ndarray]:
        """(Σ K·I, Σ K) over ``reg`` around every pixel (H×W views)."""
        key = (reg.weights.shape, reg.weights.tobytes())
        if key not in cache:
            cache[key] = (_region_filter(num_pad, reg), _region_filter(den_pad, reg))
        nsum, dsum = cache[key]
        sl = (slice(r + reg.oy, r + reg.oy + h), slice(r + reg.ox, r + reg.ox + w))
        return nsum[sl], dsum[sl]

    def region_mean(reg: Region, fallback: np.ndarray) -> np.ndarray:
        """Mean over known pixels of ``reg``; ``fallback`` where the region has no known pixel."""
        n, d = region_sums(reg)
        return np.divide(n, d, out=fallback.copy(), where=d > 1e-3)

    zero = np.zeros((h, w), np.float32)
    if kind == "sobel":  # regions: left, right, up, down
        tl, tr, tu, td = templates("sobel")[0]
        ml, mr, mu, md = (region_mean(reg, zero) for reg in (tl, tr, tu, td))
        gx = np.where((region_sums(tl)[1] > 1e-3) & (region_sums(tr)[1] > 1e-3), (mr - ml) * np.float32(0.5), zero)
        gy = np.where((region_sums(tu)[1] > 1e-3) & (region_sums(td)[1] > 1e-3), (md - mu) * np.float32(0.5), zero)
        return np.stack([gx, gy], axis=2)
    # Mean of a region over known pixels, or the centre mean where the region has none (so G = 0 there):
    # (Σ K·I + ε·M_c) / (Σ K + ε), ε = 1e-6 — exact to float32 precision when Σ K ≥ 1; no temporaries.
    eps = np.float32(1e-6)
    acc = np.zeros((8, h, w), np.float32)
    bn = np.empty((h, w), np.float32)
    bd = np.empty((h, w), np.float32)
    for tpl in templates(kind):
        n, d = region_sums(tpl[0])
        np.add(d, eps, out=bd)
        mc = n / bd
        mce = mc * eps
        for i in range(8):
            n, d = region_sums(tpl[1 + i])
            np.add(n, mce, out=bn)
            np.add(d, eps, out=bd)
            np.divide(bn, bd, out=bn)
            acc[i] += bn
        acc -= mc
    acc *= np.float32(1.0 / 3.0)
    acc[:, region_sums(templates(kind)[0][0])[1] <= 1e-3] = 0.0  # centre unknown: no gradient
    return np.ascontiguousarray(acc.transpose(1, 2, 0))


@cache
def _region_table(kind: str) -> tuple[tuple[Region, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Distinct region shapes of ``kind``'s templates and, per region (template-major), its shape index and
    offset (oy, ox): the layout ``c2f_kernels.directional_means`` reads."""
    shapes: list[Region] = []
    keys: dict[tuple, int] = {}
    idx, oy, ox = [], [], []
    for tpl in templates(kind):
        for reg in tpl:
            key = (reg.weights.shape, reg.weights.tobytes())
            if key not in keys:
                keys[key] = len(shapes)
                shapes.append(reg)
            idx.append(keys[key])
            oy.append(reg.oy)
            ox.append(reg.ox)
    return tuple(shapes), np.array(idx, np.intp), np.array(oy, np.intp), np.array(ox, np.intp)


@lru_cache(maxsize=8)
def _known_sums(h: int, w: int) -> np.ndarray:
    """Σ K of every distinct anisotropic region shape on an all-known h×w image (zero-padded), U×(h+2r)×(w+2r)."""
    r = template_radius("anisotropic")
    den_pad = cv2.copyMakeBorder(np.ones((h, w), np.float32), r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    out = np.stack([_region_filter(den_pad, reg) for reg in _region_table("anisotropic")[0]])
    out.flags.writeable = False
    return out


def _anisotropic_compiled(img: np.ndarray, known: np.ndarray | None) -> np.ndarray:
    """Anisotropic channels over ``known`` pixels (None: all): region sums of K·I and K by the same OpenCV
    filters, then ``c2f_kernels.directional_means`` (bit-identical to ``gradient_channels_reference``)."""
    if known is None:
        return anisotropic_channels_fast(img)
    from inpaint.c2f_kernels import directional_means

    r = template_radius("anisotropic")
    h, w = img.shape
    k = known.astype(np.float32)
    num_pad = cv2.copyMakeBorder(np.where(k > 0, img, 0).astype(np.float32), r, r, r, r, cv2.BORDER_CONSTANT,
                                 value=0)
    den_pad = cv2.copyMakeBorder(k, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    shapes, idx, oy, ox = _region_table("anisotropic")
    nsum = np.empty((len(shapes),) + num_pad.shape, np.float32)
    dsum = np.empty((len(shapes),) + num_pad.shape, np.float32)
    for u, reg in enumerate(shapes):
        nsum[u] = _region_filter(num_pad, reg)
        dsum[u] = _region_filter(den_pad, reg)
    out = np.empty((h, w, 8), np.float32)
    directional_means(nsum, dsum, idx, oy, ox, r, h, w, out)
    return out


def anisotropic_channels_fast(image: np.ndarray) -> np.ndarray:
    """``gradient_channels(image, None, "anisotropic")`` (every pixel known), bit-identical, faster: the distinct
    region sums are filtered once and the per-pixel means and differences run in one compiled loop
    (``c2f_kernels.directional_means``) instead of ~100 whole-image numpy operations. H×W float32 → H×W×8."""
    from inpaint.c2f_kernels import directional_means

    img = np.asarray(image, np.float32)
    r = template_radius("anisotropic")
    h, w = img.shape
    num_pad = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    shapes, idx, oy, ox = _region_table("anisotropic")
    nsum = np.empty((len(shapes),) + num_pad.shape, np.float32)
    for u, reg in enumerate(shapes):
        nsum[u] = _region_filter(num_pad, reg)
    dsum = _known_sums(h, w)
    out = np.empty((h, w, 8), np.float32)
    directional_means(nsum, dsum, idx, oy, ox, r, h, w, out)
    return out


Rect = tuple[int, int, int, int]  # (y0, y1, x0, x1), half-open, pixels


@dataclass
class FeatureJob:
    """Recompute the feature channels of ``image``/``known`` (H×W) inside ``rects`` into ``out`` (H×W×C view);
    if ``gvec_out`` (H×W×2) is given, also the gradient vectors (gy, gx) there."""

    image: np.ndarray
    known: np.ndarray
    rects: list[Rect]
    out: np.ndarray
    gvec_out: np.ndarray | None = None


def run_feature_jobs(jobs: list[FeatureJob], kind: str = "anisotropic") -> None:
    """Execute feature updates of several images in one filter pass.

    The neighbourhoods (± the template radius) of all rects of all jobs are cut out, stacked into one tall image
    separated by unknown rows, and filtered once; results inside each rect equal those of ``gradient_channels``
    on the job's whole image.
    """
    r = template_radius(kind)
    crops = []
    for j, job in enumerate(jobs):
        h, w = job.image.shape
        for y0, y1, x0, x1 in job.rects:
            y0, y1, x0, x1 = max(0, y0), min(h, y1), max(0, x0), min(w, x1)
            if y0 >= y1 or x0 >= x1:
                continue
            crops.append((j, y0, y1, x0, x1, max(0, y0 - r), min(h, y1 + r), max(0, x0 - r), min(w, x1 + r)))
    if not crops:
        return
    narrow = [c for c in crops if c[8] - c[7] <= 96]
    groups = [[c] for c in crops if c[8] - c[7] > 96] + ([narrow] if narrow else [])
    for group in groups:  # wide crops alone, narrow ones stacked together (little padding waste)
        _run_stack(jobs, group, r, kind)


def _run_stack(jobs: list[FeatureJob], crops: list[tuple[int, ...]], r: int, kind: str) -> None:
    width = max(c[8] - c[7] for c in crops)
    total = sum(c[6] - c[5] + r for c in crops)
    big = np.zeros((total, width), np.float32)
    bigk = np.zeros((total, width), bool)
    row = 0
    for j, _y0, _y1, _x0, _x1, cy0, cy1, cx0, cx1 in crops:
        big[row:row + cy1 - cy0, :cx1 - cx0] = jobs[j].image[cy0:cy1, cx0:cx1]
        bigk[row:row + cy1 - cy0, :cx1 - cx0] = jobs[j].known[cy0:cy1, cx0:cx1]
        row += cy1 - cy0 + r
    feats = gradient_channels(big, bigk, kind)
    gx = gy = None
    if any(jobs[c[0]].gvec_out is not None for c in crops):
        gx, gy = vector_from_channels(feats, kind)
    row = 0
    for j, y0, y1, x0, x1, cy0, cy1, cx0, _cx1 in crops:
        sl = (slice(row + y0 - cy0, row + y1 - cy0), slice(x0 - cx0, x1 - cx0))
        jobs[j].out[y0:y1, x0:x1] = feats[sl]
        if jobs[j].gvec_out is not None:
            jobs[j].gvec_out[y0:y1, x0:x1, 0] = gy[sl]
            jobs[j].gvec_out[y0:y1, x0:x1, 1] = gx[sl]
        row += cy1 - cy0 + r


def gradient_channels_in_rects(image: np.ndarray, known: np.ndarray, rects: list[Rect], out: np.ndarray,
                               kind: str = "anisotropic") -> None:
    """Recompute feature channels inside each rect (y0, y1, x0, x1; half-open) of ``out`` (H×W×C, in place);
    results equal those of ``gradient_channels`` on the whole image (see ``run_feature_jobs``)."""
    run_feature_jobs([FeatureJob(image, known, list(rects), out)], kind)
