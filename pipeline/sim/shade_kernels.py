"""Compiled (numba) shading of polygon pixels (leaflets, weeds, canopy prisms; see ``render._shade_polys``).

Two passes around the texture and shadow lookups, which stay with their own samplers:

1. :func:`poly_surface_coords`: texture coordinates on each pixel's polygon and its footprint;
2. :func:`poly_radiance`: the lighting model (two-sided normals, folded and arched leaf shading normals, sun with
   leaf translucency and glossy highlights, ambient with height occlusion; canopy prisms with a darker base).

Polygon pixel ``i`` is pixel ``q = pix[i]`` of a flattened bundle: ray ``d[q]`` (field frame, rectified z = 1)
of length ``norm_d[q]``, depth ``t[q]``; it shows polygon ``k[i]`` of the table ``tab`` (``render.poly_table``
columns: e1 0-2, e2 3-5, normal 6-8, albedo 9-11, size 12, extra 13, ground 14). Arithmetic is float64 per
pixel; results are float32.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT


@numba.njit(**NJIT)
def poly_surface_coords(d: np.ndarray, t: np.ndarray, norm_d: np.ndarray, pix: np.ndarray, k: np.ndarray,
                        tab: np.ndarray, orel: np.ndarray, origin: np.ndarray, pixel_angle: float,
                        out: np.ndarray) -> None:
    """``out[i] = (a, b, footprint, x, y, z)``: hit point in the polygon's texture axes (metres from its origin
    along e1, e2), the pixel's footprint on it (metres; grows as the view becomes grazing) and the hit point in
    the field frame (metres).

    Args:
        orel: (P, 3) float32 polygon origins minus the camera centre, metres.
        origin: (3,) float64 camera centre, field frame.
        pixel_angle: angular pixel size, rad.
        out: (N, 6) float32.
    """
    for i in range(k.size):
        p = k[i]
        q = pix[i]
        ti = float(t[q])
        hx = ti * d[q, 0]
        hy = ti * d[q, 1]
        hz = ti * d[q, 2]
        rx = hx - orel[p, 0]
        ry = hy - orel[p, 1]
        rz = hz - orel[p, 2]
        out[i, 0] = rx * tab[p, 0] + ry * tab[p, 1] + rz * tab[p, 2]
        out[i, 1] = rx * tab[p, 3] + ry * tab[p, 4] + rz * tab[p, 5]
        ndv = (tab[p, 6] * d[q, 0] + tab[p, 7] * d[q, 1] + tab[p, 8] * d[q, 2]) / norm_d[q]
        out[i, 2] = ti * norm_d[q] * pixel_angle / math.sqrt(max(abs(ndv), 0.05))
        out[i, 3] = origin[0] + hx
        out[i, 4] = origin[1] + hy
        out[i, 5] = origin[2] + hz


@numba.njit(**NJIT)
def poly_radiance(d: np.ndarray, t: np.ndarray, norm_d: np.ndarray, pix: np.ndarray, k: np.ndarray, tab: np.ndarray,
                  is_soy: np.ndarray, is_canopy: np.ndarray, coords: np.ndarray, tex: np.ndarray,
                  shadow: np.ndarray, origin_z: float, sun_dir: np.ndarray, sun_e: float, plant_height: float,
                  leaf_gloss: float, rad: np.ndarray, glare: np.ndarray) -> None:
    """Linear radiance ``rad[pix[i]]`` (RGB) of polygon pixels, and their glare radiance (the specular part) added to
    ``glare[pix[i]]``.

    Args:
        is_soy, is_canopy: (P,) bool soybean leaflet (midrib and veins) / canopy prism, per polygon.
        coords: (N, 3) from :func:`poly_surface_coords`.
        tex: (N, 3) float32: leaves: the leaf-noise factor in column 0; canopy prisms: the foliage albedo.
        shadow: (N,) float32 fraction of sun blocked by leaves (leaves only).
        origin_z: camera centre height, metres (field frame).
        sun_dir: (3,) unit direction towards the sun; sun_e: direct sun irradiance.
        plant_height: canopy height for the height occlusion, metres.
        leaf_gloss: strength of the glossy highlight.
        rad: (H·W, 3) float32 output; glare: (H·W,) float32, added to.
    """
    sx, sy, sz = sun_dir[0], sun_dir[1], sun_dir[2]
    for i in range(k.size):
        p = k[i]
        q = pix[i]
        ti = float(t[q])
        nd = float(norm_d[q])
        ux, uy, uz = d[q, 0] / nd, d[q, 1] / nd, d[q, 2] / nd
        nx, ny, nz = float(tab[p, 6]), float(tab[p, 7]), float(tab[p, 8])
        ndv = nx * ux + ny * uy + nz * uz
        sgn = 1.0
        if ndv > 0.0:  # two-sided: the normal towards the viewer
            nx, ny, nz = -nx, -ny, -nz
            sgn = -1.0
        a = float(coords[i, 0])
        b = float(coords[i, 1])
        if is_canopy[p]:
            ao = 1.0 - 0.35 * min(max(b / 0.35, 0.0), 1.0)
            irr = ao * 0.8 + sun_e * 0.85 * max(nx * sx + ny * sy + nz * sz, 0.0)
            for c in range(3):
                rad[q, c] = tex[i, c] * irr
            continue
        size = float(tab[p, 12])
        ex = float(tab[p, 13])
        aa = a / size
        bb = b / size
        f = 1.0
        if is_soy[p]:
            midrib = math.exp(-(bb / 0.02) ** 2)
            vein = max(math.cos(2.0 * math.pi / 0.14 * (aa - 1.5 * abs(bb))), 0.0) ** 10 * (abs(bb) < 0.28)
            f = 1.0 + 0.22 * midrib + 0.10 * vein
        f *= float(tex[i, 0])
        # leaves are not flat: folded along the midrib and arched along it (shading normal only)
        fold = (0.6 + 0.9 * ex) * min(max(bb, -0.35), 0.35)
        arch = 0.5 * (aa - 0.5)
        lx = nx + sgn * (fold * tab[p, 3] + arch * tab[p, 0])
        ly = ny + sgn * (fold * tab[p, 4] + arch * tab[p, 1])
        lz = nz + sgn * (fold * tab[p, 5] + arch * tab[p, 2])
        ln = math.sqrt(lx * lx + ly * ly + lz * lz)
        lx, ly, lz = lx / ln, ly / ln, lz / ln
        ndl = lx * sx + ly * sy + lz * sz
        hz = origin_z + ti * d[q, 2] - tab[p, 14]
        ao = 0.45 + 0.55 * min(max(hz / max(plant_height, 0.05), 0.0), 1.2)
        lit = sun_e * (1.0 - shadow[i])
        front = max(ndl, 0.0)
        trans = max(-ndl, 0.0) * 0.45
        ambient = ao * (0.55 + 0.45 * abs(lz))
        base = ambient + lit * (front + trans * 0.8)
        hx, hy, hzv = sx - ux, sy - uy, sz - uz
        hn = math.sqrt(hx * hx + hy * hy + hzv * hzv)
        ndh = max((lx * hx + ly * hy + lz * hzv) / hn, 0.0)
        spec = ndh ** 48 * (ndl > 0.0) * lit * leaf_gloss * 0.9 * (0.6 + 0.8 * ex)
        tint = (0.25, 0.35, 0.0)
        white = (1.0, 1.0, 0.95)
        for c in range(3):
            alb = float(tab[p, 9 + c]) * f
            rad[q, c] = alb * base + alb * tint[c] * lit * trans + spec * white[c]
        glare[q] += spec


@numba.njit(**NJIT)
def sensor_linear(lin: np.ndarray, vignette: np.ndarray, gain: float, out: np.ndarray) -> None:
    """``out = clip(lin · vignette · gain, 0, 1)``: (H, W, 3) float32 linear sensor level (before the gamma)."""
    h, w = vignette.shape
    for i in range(h):
        for j in range(w):
            f = vignette[i, j] * gain
            for c in range(3):
                out[i, j, c] = min(max(lin[i, j, c] * f, 0.0), 1.0)


@numba.njit(**NJIT)
def sensor_digitise(val: np.ndarray, offset_dn: float, read_noise_dn: float, shot_noise: float, noise: np.ndarray,
                    bgr: np.ndarray) -> float:
    """Digital numbers of gamma-encoded levels ``val`` (H, W, 3) RGB in 0..1: ``dn = 255 · val + offset`` plus
    Gaussian read and shot noise (``noise``: standard-normal samples, same shape), rounded and clipped into
    ``bgr`` (H, W, 3) uint8 in BGR order. Returns the mean of ``val`` (the auto-exposure input)."""
    h, w = val.shape[0], val.shape[1]
    read2 = read_noise_dn * read_noise_dn
    total = 0.0
    for i in range(h):
        row = 0.0
        for j in range(w):
            for c in range(3):
                v = float(val[i, j, c])
                row += v
                dn = v * 255.0 + offset_dn
                dn += math.sqrt(read2 + shot_noise * max(dn, 0.0)) * noise[i, j, c]
                bgr[i, j, 2 - c] = np.uint8(min(max(np.rint(dn), 0.0), 255.0))
        total += row
    return total / (h * w * 3)
