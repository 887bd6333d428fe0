"""Procedural noise, periodic image helpers and mip-mapped texture sampling (numpy/OpenCV; sampling kernel in
:mod:`pipeline.sim.texture_kernels`).

All textures here tile: their left/right and top/bottom edges continue each other, so a texture addressed with
world coordinates modulo its period shows no seams.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.sim.texture_kernels import level_sample, mip_sample, pack_levels


def periodic_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur with wrap-around borders (keeps a texture tileable). ``img``: (H, W[, C]) float32."""
    if sigma <= 0:
        return img
    if sigma > 6:  # large kernels: exact periodic Gaussian in the frequency domain
        h, w = img.shape[:2]
        fy = np.fft.fftfreq(h)[:, None]
        fx = np.fft.rfftfreq(w)[None, :]
        g = np.exp(-2 * (np.pi * sigma) ** 2 * (fx * fx + fy * fy))
        if img.ndim == 3:
            g = g[..., None]
        out = np.fft.irfft2(np.fft.rfft2(img, axes=(0, 1)) * g, s=(h, w), axes=(0, 1))
        return np.ascontiguousarray(out, dtype=np.float32)
    pad = int(np.ceil(4 * sigma)) + 1
    widths = ((pad, pad), (pad, pad)) + ((0, 0),) * (img.ndim - 2)
    out = cv2.GaussianBlur(np.pad(img, widths, mode="wrap"), (0, 0), sigma)
    return np.ascontiguousarray(out[pad:-pad, pad:-pad])


def fbm(rng: np.random.Generator, size: int | tuple[int, int], octaves: tuple[tuple[float, float], ...],
        channels: int = 1) -> np.ndarray:
    """Tileable multi-octave noise, normalised to zero mean and unit standard deviation.

    Args:
        rng: random generator (consumed deterministically).
        size: side (square) or ``(height, width)`` in texels.
        octaves: ``(blur_sigma_texels, weight)`` pairs; each octave is white noise blurred periodically and
            normalised before weighting.
        channels: 1 gives (H, W); more gives (H, W, C) with independent channels.
    Returns:
        float32 noise.
    """
    h, w = (size, size) if isinstance(size, int) else size
    acc = np.zeros((h, w, channels), np.float32)
    for sigma, weight in octaves:
        n = rng.standard_normal((h, w, channels)).astype(np.float32)
        if sigma > 0:
            n = periodic_blur(n, sigma).reshape(h, w, channels)
        n -= n.mean(axis=(0, 1), keepdims=True)
        n /= n.std(axis=(0, 1), keepdims=True) + 1e-9
        acc += np.float32(weight) * n
    acc -= acc.mean(axis=(0, 1), keepdims=True)
    acc /= acc.std(axis=(0, 1), keepdims=True) + 1e-9
    return acc[..., 0] if channels == 1 else acc


