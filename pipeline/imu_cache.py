"""A bag's IMU samples, read once and kept in the cache for every run of the sequence.

Each VIO run needs all IMU samples of its bag, and reading them scans the whole bag: the IMU messages share the
bag's chunks with the stereo images, so every chunk is read (≈ 2 s per run for a 120 s simulated bag, ≈ 7 s at
450 s, measured). The samples — after the repeated-stamp policy, exactly what
:meth:`pipeline.bag_reader.RosarioSequence.imu_samples` returns — are stored once per (bag identity, policy) as
``<cache>/imu/<identity>-<policy>-v<version>.npz`` (written atomically) and read back by later runs: the same
arrays, so the same results. The key is the bag's content identity, as for the depth caches
(:meth:`~pipeline.bag_reader.RosarioSequence.identity`); an unreadable file is said and read from the bag again.
"""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_path

#: Bump when the IMU reading or the stamp policy changes what ``imu_samples`` returns.
IMU_CACHE_VERSION = 1

__all__ = ["IMU_CACHE_VERSION", "cached_imu_samples", "imu_cache_path"]


def imu_cache_path(seq, cache_root: Path | str) -> Path:
    """Where the IMU samples of ``seq`` (a :class:`pipeline.bag_reader.RosarioSequence`) are kept."""
    return Path(cache_root) / "imu" / f"{seq.identity()}-{seq.imu_stamps}-v{IMU_CACHE_VERSION}.npz"


def _read(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    try:
        with np.load(path) as z:
            stamps, data = z["stamp_ns"], z["data"]
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        print(f"warning: {path}: unreadable IMU cache ({type(exc).__name__}: {exc}); read from the bag again",
              file=sys.stderr)
        return None
    if stamps.dtype != np.int64 or data.dtype != np.float64 or data.shape != (len(stamps), 6):
        print(f"warning: {path}: IMU cache of the wrong shape; read from the bag again", file=sys.stderr)
        return None
    return stamps, data


def cached_imu_samples(seq, cache_root: Path | str) -> tuple[np.ndarray, np.ndarray]:
    """``seq.imu_samples()`` — (N,) int64 stamps in ns and (N, 6) float64 ``[gx, gy, gz, ax, ay, az]`` (rad/s,
    m/s², IMU frame) — from the cache when stored there, else read from the bag and stored."""
    path = imu_cache_path(seq, cache_root)
    cached = _read(path)
    if cached is not None:
        return cached
    stamps, data = seq.imu_samples()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, stamp_ns=stamps, data=data)
    return stamps, data
