"""Compiled (numba) visibility kernels of the renderer (see ``render.FieldRenderer._raster`` and ``_trace``).

* :func:`project_polygons`: polygon vertices into a camera's raster, with view culling;
* :func:`raster_polygons`: the polygon id raster, polygons filled far to near (painter's order);
* :func:`trace_surfaces`: one pass over the rays of a bundle, after the terrain hit is known: the far canopy
  plane, the two tree lines (vertical cylinders with a height profile) and the polygon that the raster names for
  the ray (exact ray/plane hit, z-tested against the rest). Arithmetic is float64 per ray; results are stored as
  float32.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT

#: what a pixel shows (``Trace.label``, the exported ground-truth labels); ``render`` re-exports these
LABEL_SKY, LABEL_SOIL, LABEL_LEAF, LABEL_CANOPY, LABEL_TREES = 0, 1, 2, 3, 4


@numba.njit(**NJIT)
def project_polygons(verts: np.ndarray, origin: np.ndarray, normal: np.ndarray, two_sided: np.ndarray,
                     R: np.ndarray, o: np.ndarray, fx: float, fy: float, cx: float, cy: float, width: int,
                     height: int, near_m: float, uv: np.ndarray, visible: np.ndarray, dist2: np.ndarray) -> None:
    """Project polygons into a camera's raster and cull them.

    Args:
        verts: (N, V, 3) float64 field-frame vertices; origin, normal: (N, 3) float64 plane point and normal.
        two_sided: (N,) bool polygons seen from both sides (leaves); the others only from their normal's side.
        R, o: (3, 3) and (3,) float64 camera pose in the field frame (``p_F = R · p_cam + o``).
        fx, fy, cx, cy, width, height: raster intrinsics (px) and size.
        near_m: every vertex must be farther than this in front of the camera.
        uv: (N, V, 2) float64 output pixel coordinates, clipped to [-4000, 8000].
        visible: (N,) bool output: in front, facing, and overlapping the raster.
        dist2: (N,) float64 output squared distance from the camera to the polygon origin, m².
    """
    for k in range(verts.shape[0]):
        ex = o[0] - origin[k, 0]
        ey = o[1] - origin[k, 1]
        ez = o[2] - origin[k, 2]
        dist2[k] = ex * ex + ey * ey + ez * ez
        ok = two_sided[k] or normal[k, 0] * ex + normal[k, 1] * ey + normal[k, 2] * ez > 0.0
        u_lo = w_lo = 1e300
        u_hi = w_hi = -1e300
        for m in range(verts.shape[1]):
            px = verts[k, m, 0] - o[0]
            py = verts[k, m, 1] - o[1]
            pz = verts[k, m, 2] - o[2]
            x = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
            y = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
            z = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
            if not z > near_m:
                ok = False
                z = near_m
            u = fx * x / z + cx
            w = fy * y / z + cy
            u_lo = min(u_lo, u)
            u_hi = max(u_hi, u)
            w_lo = min(w_lo, w)
            w_hi = max(w_hi, w)
            uv[k, m, 0] = min(max(u, -4000.0), 8000.0)
            uv[k, m, 1] = min(max(w, -4000.0), 8000.0)
        visible[k] = ok and u_hi >= -1.0 and u_lo <= width and w_hi >= -1.0 and w_lo <= height


@numba.njit(**NJIT)
def raster_polygons(uv: np.ndarray, order: np.ndarray, buf: np.ndarray) -> None:
    """Fill polygons into an id raster in the given order (later ones overwrite earlier ones).

    Like ``cv2.fillPoly``, a polygon covers the pixels whose centre (column j, row i) lies inside it (even-odd
    rule) and the pixels of its outline (8-connected lines between the rounded vertices), so that polygons
    thinner than a pixel still show.

    Args:
        uv: (N, V, 2) float64 vertex pixel coordinates (column, row); shorter polygons repeat their last vertex.
        order: (M,) int64 polygon indices in drawing order (far to near).
        buf: (H, W) int32 raster, written with ``index + 1`` of the polygon covering each pixel.
    """
    h, w = buf.shape
    nv = uv.shape[1]
    xs = np.empty(nv, np.float64)
    for q in range(order.size):
        k = order[q]
        val = k + 1
        v_lo = uv[k, 0, 1]
        v_hi = v_lo
        for m in range(1, nv):
            v_lo = min(v_lo, uv[k, m, 1])
            v_hi = max(v_hi, uv[k, m, 1])
        i0 = max(int(math.ceil(v_lo)), 0)
        i1 = min(int(math.floor(v_hi)), h - 1)
        for i in range(i0, i1 + 1):
            y = float(i)
            nx = 0
            for m in range(nv):
                ax, ay = uv[k, m, 0], uv[k, m, 1]
                bx, by = uv[k, (m + 1) % nv, 0], uv[k, (m + 1) % nv, 1]
                if (ay <= y < by) or (by <= y < ay):
                    x = ax + (y - ay) * (bx - ax) / (by - ay)
                    p = nx  # insertion into the sorted crossings
                    while p > 0 and xs[p - 1] > x:
                        xs[p] = xs[p - 1]
                        p -= 1
                    xs[p] = x
                    nx += 1
            for c in range(0, nx - 1, 2):
                j0 = max(int(math.ceil(xs[c])), 0)
                j1 = min(int(math.floor(xs[c + 1])), w - 1)
                for j in range(j0, j1 + 1):
                    buf[i, j] = val
        # outline: 8-connected (Bresenham) lines between the rounded vertices
        for m in range(nv):
            x0 = int(math.floor(uv[k, m, 0] + 0.5))
            y0 = int(math.floor(uv[k, m, 1] + 0.5))
            x1 = int(math.floor(uv[k, (m + 1) % nv, 0] + 0.5))
            y1 = int(math.floor(uv[k, (m + 1) % nv, 1] + 0.5))
            if (x0 < 0 and x1 < 0) or (y0 < 0 and y1 < 0) or (x0 >= w and x1 >= w) or (y0 >= h and y1 >= h):
                continue
            ddx = abs(x1 - x0)
            ddy = -abs(y1 - y0)
            sx = 1 if x0 < x1 else -1
            sy = 1 if y0 < y1 else -1
            err = ddx + ddy
            while True:
                if 0 <= x0 < w and 0 <= y0 < h:
                    buf[y0, x0] = val
                if x0 == x1 and y0 == y1:
                    break
                e2 = 2 * err
                if e2 >= ddy:
                    err += ddy
                    x0 += sx
                if e2 <= ddx:
                    err += ddx
                    y0 += sy


@numba.njit(**NJIT)
def trace_surfaces(dirs: np.ndarray, ray_norm: np.ndarray, origin: np.ndarray, t: np.ndarray, label: np.ndarray,
                   canopy: np.ndarray, canopy_box: np.ndarray, tree_centre: np.ndarray, tree_radii: np.ndarray,
                   tree_profiles: np.ndarray, tree_top: np.ndarray, tree_k: np.ndarray, tree_arc: np.ndarray,
                   tree_z: np.ndarray, ids: np.ndarray, raster_x: np.ndarray, raster_y: np.ndarray,
                   poly_tab: np.ndarray, poly_orel: np.ndarray,
                   poly_is_canopy: np.ndarray, pixel_angle: float, near_m: float, poly_k: np.ndarray) -> None:
    """Nearest non-terrain surface of every ray, in place.

    Args:
        dirs: (N, 3) float32 field-frame ray directions (rectified z = 1, so ``t`` is the rectified depth).
        ray_norm: (N,) float32 ray lengths.
        origin: (3,) float64 camera centre, field frame, metres.
        t: (N,) float32 ray parameter of the terrain hit (``inf``: none); replaced by the nearest hit.
        label: (N,) uint8 output label (``LABEL_*``).
        canopy: (N,) bool output: the far canopy plane is what the ray sees.
        canopy_box: (6,) float64 ``(height, x0, x1, y0, y1, min_range)``: the far canopy plane z = height over
            the row extent, only beyond ``min_range`` metres (horizontal) from the camera.
        tree_centre: (2,) float64 centre of the tree-line circles; tree_radii: (K,) their radii, metres.
        tree_profiles: (K, M) float32 tree-top height along each circle (M samples over 2π), metres.
        tree_top: (K,) float64 highest value of each profile, metres.
        tree_k, tree_arc, tree_z: (N,) outputs: tree line hit (-1: none), arc length (m) and height (m) of the hit.
        ids: (H_r, W_r) int32 polygon raster (-1: none); raster_x, raster_y: (N,) int32 the raster pixel of each
            ray (nearest).
        poly_tab: (P, 16) float32 polygon table (``render.poly_table``: normal in columns 6-8, radius 15).
        poly_orel: (P, 3) float32 polygon origin minus the camera centre, metres.
        poly_is_canopy: (P,) bool canopy-prism material (labelled canopy, not leaf).
        pixel_angle: angular pixel size, rad (a ray may miss a polygon's radius by up to two pixels).
        near_m: nearest accepted polygon hit, metres.
        poly_k: (N,) int32 output: visible polygon (-1: none).
    """
    ox, oy, oz = origin[0], origin[1], origin[2]
    hc, x0, x1, y0, y1, min_range = (canopy_box[0], canopy_box[1], canopy_box[2], canopy_box[3], canopy_box[4],
                                     canopy_box[5])
    ocx = ox - tree_centre[0]
    ocy = oy - tree_centre[1]
    oc2 = ocx * ocx + ocy * ocy
    r_min = tree_radii[0] - math.sqrt(oc2)
    n_prof = tree_profiles.shape[1]
    for r in range(dirs.shape[0]):
        dx = float(dirs[r, 0])
        dy = float(dirs[r, 1])
        dz = float(dirs[r, 2])
        tr = float(t[r])
        lab = LABEL_SOIL if math.isfinite(tr) else LABEL_SKY
        is_canopy = False
        # far canopy plane
        if dz < 0.0:
            tc = (hc - oz) / dz
            if tc < tr:
                pcx = ox + tc * dx
                pcy = oy + tc * dy
                ex = pcx - ox
                ey = pcy - oy
                if x0 < pcx < x1 and y0 < pcy < y1 and ex * ex + ey * ey >= min_range * min_range:
                    tr = tc
                    lab = LABEL_CANOPY
                    is_canopy = True
        # tree lines: only rays reaching beyond the nearest possible tree
        tk = -1
        a = dx * dx + dy * dy
        if not (tr * math.sqrt(a) < r_min) and a > 0.0:
            bq = 2.0 * (dx * ocx + dy * ocy)
            for k in range(tree_radii.shape[0]):
                rad = tree_radii[k]
                tt = (-bq + math.sqrt(max(bq * bq - 4.0 * a * (oc2 - rad * rad), 0.0))) / (2.0 * a)
                zt = oz + tt * dz
                if zt > tree_top[k] or zt < -2.0 or not tt < tr:  # above the highest tree (most sky rays)
                    continue
                phi = math.atan2(oy + tt * dy - tree_centre[1], ox + tt * dx - tree_centre[0])
                idx = (phi / (2.0 * math.pi) % 1.0) * n_prof
                i0 = int(idx) % n_prof
                fr = idx - math.floor(idx)
                top = tree_profiles[k, i0] * (1.0 - fr) + tree_profiles[k, (i0 + 1) % n_prof] * fr
                if zt <= top and zt >= -2.0 and tt < tr:
                    tr = tt
                    lab = LABEL_TREES
                    is_canopy = False
                    tk = k
                    tree_arc[r] = phi * rad
                    tree_z[r] = zt
                    break
        tree_k[r] = tk
        # the polygon the raster names: exact ray/plane hit, within its radius plus two pixels
        pk = -1
        p = ids[raster_y[r], raster_x[r]]
        if p >= 0:
            nx, ny, nz = float(poly_tab[p, 6]), float(poly_tab[p, 7]), float(poly_tab[p, 8])
            rx, ry, rz = float(poly_orel[p, 0]), float(poly_orel[p, 1]), float(poly_orel[p, 2])
            den = nx * dx + ny * dy + nz * dz
            if abs(den) > 1e-9:
                th = (nx * rx + ny * ry + nz * rz) / den
                if th > near_m and th < tr:
                    qx = th * dx - rx
                    qy = th * dy - ry
                    qz = th * dz - rz
                    reach = float(poly_tab[p, 15]) + 2.0 * pixel_angle * abs(th) * float(ray_norm[r])
                    if qx * qx + qy * qy + qz * qz <= reach * reach:
                        tr = th
                        pk = p
                        lab = LABEL_CANOPY if poly_is_canopy[p] else LABEL_LEAF
                        is_canopy = False
                        if tk >= 0:
                            tk = -1
                            tree_k[r] = -1
        poly_k[r] = pk
        t[r] = tr
        label[r] = lab
        canopy[r] = is_canopy


@numba.njit(**NJIT)
def max_vertex_distance(verts: np.ndarray, origin: np.ndarray, out: np.ndarray) -> None:
    """``out[k]``: largest distance (m) from ``origin[k]`` (N, 3) to a vertex of ``verts[k]`` (N, V, 3)."""
    for k in range(verts.shape[0]):
        best = 0.0
        for m in range(verts.shape[1]):
            dx = verts[k, m, 0] - origin[k, 0]
            dy = verts[k, m, 1] - origin[k, 1]
            dz = verts[k, m, 2] - origin[k, 2]
            best = max(best, dx * dx + dy * dy + dz * dz)
        out[k] = math.sqrt(best)