def smooth_noise_1d(rng: np.random.Generator, n: int, sigma: float, periodic: bool = True) -> np.ndarray:
    """(n,) float64 Gaussian-smoothed white noise with unit standard deviation (periodic by default)."""
    x = rng.standard_normal(n)
    if sigma > 0:
        k = np.arange(-int(4 * sigma) - 1, int(4 * sigma) + 2)
        g = np.exp(-0.5 * (k / sigma) ** 2)
        g /= g.sum()
        if periodic:
            x = np.real(np.fft.ifft(np.fft.fft(x) * np.fft.fft(np.roll(np.pad(g, (0, max(0, n - g.size))),
                                                                        -(g.size // 2))[:n])))
        else:
            x = np.convolve(x, g, mode="same")
    return (x - x.mean()) / (x.std() + 1e-12)


def periodic_pyramid(img: np.ndarray, min_size: int = 4) -> list[np.ndarray]:
    """Mip pyramid of a tileable texture (each level halves both sides; the image sides must be powers of two)."""
    levels = [img.astype(np.float32)]
    while min(levels[-1].shape[:2]) > min_size:
        prev = levels[-1]
        blurred = periodic_blur(prev, 0.6)
        h, w = prev.shape[:2]
        half = blurred.reshape((h // 2, 2, w // 2, 2) + prev.shape[2:]).mean(axis=(1, 3))
        levels.append(np.ascontiguousarray(half, dtype=np.float32))
    return levels


@dataclass
class MipTexture:
    """A tileable texture addressed in metres, sampled with trilinear mip-mapping (compiled kernel).

    Attributes:
        levels: mip pyramid, level 0 full resolution (H, W[, C]) float32.
        texel_m: size of a level-0 texel, metres.
    """

    levels: list[np.ndarray]
    texel_m: float

    def __post_init__(self) -> None:
        self._flat, self._info, self._scale = pack_levels(self.levels)
        self._channels = int(np.prod(self.levels[0].shape[2:], dtype=np.int64))

    @classmethod
    def from_image(cls, img: np.ndarray, texel_m: float) -> MipTexture:
        return cls(periodic_pyramid(img), texel_m)

    @property
    def period_m(self) -> tuple[float, float]:
        """(x period, y period) in metres."""
        h, w = self.levels[0].shape[:2]
        return w * self.texel_m, h * self.texel_m

    def sample_lod(self, x_m: np.ndarray, y_m: np.ndarray, lod: np.ndarray | float,
                   valid: np.ndarray | None = None, max_level: int | None = None, beyond: float = 1.0
                   ) -> np.ndarray:
        """Trilinear samples at surface points for a given level of detail.

        Args:
            x_m, y_m: surface coordinates in metres, any same shape S (x → texture columns, y → rows).
            lod: (S) or scalar log2(footprint / level-0 texel); fractional levels blend two mip levels.
            valid: (S) bool points that need a value (others are zero); None = all.
            max_level: points needing this level or coarser get the constant ``beyond`` (a detail texture that
                has averaged out to its mean there).
        Returns:
            (S) or (S + (C,)) float32.
        """
        shape = np.shape(x_m)
        x = np.ascontiguousarray(x_m, np.float64).reshape(-1)
        y = np.ascontiguousarray(y_m, np.float64).reshape(-1)
        if valid is None and np.ndim(lod) == 0 and float(lod) == int(lod) and 0 <= int(lod) < len(self.levels) \
                and (max_level is None or int(lod) < max_level):  # one whole level: plain bilinear
            out = np.empty((x.size, self._channels), np.float32)
            level_sample(self._flat, self._info, self._scale, int(lod), x, y, 1.0 / self.texel_m, out)
            return out.reshape(shape + self.levels[0].shape[2:])
        lv = np.ascontiguousarray(np.broadcast_to(np.asarray(lod, np.float32), shape)).reshape(-1)
        ok = np.ones(x.size, bool) if valid is None else np.ascontiguousarray(valid, bool).reshape(-1)
        out = np.zeros((x.size, self._channels), np.float32)
        mip_sample(self._flat, self._info, self._scale, x, y, lv, ok, 1.0 / self.texel_m,
                   len(self.levels) if max_level is None else int(max_level), float(beyond), out)
        return out.reshape(shape + self.levels[0].shape[2:])

    def sample(self, x_m: np.ndarray, y_m: np.ndarray, footprint_m: np.ndarray | float) -> np.ndarray:
        """Sample at world coordinates with a per-point footprint (the size of a pixel on the surface).

        Args:
            x_m, y_m: (N,) surface coordinates in metres (x → texture columns, y → rows).
            footprint_m: (N,) or scalar pixel footprint in metres; selects the mip level.
        Returns:
            (N,) or (N, C) float32.
        """
        fp = np.maximum(np.asarray(footprint_m, np.float64) / self.texel_m, 1e-6)
        return self.sample_lod(x_m, y_m, np.log2(fp))


def sample_level(tex: MipTexture, x_m: np.ndarray, y_m: np.ndarray, level: int) -> np.ndarray:
    """Bilinear sampling of one mip level at surface coordinates (metres): 1-D arrays or 2-D images."""
    lvl = int(np.clip(level, 0, len(tex.levels) - 1))
    return tex.sample_lod(x_m, y_m, float(lvl))
