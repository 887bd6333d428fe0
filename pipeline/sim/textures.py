"""Surface textures of the simulated field (all tileable, linear-RGB albedo, generated once per world seed).

* soil: dark/dry soil colour, pebbles (scikit-image's ``gravel`` photo as grain), clods (relief → bump mapping
  and crevice darkening), straw residue of a no-till field (light, elongated pieces drawn with OpenCV);
* foliage: what a row of soybean plants looks like from afar (the far canopy prisms and plane);
* trees: the distant tree line; clouds: the cloud layer's density.

Colours are linear RGB albedo (0..1); :func:`srgb_to_linear` converts the sRGB colours they were picked in.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.sim.config import FieldConfig
from pipeline.sim.noise import MipTexture, fbm, periodic_blur


def srgb_to_linear(rgb: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """sRGB in 0..255 to linear 0..1 (float32)."""
    c = np.asarray(rgb, np.float32) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


#: Level-0 texel of the soil textures, metres (the near ground is seen at ≈3-5 mm per pixel).
SOIL_TEXEL_M = 0.0045
SOIL_SIZE = 1024


@dataclass
class SoilTextures:
    """Soil appearance.

    Attributes:
        surface: 5 channels: RGB albedo and (dh/dx, dh/dy) of the clod relief (dimensionless slopes, for
            bump-mapped shading); period ``SOIL_SIZE · SOIL_TEXEL_M`` (4.6 m).
        grain: fine pebble grain (multiplier around 1), 1.5 mm texels, 0.77 m period.
        large: low-frequency colour variation (multiplier around 1), 0.25 m texels, 64 m period.
    """

    surface: MipTexture
    grain: MipTexture
    large: MipTexture


def _draw_wrapped_lines(canvas: np.ndarray, p0: np.ndarray, p1: np.ndarray, colors: np.ndarray,
                        widths: np.ndarray) -> None:
    """Draw line segments on a tileable canvas (segments crossing an edge continue on the opposite side)."""
    n = canvas.shape[0]
    for a, b, c, w in zip(p0, p1, colors, widths):
        lo = np.minimum(a, b)
        hi = np.maximum(a, b)
        shifts_x = [0] + ([n] if lo[0] < w else []) + ([-n] if hi[0] > n - 1 - w else [])
        shifts_y = [0] + ([n] if lo[1] < w else []) + ([-n] if hi[1] > n - 1 - w else [])
        col = tuple(float(v) for v in c)
        for sx in shifts_x:
            for sy in shifts_y:
                cv2.line(canvas, (int(a[0] + sx), int(a[1] + sy)), (int(b[0] + sx), int(b[1] + sy)), col, int(w),
                         cv2.LINE_AA)


def make_soil(cfg: FieldConfig, seed: int) -> SoilTextures:
    """Generate the soil textures of a field (≈0.5 s)."""
    from skimage import data as skdata  # scikit-image ships the 'gravel' photo

    rng = np.random.default_rng([seed, 101])
    n = SOIL_SIZE
    # clod relief (metres): blobs of 1-8 cm with sharper crests, std = roughness/2 (the rest is geometric relief)
    rel = fbm(rng, n, ((1.2, 0.25), (3.0, 0.55), (7.0, 0.6), (16.0, 0.45)))
    rel = np.sign(rel) * np.abs(rel) ** 0.8
    clods = rel * np.float32(max(cfg.roughness_m, 1e-4) * 0.5)
    # straw residue: elongated light pieces, with a few mm of thickness in the relief
    straw_rgb = np.zeros((n, n, 3), np.float32)
    straw_a = np.zeros((n, n), np.float32)
    count = int(cfg.straw_cover * n * n / 260.0)
    if count:
        centre = rng.uniform(0, n, (count, 2))
        length = rng.uniform(25, 110, count)
        ang = rng.uniform(0, np.pi, count)
        d = np.stack([np.cos(ang), np.sin(ang)], 1) * (length / 2)[:, None]
        tone = rng.uniform(0.0, 1.0, count)
        base = srgb_to_linear((178, 162, 128))
        grey = srgb_to_linear((150, 146, 136))
        cols = (base[None] * (1 - tone[:, None] * 0.6) + grey[None] * tone[:, None] * 0.6) * \
            rng.uniform(0.75, 1.15, (count, 1)).astype(np.float32)
        widths = rng.choice([2, 2, 3, 3, 4], count)
        # draw alpha and colour (alpha via a separate single-channel canvas)
        _draw_wrapped_lines(straw_rgb, centre - d, centre + d, cols, widths)
        _draw_wrapped_lines(straw_a[..., None], centre - d, centre + d, np.ones((count, 1)), widths)
        straw_a = np.clip(straw_a, 0, 1)
    height = clods + straw_a * np.float32(0.004)
    # slopes for bump mapping (periodic central differences)
    gx = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) / np.float32(2 * SOIL_TEXEL_M)
    gy = (np.roll(height, -1, 0) - np.roll(height, 1, 0)) / np.float32(2 * SOIL_TEXEL_M)
    relief = np.stack([gx, gy], -1).astype(np.float32)

    # soil colour: moist dark ↔ dry light, mottled; crevices darker, clod tops lighter (drier)
    dark = srgb_to_linear((92, 76, 62))
    dry = srgb_to_linear((138, 118, 98))
    m = float(np.clip(cfg.soil_moisture, 0, 1))
    mott = fbm(rng, n, ((6.0, 0.5), (20.0, 0.5), (60.0, 0.6)))
    dryness = np.clip(0.5 + 0.35 * (1 - 2 * m) + 0.18 * mott + 2.5 * clods / max(cfg.roughness_m, 1e-4) * 0.12, 0, 1)
    soil = dark[None, None] * (1 - dryness[..., None]) + dry[None, None] * dryness[..., None]
    speck = fbm(rng, n, ((0.0, 1.0), (0.8, 0.6)))
    soil *= (1.0 + 0.10 * speck)[..., None]
    # a few small stones / dark organic bits
    blobs = np.zeros((n, n), np.float32)
    for (cx, cy), r, v in zip(rng.uniform(0, n, (900, 2)), rng.uniform(1.0, 3.5, 900), rng.uniform(-0.6, 0.5, 900)):
        cv2.circle(blobs, (int(cx), int(cy)), int(round(r)), float(v), -1, cv2.LINE_AA)
    soil *= (1.0 + periodic_blur(blobs, 0.7))[..., None]
    albedo = soil * (1 - straw_a[..., None]) + straw_rgb  # the anti-aliased straw colour is premultiplied
    albedo = np.clip(albedo, 0.005, 0.9).astype(np.float32)

    gravel = skdata.gravel().astype(np.float32) / 255.0
    gravel = cv2.resize(gravel, (512, 512), interpolation=cv2.INTER_AREA)
    # make the photo tileable: blend with its half-period shift using a smooth window
    w = np.sin(np.linspace(0, np.pi, 512, endpoint=False)) ** 2
    win = np.outer(w, w).astype(np.float32)
    shifted = np.roll(np.roll(gravel, 256, 0), 256, 1)
    grain = gravel * win + shifted * (1 - win)
    grain = grain - periodic_blur(grain, 12.0)
    grain = (1.0 + 0.9 * grain / (grain.std() + 1e-6) * 0.12).astype(np.float32)

    large = fbm(rng, 256, ((3.0, 0.6), (10.0, 0.8), (30.0, 0.6)))
    large = (1.0 + 0.12 * large).astype(np.float32)
    surface = np.concatenate([albedo, relief], axis=-1).astype(np.float32)
    return SoilTextures(MipTexture.from_image(surface, SOIL_TEXEL_M), MipTexture.from_image(grain, 0.0015),
                        MipTexture.from_image(large, 0.25))


def make_foliage(seed: int, size: int = 512, texel_m: float = 0.01) -> MipTexture:
    """Far-canopy appearance: overlapping leaf-sized ellipses of varied greens over dark gaps (RGB albedo)."""
    rng = np.random.default_rng([seed, 102])
    gap = srgb_to_linear((38, 48, 28))
    img = np.empty((size, size, 3), np.float32)
    img[:] = gap
    n_leaves = size * size // 60
    greens = np.array([srgb_to_linear(c) for c in ((72, 112, 46), (86, 128, 52), (60, 98, 40), (98, 132, 60),
                                                   (110, 140, 70))])
    centres = rng.uniform(0, size, (n_leaves, 2))
    axes = rng.uniform(2.0, 6.0, (n_leaves, 1)) * np.array([[1.0, 0.6]])
    angles = rng.uniform(0, 180, n_leaves)
    cols = greens[rng.integers(0, len(greens), n_leaves)] * rng.uniform(0.75, 1.2, (n_leaves, 1))
    for c, ax, a, col in zip(centres, axes, angles, cols):
        for sx in (0, size, -size):
            for sy in (0, size, -size):
                x, y = c[0] + sx, c[1] + sy
                if -8 <= x < size + 8 and -8 <= y < size + 8:
                    cv2.ellipse(img, (int(x), int(y)), (int(ax[0]), max(1, int(ax[1]))), float(a), 0, 360,
                                tuple(float(v) for v in col), -1, cv2.LINE_AA)
    img *= (1.0 + 0.08 * fbm(rng, size, ((1.0, 1.0),)))[..., None]
    return MipTexture.from_image(np.clip(img, 0.005, 0.9), texel_m)


def make_trees(seed: int) -> MipTexture:
    """Tree-line foliage (RGB albedo), 0.2 m texels, period 51 m along the line and 51 m up."""
    rng = np.random.default_rng([seed, 103])
    n = fbm(rng, 256, ((1.0, 0.5), (3.0, 0.7), (8.0, 0.5)))
    dark = srgb_to_linear((34, 46, 30))
    light = srgb_to_linear((78, 92, 58))
    t = np.clip(0.45 + 0.22 * n, 0, 1)[..., None]
    return MipTexture.from_image((dark * (1 - t) + light * t).astype(np.float32), 0.2)


def make_clouds(seed: int) -> MipTexture:
    """Cloud-layer density field (zero mean, unit std), 8 m texels, period 4 km."""
    rng = np.random.default_rng([seed, 104])
    return MipTexture.from_image(fbm(rng, 512, ((2.0, 0.35), (6.0, 0.6), (18.0, 0.8), (50.0, 0.5))), 8.0)
