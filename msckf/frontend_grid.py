"""Grid bucketing and FAST detection of the front end (S-MSCKF ``addNewFeatures`` / ``pruneGridFeatures``).

The image (raw left, ``width × height`` pixels) is split into ``rows × cols`` equal cells; cell ``r * cols + c``
covers ``[c W/cols, (c+1) W/cols) × [r H/rows, (r+1) H/rows)`` (float cell sizes, so every pixel falls in a cell;
S-MSCKF's integer cell width can put the last columns outside the grid).
"""

from __future__ import annotations

import cv2
import numpy as np

# FAST-9/16 reads a circle of radius 3 and non-maximum suppression a 3×3 neighbourhood: a 4-pixel margin makes
# detection on a cell crop identical to detection on the whole image for the pixels inside the cell.
_FAST_MARGIN = 4


def cell_index(px: np.ndarray, width: int, height: int, rows: int, cols: int) -> np.ndarray:
    """(N,) int cell index of raw pixels ``px`` (N, 2); pixels outside the image are clamped to a border cell."""
    if len(px) == 0:
        return np.zeros(0, dtype=np.int64)
    c = np.clip(np.floor(px[:, 0] * (cols / width)), 0, cols - 1).astype(np.int64)
    r = np.clip(np.floor(px[:, 1] * (rows / height)), 0, rows - 1).astype(np.int64)
    return r * cols + c


def cell_bounds(cell: int, width: int, height: int, rows: int, cols: int) -> tuple[int, int, int, int]:
    """Integer pixel bounds ``(x0, x1, y0, y1)`` (half-open) of the pixels whose :func:`cell_index` is ``cell``."""
    r, c = divmod(cell, cols)
    x0 = int(np.ceil(c * width / cols))
    x1 = int(np.ceil((c + 1) * width / cols)) if c < cols - 1 else width
    y0 = int(np.ceil(r * height / rows))
    y1 = int(np.ceil((r + 1) * height / rows)) if r < rows - 1 else height
    return x0, x1, y0, y1


def rank_in_groups(group: np.ndarray, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Order items by group, then by decreasing ``key`` (ties keep input order); rank of each within its group.

    Returns:
        ``(order, rank)``: ``order`` (N,) indices sorting the items; ``rank`` (N,) the 0-based position of item
        ``order[i]`` inside its group.
    """
    n = len(group)
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.lexsort((-np.asarray(key, dtype=np.float64), group))
    g = group[order]
    starts = np.r_[0, np.flatnonzero(g[1:] != g[:-1]) + 1]
    group_start = np.repeat(starts, np.diff(np.r_[starts, n]))
    return order, np.arange(n) - group_start


def top_per_group(group: np.ndarray, key: np.ndarray, quota: np.ndarray) -> np.ndarray:
    """Indices of the items with the largest ``key`` in each group, at most ``quota[group]`` per group.

    Args:
        group: (N,) int group (cell) of each item.
        key: (N,) score; larger is better. Ties keep input order.
        quota: (G,) int maximum number kept per group.
    Returns:
        Sorted (K,) int indices of the kept items.
    """
    order, rank = rank_in_groups(group, key)
    keep = rank < quota[group[order]]
    return np.sort(order[keep])


def exclusion_mask(px: np.ndarray, width: int, height: int, radius: int) -> np.ndarray:
    """uint8 (H, W) mask, 255 where a new feature may be detected: 0 within Chebyshev ``radius`` of ``px``."""
    mask: np.ndarray = np.full((height, width), 255, dtype=np.uint8)
    if len(px):
        x = px[:, 0].astype(np.int64)  # S-MSCKF truncates to int
        y = px[:, 1].astype(np.int64)
        inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
        mask[y[inside], x[inside]] = 0
        if radius > 0:
            mask = cv2.erode(mask, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))
    return mask


def detect_fast_in_cells(
    detector: cv2.FastFeatureDetector,
    image: np.ndarray,
    cells: np.ndarray,
    mask: np.ndarray,
    rows: int,
    cols: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """FAST corners inside the given cells where ``mask`` is non-zero.

    Detection runs on a crop of each requested cell (plus a 4-pixel margin), which gives the same corners as a
    whole-image detection restricted to the cell but skips the cells that need no new features. When more than
    half of the cells are requested, one whole-image detection is cheaper (no overlapping margins, one call) and
    is used instead; the corners and their order (cell by cell in the order of ``cells``, raster order within a
    cell) are the same either way.

    Args:
        detector: a configured ``cv2.FastFeatureDetector``.
        image: (H, W) uint8 raw left image.
        cells: (M,) int cell indices to search.
        mask: (H, W) uint8, 0 where detection is not allowed.
    Returns:
        ``(px, response, cell)``: (K, 2) float64 pixel positions, (K,) FAST responses, (K,) int cell indices.
    """
    height, width = image.shape
    cells = np.asarray(cells, dtype=np.int64)
    if 2 * len(cells) > rows * cols:
        return _detect_fast_whole_image(detector, image, cells, mask, rows, cols)
    all_px, all_resp, all_cell = [], [], []
    for cell in cells:
        x0, x1, y0, y1 = cell_bounds(int(cell), width, height, rows, cols)
        if x1 <= x0 or y1 <= y0 or not mask[y0:y1, x0:x1].any():
            continue
        cx0, cy0 = max(x0 - _FAST_MARGIN, 0), max(y0 - _FAST_MARGIN, 0)
        cx1, cy1 = min(x1 + _FAST_MARGIN, width), min(y1 + _FAST_MARGIN, height)
        # The detector drops masked corners itself (after non-maximum suppression, order kept), so fewer
        # keypoint objects reach Python; the corners outside the cell (the margin) are dropped below.
        kps = detector.detect(image[cy0:cy1, cx0:cx1], mask[cy0:cy1, cx0:cx1])
        if not kps:
            continue
        pts = cv2.KeyPoint_convert(kps).astype(np.float64) + (cx0, cy0)  # type: ignore[attr-defined]
        resp = np.fromiter((k.response for k in kps), dtype=np.float64, count=len(kps))
        xi = np.rint(pts[:, 0]).astype(np.int64)
        yi = np.rint(pts[:, 1]).astype(np.int64)
        keep = (xi >= x0) & (xi < x1) & (yi >= y0) & (yi < y1)
        all_px.append(pts[keep])
        all_resp.append(resp[keep])
        all_cell.append(np.full(int(keep.sum()), cell, dtype=np.int64))
    if not all_px:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.concatenate(all_px), np.concatenate(all_resp), np.concatenate(all_cell)


def _detect_fast_whole_image(detector: cv2.FastFeatureDetector, image: np.ndarray, cells: np.ndarray,
                             mask: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`detect_fast_in_cells` by one detection over the whole image (same corners, same order)."""
    height, width = image.shape
    kps = detector.detect(image, mask)
    if not kps:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
    pts = cv2.KeyPoint_convert(kps).astype(np.float64)  # type: ignore[attr-defined]
    resp = np.fromiter((k.response for k in kps), dtype=np.float64, count=len(kps))
    # Integer corner pixels: floor(x · cols / W) is the cell whose cell_bounds hold x.
    cell = cell_index(np.rint(pts), width, height, rows, cols)
    rank = np.full(rows * cols, -1, dtype=np.int64)
    rank[cells] = np.arange(len(cells))
    keep = np.flatnonzero(rank[cell] >= 0)
    keep = keep[np.argsort(rank[cell[keep]], kind="stable")]          # cell by cell, raster order within
    return pts[keep], resp[keep], cell[keep]
