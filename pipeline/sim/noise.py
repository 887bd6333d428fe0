"""Procedural noise, periodic image helpers and mip-mapped texture sampling (vectorised with numpy/OpenCV).

All textures here tile: their left/right and top/bottom edges continue each other, so a texture addressed with
world coordinates modulo its period shows no seams.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


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


def remap_points(img: np.ndarray, u: np.ndarray, v: np.ndarray, wrap: bool = True,
                 interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Bilinear lookup of ``img`` at arbitrary texel coordinates.

    Args:
        img: (H, W) or (H, W, C) float32 image.
        u, v: (N,) column and row coordinates in texels (texel centres at integers).
        wrap: wrap around the borders (tiling); otherwise clamp to the border.
    Returns:
        (N,) or (N, C) float32 samples.
    """
    n = u.size
    if n == 0:
        return np.zeros((0,) + img.shape[2:], np.float32)
    width = 1024
    rows = -(-n // width)
    pad = rows * width - n
    U = np.pad(u.astype(np.float32, copy=False).ravel(), (0, pad)).reshape(rows, width)
    V = np.pad(v.astype(np.float32, copy=False).ravel(), (0, pad)).reshape(rows, width)
    out = cv2.remap(img, U, V, interpolation, borderMode=cv2.BORDER_WRAP if wrap else cv2.BORDER_REPLICATE)
    return out.reshape((rows * width,) + img.shape[2:])[:n]


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
    """A tileable texture addressed in metres, sampled with trilinear mip-mapping.

    Attributes:
        levels: mip pyramid, level 0 full resolution (H, W[, C]) float32.
        texel_m: size of a level-0 texel, metres.
    """

    levels: list[np.ndarray]
    texel_m: float

    @classmethod
    def from_image(cls, img: np.ndarray, texel_m: float) -> "MipTexture":
        return cls(periodic_pyramid(img), texel_m)

    @property
    def period_m(self) -> tuple[float, float]:
        """(x period, y period) in metres."""
        h, w = self.levels[0].shape[:2]
        return w * self.texel_m, h * self.texel_m

    def sample(self, x_m: np.ndarray, y_m: np.ndarray, footprint_m: np.ndarray | float) -> np.ndarray:
        """Sample at world coordinates with a per-point footprint (the size of a pixel on the surface).

        Args:
            x_m, y_m: (N,) surface coordinates in metres (x → texture columns, y → rows).
            footprint_m: (N,) or scalar pixel footprint in metres; selects the mip level.
        Returns:
            (N,) or (N, C) float32.
        """
        n = x_m.size
        h, w = self.levels[0].shape[:2]
        # wrap in float64 first so float32 keeps sub-texel precision far from the origin
        u = np.mod(np.asarray(x_m, np.float64) / self.texel_m, w)
        v = np.mod(np.asarray(y_m, np.float64) / self.texel_m, h)
        fp = np.broadcast_to(np.asarray(footprint_m, np.float64), (n,))
        lod = np.clip(np.log2(np.maximum(fp / self.texel_m, 1e-6)), 0.0, len(self.levels) - 1.0)
        base = np.minimum(np.floor(lod).astype(np.int32), len(self.levels) - 2) if len(self.levels) > 1 else \
            np.zeros(n, np.int32)
        frac = (lod - base).astype(np.float32)
        out = np.empty((n,) + self.levels[0].shape[2:], np.float32)
        for lvl in np.unique(base):
            idx = np.flatnonzero(base == lvl)
            s0 = 0.5 ** lvl  # texel i of level l covers [i, i+1) · texel_m · 2^l: its centre is at u·s − 0.5
            a = remap_points(self.levels[lvl], u[idx] * s0 - 0.5, v[idx] * s0 - 0.5)
            if lvl + 1 < len(self.levels):
                s1 = 0.5 ** (lvl + 1)
                b = remap_points(self.levels[lvl + 1], u[idx] * s1 - 0.5, v[idx] * s1 - 0.5)
                f = frac[idx] if a.ndim == 1 else frac[idx, None]
                a = a + (b - a) * f
            out[idx] = a
        return out


def sample_rows(tex: MipTexture, x_m: np.ndarray, y_m: np.ndarray, lod: np.ndarray, valid: np.ndarray,
                lod_offset: float = 0.0, max_level: int | None = None, beyond: float = 1.0) -> np.ndarray:
    """Trilinear mip sampling of a whole image of surface points, choosing the mip level per image row.

    The level of a row is the smallest (sharpest) level needed by its valid pixels; pixels whose own level is
    higher are blended towards the next level by their fractional excess. Rows of the same level are sampled
    with one ``cv2.remap`` call per level (no gathers), which is what makes ground texturing fast.

    Args:
        tex: the texture.
        x_m, y_m: (H, W) float32 surface coordinates in metres (anything where ``valid`` is False).
        lod: (H, W) float32 level of detail for a texel of ``tex.texel_m`` (log2 of footprint / texel).
        valid: (H, W) bool pixels that need a value.
        lod_offset: added to ``lod`` (for textures sharing a footprint but with another texel size).
        max_level: rows needing this level or coarser get the constant ``beyond`` (a detail texture that has
            averaged out to its mean there).
    Returns:
        (H, W[, C]) float32 samples (undefined where not valid).
    """
    h, w = x_m.shape
    nlev = len(tex.levels)
    lod = np.clip(lod + np.float32(lod_offset), 0.0, nlev - 1.0)
    row_lod = np.where(valid, lod, np.float32(1e9)).min(axis=1)
    row_lvl = np.clip(np.floor(np.where(row_lod > 1e8, 0, row_lod)), 0, max(nlev - 2, 0)).astype(np.int32)
    # few bands: a row never gets a coarser level than any row below it (distance grows up the image)
    row_lvl = np.minimum.accumulate(row_lvl[::-1])[::-1]
    th, tw = tex.levels[0].shape[:2]
    pu = tw * tex.texel_m
    pv = th * tex.texel_m
    u0 = (np.mod(x_m, np.float32(pu)) / np.float32(tex.texel_m)).astype(np.float32)
    v0 = (np.mod(y_m, np.float32(pv)) / np.float32(tex.texel_m)).astype(np.float32)
    out = np.zeros((h, w) + tex.levels[0].shape[2:], np.float32)
    rows_any = valid.any(axis=1)
    if max_level is not None:
        coarse = row_lvl >= max_level
        out[coarse] = beyond
        rows_any = rows_any & ~coarse
    start = 0
    while start < h:
        lvl = row_lvl[start]
        stop = start + 1
        while stop < h and row_lvl[stop] == lvl:
            stop += 1
        if rows_any[start:stop].any():
            sl = slice(start, stop)
            s0 = np.float32(0.5 ** lvl)
            a = cv2.remap(tex.levels[lvl], u0[sl] * s0 - 0.5, v0[sl] * s0 - 0.5, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_WRAP)
            if lvl + 1 < nlev:
                frac = np.clip(lod[sl] - lvl, 0.0, 1.0)
                if frac.max() > 0.02:
                    s1 = np.float32(0.5 ** (lvl + 1))
                    b = cv2.remap(tex.levels[lvl + 1], u0[sl] * s1 - 0.5, v0[sl] * s1 - 0.5, cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_WRAP)
                    if a.ndim == 3:
                        frac = frac[..., None]
                    a = a + (b - a) * frac
            out[sl] = a
        start = stop
    return out


def sample_level(tex: MipTexture, x_m: np.ndarray, y_m: np.ndarray, level: int) -> np.ndarray:
    """Bilinear sampling of one mip level at surface coordinates (metres): 1-D arrays or 2-D images."""
    lvl = int(np.clip(level, 0, len(tex.levels) - 1))
    th, tw = tex.levels[lvl].shape[:2]
    texel = tex.texel_m * 2 ** lvl
    u = (np.mod(x_m, np.float32(tw * texel)) / np.float32(texel) - 0.5).astype(np.float32)
    v = (np.mod(y_m, np.float32(th * texel)) / np.float32(texel) - 0.5).astype(np.float32)
    if u.ndim == 2 and max(u.shape) < 32000:
        return cv2.remap(tex.levels[lvl], u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return remap_points(tex.levels[lvl], u, v)
