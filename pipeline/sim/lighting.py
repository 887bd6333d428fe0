"""Sun, sky, clouds and the cloud-shadow dimming of the sun (radiance in relative linear units).

Units: the sky's diffuse irradiance on a horizontal surface is 1; the direct sun irradiance (on a surface facing
the sun) is ``lighting.sun_irradiance · transmittance``, where the transmittance drops when a cloud of the drifting
cloud layer (1.5 km up) crosses the line from the camera to the sun. Surface radiance = albedo · irradiance.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

from pipeline.sim.config import LightingConfig
from pipeline.sim.noise import MipTexture
from pipeline.sim.textures import make_clouds

CLOUD_HEIGHT_M = 1500.0
SUN_RADIUS_RAD = 0.00465


class Sky:
    """Sun direction, sky radiance, cloud layer.

    Args:
        cfg: lighting parameters.
        field_azimuth_deg: direction of the field's +y axis from north towards east (to express the sun's ENU
            direction in the field frame).
        seed: world seed (cloud texture).
    """

    def __init__(self, cfg: LightingConfig, field_azimuth_deg: float, seed: int) -> None:
        self.cfg = cfg
        el = np.radians(cfg.sun_elevation_deg)
        # sun azimuth relative to the field's +y axis, measured towards +x (east-like): field frame = ENU rotated
        rel = np.radians(cfg.sun_azimuth_deg - field_azimuth_deg)
        self.sun_dir = np.array([np.cos(el) * np.sin(rel), np.cos(el) * np.cos(rel), np.sin(el)])
        self.clouds: MipTexture = make_clouds(seed)
        cover = float(np.clip(cfg.cloud_cover, 0.0, 1.0))
        self._threshold = float(ndtri(1.0 - cover)) if 0 < cover < 1 else (-9.0 if cover >= 1 else 9.0)
        ang = np.radians(cfg.sun_azimuth_deg * 0.7 + 40.0)
        self._wind = cfg.cloud_speed_mps * np.array([np.cos(ang), np.sin(ang)])
        self.horizon = np.array([0.78, 0.84, 0.92], np.float32) * 1.35
        self.zenith = np.array([0.20, 0.36, 0.80], np.float32) * 1.05

    def cloud_alpha(self, x: np.ndarray, y: np.ndarray, t_s: float, footprint: np.ndarray | float) -> np.ndarray:
        """Cloud opacity 0..1 at cloud-layer coordinates (field frame x, y in metres) at time ``t_s``."""
        dens = self.clouds.sample(x - self._wind[0] * t_s, y - self._wind[1] * t_s, footprint)
        return np.clip((dens - self._threshold) / 0.55 + 0.5, 0.0, 1.0) ** 1.2

    def sun_transmittance(self, cam_pos: np.ndarray, t_s: float) -> float:
        """Fraction of direct sunlight reaching ``cam_pos`` (clouds on the line of sight to the sun)."""
        s = self.sun_dir
        k = (CLOUD_HEIGHT_M - cam_pos[2]) / max(s[2], 0.02)
        a = self.cloud_alpha(np.array([cam_pos[0] + k * s[0]]), np.array([cam_pos[1] + k * s[1]]), t_s, 40.0)
        return float(1.0 - 0.82 * a[0])

    def sun_irradiance(self, cam_pos: np.ndarray, t_s: float) -> float:
        return self.cfg.sun_irradiance * self.sun_transmittance(cam_pos, t_s)

    def radiance(self, dirs: np.ndarray, cam_pos: np.ndarray, t_s: float, sun_e: float,
                 px_angle: float, sun_disk: bool = True) -> np.ndarray:
        """Sky radiance (N, 3) float32 along unit directions ``dirs`` (N, 3) (field frame).

        ``sun_e``: current direct irradiance (dims the sun disk and halo); ``px_angle``: angular pixel size, rad;
        ``sun_disk``: add the sun's disk (off when the caller draws it at another resolution).
        """
        d = dirs.astype(np.float32)
        el = np.clip(d[:, 2], 0.0, 1.0)
        w = (1.0 - el) ** 3
        base = self.zenith[None] * (1 - w[:, None]) + self.horizon[None] * w[:, None]
        cosang = np.clip(d @ self.sun_dir.astype(np.float32), -1.0, 1.0)
        ang = np.arccos(cosang)
        halo = (0.10 * np.exp(-ang / 0.14) + 0.04 * np.exp(-ang / 0.6)).astype(np.float32) * np.float32(sun_e / 3.0)
        base = base + halo[:, None] * np.array([1.0, 0.93, 0.8], np.float32)[None]
        # cloud layer
        up = d[:, 2] > 0.02
        if np.any(up):
            du = d[up]
            k = (CLOUD_HEIGHT_M - cam_pos[2]) / du[:, 2]
            cx = cam_pos[0] + k * du[:, 0]
            cy = cam_pos[1] + k * du[:, 1]
            fp = k * px_angle / np.maximum(du[:, 2], 0.05)
            alpha = self.cloud_alpha(cx, cy, t_s, fp) * np.clip((du[:, 2] - 0.02) / 0.12, 0, 1)
            lit = 1.45 + 1.2 * halo[up] * 3.0
            cloud = np.stack([lit, lit, lit * 1.03], 1) * (1.0 - 0.35 * alpha[:, None])
            base[up] = base[up] * (1 - alpha[:, None]) + cloud * alpha[:, None]
        # sun disk (area-weighted when smaller than a pixel)
        disk = ang < max(SUN_RADIUS_RAD, 0.5 * px_angle)
        if sun_disk and np.any(disk):
            frac = (SUN_RADIUS_RAD / max(SUN_RADIUS_RAD, 0.5 * px_angle)) ** 2
            base[disk] += np.float32(400.0 * sun_e * frac)
        return base.astype(np.float32)
