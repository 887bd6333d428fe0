"""Terrain geometry: ``z = h(x, y)`` in the field frame (metres), sampled from two grids.

* undulation: smooth waves of 25-90 m wavelength (total amplitude ``field.undulation_m``) on a 2 m grid covering
  1.6 km around the field, fading to flat beyond;
* relief: tileable noise of 0.3-3 m features (wheel ruts, furrows, soil heaps), standard deviation
  ``0.6 · field.roughness_m``, on a 2 cm grid with a 10.24 m period.

The terrain *is* the bilinear interpolation of these grids (exactly what every plant and wheel uses). Slopes come
from precomputed grid gradients (interpolated the same way).

Rendering level of detail: when a frame is rendered, the relief fades out between 8 and 20 m from the rig
(``RELIEF_FADE_M``) and the undulation between 60 and 150 m (``UNDULATION_FADE_M``), measured from the rig's
position of that frame, so both cameras of a frame see one surface. Beyond those ranges a relief of centimetres is
far below a pixel, while grazing rays over it would make the ray intersection ill-posed. The fade factor of a ray
is taken at its first estimate of the hit (the plane z = 0) and kept through the Newton steps; shading slopes
ignore the fade's own gradient (it changes by 1/12 per metre over centimetres of relief).
The clod-scale relief (1-8 cm) is not geometry: it is bump-mapped in the soil shading (``textures.make_soil``);
at the camera's distances (≥ 0.9 m) its effect on disparity is below 0.1 px.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.sim.config import FieldConfig
from pipeline.sim.noise import fbm

_LONG_STEP_M = 2.0
_LONG_HALF_M = 800.0
_RELIEF_TEXEL_M = 0.02
_RELIEF_SIZE = 512
RELIEF_FADE_M = (8.0, 20.0)
UNDULATION_FADE_M = (60.0, 150.0)


class Terrain:
    """Ground height of the field frame.

    Args:
        cfg: field parameters (``undulation_m``, ``roughness_m``).
        seed: world seed.
        centre: (x, y) field-frame centre of the undulation grid (the field's centre), metres.
    """

    def __init__(self, cfg: FieldConfig, seed: int, centre: tuple[float, float] = (0.0, 0.0)) -> None:
        rng = np.random.default_rng([seed, 201])
        n = int(2 * _LONG_HALF_M / _LONG_STEP_M) + 1
        self._long_origin = np.array(centre, np.float64) - _LONG_HALF_M
        ax = np.arange(n) * _LONG_STEP_M
        gx, gy = np.meshgrid(ax + self._long_origin[0], ax + self._long_origin[1])
        h = np.zeros_like(gx)
        hx = np.zeros_like(gx)
        hy = np.zeros_like(gx)
        lam = rng.uniform(25.0, 90.0, 4)
        ang = rng.uniform(0, np.pi, 4)
        amp = rng.uniform(0.5, 1.0, 4)
        amp *= cfg.undulation_m / amp.sum()
        ph = rng.uniform(0, 2 * np.pi, 4)
        for lj, aj, mj, pj in zip(lam, ang, amp, ph):
            kx, ky = 2 * np.pi / lj * np.cos(aj), 2 * np.pi / lj * np.sin(aj)
            arg = kx * gx + ky * gy + pj
            h += mj * np.sin(arg)
            hx += mj * kx * np.cos(arg)
            hy += mj * ky * np.cos(arg)
        # fade to flat towards the grid border (smoothly, so the slopes stay consistent)
        r = np.hypot(gx - centre[0], gy - centre[1])
        win = np.clip((_LONG_HALF_M - 100.0 - r) / 300.0, 0.0, 1.0)
        win = win * win * (3 - 2 * win)
        self._long = np.stack([h * win, hx * win, hy * win], -1).astype(np.float32)
        rel = fbm(rng, _RELIEF_SIZE, ((15.0, 0.5), (35.0, 0.8), (70.0, 0.6)))
        rel = rel * np.float32(0.6 * cfg.roughness_m)
        rx = (np.roll(rel, -1, 1) - np.roll(rel, 1, 1)) / np.float32(2 * _RELIEF_TEXEL_M)
        ry = (np.roll(rel, -1, 0) - np.roll(rel, 1, 0)) / np.float32(2 * _RELIEF_TEXEL_M)
        self._relief = np.stack([rel, rx, ry], -1).astype(np.float32)
        self.h_min = float(self._long[..., 0].min() + rel.min()) - 1e-3
        self.h_max = float(self._long[..., 0].max() + rel.max()) + 1e-3

    def height_grad(self, x: np.ndarray, y: np.ndarray, weights: tuple[np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(h, dh/dx, dh/dy)`` (float32) at field coordinates ``x, y`` (same-shape arrays, metres).

        ``weights``: per-point (undulation, relief) level-of-detail factors from :meth:`lod_weights`; None = full
        detail.
        """
        x = np.asarray(x)
        y = np.asarray(y)
        shape = x.shape
        xf = x.reshape(-1) if x.ndim != 2 else x
        yf = y.reshape(-1) if y.ndim != 2 else y
        u_l = ((xf - self._long_origin[0]) / _LONG_STEP_M).astype(np.float32)
        v_l = ((yf - self._long_origin[1]) / _LONG_STEP_M).astype(np.float32)
        u_r = (np.mod(xf, _RELIEF_SIZE * _RELIEF_TEXEL_M) / _RELIEF_TEXEL_M - 0.5).astype(np.float32)
        v_r = (np.mod(yf, _RELIEF_SIZE * _RELIEF_TEXEL_M) / _RELIEF_TEXEL_M - 0.5).astype(np.float32)
        a = _remap(self._long, u_l, v_l, cv2.BORDER_CONSTANT)
        b = _remap(self._relief, u_r, v_r, cv2.BORDER_WRAP)
        if weights is None:
            s = a + b
        else:
            wu, wr = weights
            s = a * wu.reshape(a.shape[:-1] + (1,)) + b * wr.reshape(b.shape[:-1] + (1,))
        return s[..., 0].reshape(shape), s[..., 1].reshape(shape), s[..., 2].reshape(shape)

    @staticmethod
    def lod_weights(dist_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(undulation, relief) weights (float32) for points at horizontal distance ``dist_m`` from the rig."""
        d = np.asarray(dist_m, np.float32)
        (u0, u1), (r0, r1) = UNDULATION_FADE_M, RELIEF_FADE_M
        return (np.clip((np.float32(u1) - d) / np.float32(u1 - u0), 0, 1),
                np.clip((np.float32(r1) - d) / np.float32(r1 - r0), 0, 1))

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height (float64, metres) at field coordinates ``x, y`` (any same shapes, or scalars)."""
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        xb, yb = np.broadcast_arrays(x, y)
        h, _, _ = self.height_grad(xb.reshape(-1), yb.reshape(-1))
        return h.astype(np.float64).reshape(xb.shape)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray, t_max: float, iterations: int = 2,
                  ref_xy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """First ground hit of rays ``origin + t · dirs``.

        Newton iterations from the hit with the plane ``z = 0``. Converges to well below 1 mm where the ray
        descends more steeply than the terrain's slope (all but grazing rays near the horizon, which are far
        away and sub-pixel in disparity).

        Args:
            origin: (3,) ray origin, field frame, metres.
            dirs: (..., 3) float32 ray directions (any length: ``t`` is in units of it).
            t_max: rays not pointing down, or hitting beyond ``t_max``, give ``inf``.
            iterations: Newton steps.
            ref_xy: rendering reference point for the level-of-detail fades (see the module docstring).
        Returns:
            ``(t, h, hx, hy)``, each shaped like ``dirs[..., 0]`` (float32): the ray parameter and the terrain
            height and slopes at the hit (from the last iteration; not meaningful where ``t`` is inf).
        """
        dz = dirs[..., 2]
        down = dz < -1e-5
        safe_dz = np.where(down, dz, np.float32(-1.0))
        oz = np.float32(origin[2])
        # the ray can only meet the ground inside the slab [h_min, h_max]: start at the plane z = 0 within it
        t_in = np.maximum((np.float32(self.h_max) - oz) / safe_dz, np.float32(1e-3))
        t_out = (np.float32(self.h_min) - oz) / safe_dz
        t = np.clip(-oz / safe_dz, t_in, t_out)
        weights = None
        if ref_xy is not None:
            ex = np.float32(origin[0] - ref_xy[0]) + t * dirs[..., 0]
            ey = np.float32(origin[1] - ref_xy[1]) + t * dirs[..., 1]
            weights = self.lod_weights(np.sqrt(ex * ex + ey * ey))
        h = hx = hy = np.zeros_like(t)
        for _ in range(iterations):
            px = np.float32(origin[0]) + t * dirs[..., 0]
            py = np.float32(origin[1]) + t * dirs[..., 1]
            h, hx, hy = self.height_grad(px, py, weights)
            f = oz + t * dz - h
            fp = np.minimum(safe_dz - hx * dirs[..., 0] - hy * dirs[..., 1], np.float32(0.2) * safe_dz)
            t = np.clip(t - f / fp, t_in, t_out)
        t = np.where(down & (t < t_max), t, np.float32(np.inf)).astype(np.float32)
        return t, h, hx, hy


def _remap(grid: np.ndarray, u: np.ndarray, v: np.ndarray, border: int) -> np.ndarray:
    """Bilinear lookup of a (H, W, C) grid at texel coordinates u, v (1-D or 2-D arrays); returns (..., C)."""
    if u.ndim == 2 and u.shape[0] < 32000 and u.shape[1] < 32000:
        return cv2.remap(grid, u, v, cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    n = u.size
    width = 1024
    rows = max(1, -(-n // width))
    pad = rows * width - n
    U = np.pad(u.ravel(), (0, pad)).reshape(rows, width)
    V = np.pad(v.ravel(), (0, pad)).reshape(rows, width)
    out = cv2.remap(grid, U, V, cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    return out.reshape(rows * width, grid.shape[2])[:n]
