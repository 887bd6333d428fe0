"""Compiled (numba) shading of the ground: soil pixel geometry, the leaf shadow map lookup, the analytic canopy
row shadow and ambient occlusion, and the bump-mapped soil lighting (see ``render._shade_soil``).

The soil's textures are sampled between :func:`soil_footprints` and :func:`soil_radiance` by the texture kernels.
Arithmetic is float64 per pixel; results are float32.

Shadow map (``render.FieldRenderer.shadow_atlas``): ``amap`` (H, W) float32 holds, per 1 cm texel of the ground,
the height of the highest leaf whose sun shadow falls there; texel ``(i, j)`` is centred at
``corner + ((j, i) + 0.5) · texel`` in the field frame (metres).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT


@numba.njit(inline="always", **NJIT)
def _occlusion(amap: np.ndarray, cx: float, cy: float, inv_texel: float, x: float, y: float, z: float,
               tol: float) -> float:
    """Fraction (0..1) of sun blocked at the point whose sun shadow falls at ground ``(x, y)`` and which lies
    ``z`` metres high: exact bilinear lookup of the shadow map, 0 outside it; blocked where a leaf more than
    ``tol`` above the point casts the shadow, with a 1 cm soft edge."""
    u = (x - cx) * inv_texel - 0.5
    v = (y - cy) * inv_texel - 0.5
    if not (u >= 0.0 and v >= 0.0 and u < amap.shape[1] - 1 and v < amap.shape[0] - 1):
        return 0.0
    j = int(u)
    i = int(v)
    a = u - j
    b = v - i
    occ = (1.0 - b) * ((1.0 - a) * amap[i, j] + a * amap[i, j + 1]) + b * ((1.0 - a) * amap[i + 1, j] +
                                                                          a * amap[i + 1, j + 1])
    return min(max((occ - z - tol) * 100.0, 0.0), 1.0)


@numba.njit(**NJIT)
def atlas_occlusion(amap: np.ndarray, corner: np.ndarray, disp: np.ndarray, texel_m: float, px: np.ndarray,
                    py: np.ndarray, pz: np.ndarray, hz: np.ndarray, tol: float, out: np.ndarray) -> None:
    """``out[k]``: fraction of sun blocked by leaves at points ``(px, py, pz)[k]`` (field frame, metres) that lie
    ``hz[k]`` above the ground; their shadow falls at ``(px, py) + hz · disp`` (``disp``: (2,) ground displacement
    per metre of height along the sun rays). ``corner``: (2,) the map's corner."""
    inv = 1.0 / texel_m
    for k in range(px.size):
        h = float(hz[k])
        out[k] = _occlusion(amap, corner[0], corner[1], inv, px[k] + h * disp[0], py[k] + h * disp[1], float(pz[k]),
                            tol)


@numba.njit(**NJIT)
def soil_footprints(dirs: np.ndarray, t: np.ndarray, norm: np.ndarray, idx: np.ndarray, ox: float, oy: float,
                    pixel_angle: float, px: np.ndarray, py: np.ndarray, dist: np.ndarray, lod_m: np.ndarray) -> None:
    """Ground points of the soil pixels ``idx`` (into the flattened bundle: rays ``dirs`` (N, 3), depths ``t``,
    ray lengths ``norm``) seen from ``(ox, oy)``: ``px, py`` (field frame, metres), the distance along the ray
    ``dist`` (metres) and ``lod_m = log2(footprint / 1 m)`` of the pixel on the ground (grows at grazing
    incidence)."""
    for n in range(idx.size):
        k = idx[n]
        tk = float(t[k])
        nk = float(norm[k])
        px[n] = ox + tk * dirs[k, 0]
        py[n] = oy + tk * dirs[k, 1]
        cos_inc = max(-dirs[k, 2] / nk, 0.02)
        d = tk * nk
        dist[n] = d
        lod_m[n] = math.log2(max(d * pixel_angle / math.sqrt(cos_inc), 1e-6))


@numba.njit(**NJIT)
def soil_radiance(idx: np.ndarray, px: np.ndarray, py: np.ndarray, dist: np.ndarray, hgx: np.ndarray,
                  hgy: np.ndarray, surf: np.ndarray, grain: np.ndarray, large: np.ndarray, amap: np.ndarray,
                  corner: np.ndarray, texel_m: float, shadow_range: float, rows: np.ndarray, sun_dir: np.ndarray,
                  sun_e: float, out: np.ndarray) -> None:
    """Linear radiance of soil pixels into ``out`` (H·W, 3) at ``idx``.

    Lambert sun on the bump-mapped surface (terrain slopes ``hgx, hgy`` plus the texture's slopes
    ``surf[:, 3:5]``) and sky light with ambient occlusion between the rows; albedo ``surf[:, :3]`` times the
    ``grain`` and ``large`` factors. Sun shadows: leaf shadows from the map ``amap`` (empty: none) within
    ``shadow_range`` metres, the analytic row shadow beyond (blended over the last metre).

    Args:
        px, py, dist: from :func:`soil_footprints`.
        rows: (7,) float64 ``(row spacing, canopy height, canopy half width, x0, x1, y0, y1)`` (row extent).
        sun_dir: (3,) unit vector towards the sun (z up).
    """
    s, hc, w_c, x0, x1, y0, y1 = rows[0], rows[1], rows[2], rows[3], rows[4], rows[5], rows[6]
    sdx, sdy, sdz = sun_dir[0], sun_dir[1], sun_dir[2]
    inv_sz = 1.0 / max(sdz, 0.05)
    inv_texel = 1.0 / texel_m
    has_map = amap.shape[0] > 1
    for n in range(idx.size):
        x = float(px[n])
        y = float(py[n])
        d = float(dist[n])
        gx = hgx[n] + surf[n, 3]
        gy = hgy[n] + surf[n, 4]
        inv = 1.0 / math.sqrt(gx * gx + gy * gy + 1.0)
        lam = max((sdz - gx * sdx - gy * sdy) * inv, 0.0)
        shadow = 0.0
        ao = 1.0
        if has_map and d < shadow_range:
            shadow = _occlusion(amap, corner[0], corner[1], inv_texel, x, y, 0.0, 0.01)
        if x > -1.0 and x < x1 + 1.0 and y > -1.0 and y < y1 + 1.0:
            rs = 0.0
            for frac in (0.2, 0.45, 0.7):
                z = frac * hc
                qx = x + z * sdx * inv_sz
                qy = y + z * sdy * inv_sz
                dq = abs(qx - s * math.floor(qx / s + 0.5))
                if dq < w_c * (1.0 - frac) and y0 < qy < y1 and x0 < qx < x1:
                    rs += 1.0 / 3.0
            blend = min(max(d - (shadow_range - 1.0), 0.0), 1.0)
            shadow = shadow * (1.0 - blend) + rs * blend
            if y0 < y < y1 and x0 < x < x1:
                d0 = abs(x - s * math.floor(x / s + 0.5)) / (0.8 * w_c)
                ao = 1.0 - 0.45 * math.exp(-d0 * d0)
        irr = (0.55 + 0.45 * inv) * ao + sun_e * lam * (1.0 - shadow)
        f = grain[n] * large[n] * irr
        k = idx[n]
        out[k, 0] = surf[n, 0] * f
        out[k, 1] = surf[n, 1] * f
        out[k, 2] = surf[n, 2] * f
