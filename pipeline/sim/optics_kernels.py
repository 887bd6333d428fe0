"""Compiled (numba) per-pixel optics of the renderer: veiling glare with lens-flare ghosts, and the last pass over
a shaded image (aerial haze on far surfaces, then the glare on top).

Arithmetic is float64 per pixel; results are float32. Pixels are the rays of a bundle (``render.RayBundle``),
flattened: ``dirs`` (N, 3) float32 field-frame rays, ``norm`` (N,) their lengths, ``cam_rays`` (N, 3) the same rays
in the rectified camera frame (z = 1).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.sim.jit import NJIT


@numba.njit(**NJIT)
def glare_field(dirs: np.ndarray, norm: np.ndarray, cam_rays: np.ndarray, sun_dir: np.ndarray, strength: float,
                ghosts: np.ndarray, out: np.ndarray) -> None:
    """Glare radiance ``out`` (N,) float32: a veiling halo around the sun direction (a Lorentzian core of
    ≈ 3° plus a wide exponential skirt), times ``strength``, plus Gaussian-like ghosts.

    Args:
        sun_dir: (3,) unit vector towards the sun, field frame.
        ghosts: (G, 4) float64 ``(x, y, radius, amplitude)`` of each ghost in rectified-normalised camera
            coordinates (G may be 0); a ghost adds ``amplitude · exp(-r⁴)`` with ``r = distance / radius``, out to
            ``r = 2``.
    """
    sx, sy, sz = sun_dir[0], sun_dir[1], sun_dir[2]
    n_g = ghosts.shape[0]
    for k in range(norm.size):
        cosang = (dirs[k, 0] * sx + dirs[k, 1] * sy + dirs[k, 2] * sz) / norm[k]
        ang2 = max(2.0 * (1.0 - cosang), 0.0)  # ≈ angle² near the sun
        g = (0.35 / (1.0 + ang2 / 0.0025) + 0.06 * math.exp(-math.sqrt(ang2) / 0.3)) * strength
        for m in range(n_g):
            ex = cam_rays[k, 0] - ghosts[m, 0]
            ey = cam_rays[k, 1] - ghosts[m, 1]
            r2 = (ex * ex + ey * ey) / (ghosts[m, 2] * ghosts[m, 2])
            if r2 < 4.0:
                g += ghosts[m, 3] * math.exp(-r2 * r2)
        out[k] = g


@numba.njit(**NJIT)
def haze_and_glare(is_sky: np.ndarray, t: np.ndarray, norm: np.ndarray, haze_per_m: float, horizon: np.ndarray,
                   glare: np.ndarray, has_glare: bool, rad: np.ndarray, glare_rad: np.ndarray) -> None:
    """In place over the pixels of an image: surfaces farther than 20 m along the ray fade towards the horizon
    colour (``rad ← rad · e + 1.1 · horizon · (1 - e)``, ``e = exp(-distance · haze_per_m)``), then, when
    ``has_glare``, the glare ``glare`` (N,) is added to ``rad`` (N, 3; slightly warm: 1, 0.97, 0.9 in RGB) and to
    ``glare_rad`` (N,).

    Args:
        is_sky: (N,) bool sky pixels (no haze: the sky model has its own horizon).
        t, norm: (N,) float32 depth and ray length (distance = t · norm, metres).
        horizon: (3,) float32 horizon radiance.
    """
    h0, h1, h2 = 1.1 * horizon[0], 1.1 * horizon[1], 1.1 * horizon[2]
    for k in range(t.size):
        if not is_sky[k]:
            d = float(t[k]) * float(norm[k])
            if d > 20.0:
                e = math.exp(-d * haze_per_m)
                rad[k, 0] = rad[k, 0] * e + h0 * (1.0 - e)
                rad[k, 1] = rad[k, 1] * e + h1 * (1.0 - e)
                rad[k, 2] = rad[k, 2] * e + h2 * (1.0 - e)
        if has_glare:
            g = float(glare[k])
            rad[k, 0] += g
            rad[k, 1] += g * 0.97
            rad[k, 2] += g * 0.9
            glare_rad[k] += g
