"""Frame rendering in worker processes (or inline), with results in frame order.

A frame is a pure function of (world seed and config, IMU pose, time, exposure, frame index), and the world's
caches are deterministic, so the images do not depend on how many workers render them. Workers are started with
``spawn`` (no fork after OpenCV's thread pool exists); each builds its own renderer (a few seconds).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from msckf.camera import StereoRig
from pipeline.process_pool import spawn_pool
from pipeline.sim.config import SimConfig
from pipeline.sim.export import encode_depth_frame
from pipeline.sim.render import FieldRenderer, StereoRender

NOISE_BANK = 1 << 20


@dataclass
class EncodedFrame:
    """What the sequence writer needs of a rendered frame: the raw BGR images (376, 672, 3) uint8, the left
    image's mean level before noise (auto-exposure input), the sun irradiance, and the ground truth already
    PNG-encoded (``export.encode_depth_frame``; encoding in the worker keeps the result small to send)."""

    left_bgr: np.ndarray
    right_bgr: np.ndarray
    mean_level: float
    sun: float
    depth_blobs: tuple


@dataclass(frozen=True)
class FrameJob:
    """What one frame needs: index, time since start (s), T_F_imu (4, 4), exposure."""

    index: int
    t_s: float
    T_F_imu: np.ndarray
    exposure: float


class FrameRenderer:
    """The per-process renderer plus the sensor-noise bank (deterministic in ``seed``)."""

    def __init__(self, rig: StereoRig, cfg: SimConfig, world_seed: int, seed: int, threads: int = 1) -> None:
        self.renderer = FieldRenderer(rig, cfg.field, cfg.lighting, cfg.camera, cfg.render, world_seed,
                                      threads=threads)
        self.seed = seed
        self.shape = (rig.left.height, rig.left.width, 3)
        n = int(np.prod(self.shape))
        self.bank = np.random.default_rng([seed, 901]).standard_normal(NOISE_BANK + n, dtype=np.float32)
        self.right_depth = False

    def noise(self, frame: int, cam: int) -> np.ndarray:
        off = int(np.random.default_rng([self.seed, 900, frame, cam]).integers(0, NOISE_BANK))
        return self.bank[off:off + int(np.prod(self.shape))].reshape(self.shape)

    def sun(self, T_F_imu: np.ndarray, t_s: float) -> float:
        return self.renderer.sky.sun_irradiance(np.asarray(T_F_imu)[:3, 3], t_s)

    def render(self, job: FrameJob) -> tuple[StereoRender, float]:
        sun = self.sun(job.T_F_imu, job.t_s)
        fr = self.renderer.render_frame(job.T_F_imu, job.t_s, job.exposure, sun, self.noise(job.index, 0),
                                        self.noise(job.index, 1), right_depth=self.right_depth)
        return fr, sun

    def render_encoded(self, job: FrameJob) -> EncodedFrame:
        fr, sun = self.render(job)
        return EncodedFrame(fr.left_bgr, fr.right_bgr, fr.mean_level, sun,
                            encode_depth_frame(fr.depth, fr.label, fr.glare, fr.right_depth, fr.right_label))


_WORKER: FrameRenderer | None = None


def _init(rig: StereoRig, cfg: SimConfig, world_seed: int, seed: int, right_depth: bool) -> None:
    global _WORKER
    _WORKER = FrameRenderer(rig, cfg, world_seed, seed, threads=1)
    _WORKER.right_depth = right_depth


def _work(job: FrameJob) -> EncodedFrame:
    assert _WORKER is not None
    return _WORKER.render_encoded(job)


class RenderService:
    """Submit frames in order, get results in order; ``workers <= 1`` renders inline (same results).

    Args:
        rig, cfg, world_seed, seed: what the renderer needs.
        workers: worker processes.
        right_depth: also trace the rectified right depth.
    """

    def __init__(self, rig: StereoRig, cfg: SimConfig, world_seed: int, seed: int, workers: int = 1,
                 right_depth: bool = False) -> None:
        self.workers = max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None
        self._inline: FrameRenderer | None = None
        if self.workers > 1:
            self._pool = spawn_pool(self.workers, initializer=_init,
                                    initargs=(rig, cfg, world_seed, seed, right_depth))
        else:
            self._inline = FrameRenderer(rig, cfg, world_seed, seed, threads=1)
            self._inline.right_depth = right_depth
        self._pending: deque[tuple[int, Future | EncodedFrame]] = deque()

    def render_now(self, job: FrameJob) -> EncodedFrame:
        """Render one frame synchronously (used for the auto-exposure start)."""
        if self._pool is not None:
            return self._pool.submit(_work, job).result()
        assert self._inline is not None
        return self._inline.render_encoded(job)

    def submit(self, job: FrameJob) -> None:
        if self._pool is not None:
            self._pending.append((job.index, self._pool.submit(_work, job)))
        else:
            assert self._inline is not None
            self._pending.append((job.index, self._inline.render_encoded(job)))

    def in_flight(self) -> int:
        return len(self._pending)

    def next_result(self) -> tuple[int, EncodedFrame]:
        """The oldest submitted frame's result (blocks)."""
        index, item = self._pending.popleft()
        return index, item.result() if isinstance(item, Future) else item

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
