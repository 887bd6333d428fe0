"""Read a simulated sequence back from its output folder (layout: see :mod:`pipeline.sim.sequence`)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from msckf.camera import StereoRig
from pipeline.calibration import rig_from_camchain
from pipeline.errors import AgrivioError
from pipeline.sim.config import SimConfig
from pipeline.sim.export import DepthChunkReader


@dataclass
class SimulatedSequence:
    """A simulated sequence on disk (see the module docstring for the layout)."""

    root: Path

    @cached_property
    def meta(self) -> dict[str, Any]:
        path = self.root / "meta.json"
        if not path.is_file():
            raise AgrivioError(f"{self.root}: not a finished simulated sequence (no meta.json)")
        return json.loads(path.read_text())

    @property
    def name(self) -> str:
        return str(self.meta["files"]["bag"]).removesuffix(".bag")

    @property
    def bag_path(self) -> Path:
        return self.root / self.meta["files"]["bag"]

    @property
    def camchain_path(self) -> Path:
        return self.root / self.meta["files"]["camchain"]

    @property
    def gt_path(self) -> Path:
        """TUM antenna ground truth, like the real ``sequence0X_gt.txt``."""
        return self.root / self.meta["files"]["gt"]

    @property
    def gt_antenna_true_path(self) -> Path:
        return self.root / self.meta["files"]["gt_antenna_true"]

    @property
    def body_gt_path(self) -> Path:
        return self.root / self.meta["files"]["gt_body"]

    @property
    def euroc_path(self) -> Path | None:
        p = self.meta["files"].get("euroc")
        return None if p is None else self.root / p

    @property
    def n_frames(self) -> int:
        return int(self.meta["counts"]["frames"])

    @property
    def config(self) -> SimConfig:
        return SimConfig.from_dict(self.meta["config"])

    def rig(self) -> StereoRig:
        """The stereo rig the images were rendered with (from the written camchain)."""
        return rig_from_camchain(self.camchain_path)

    @cached_property
    def _depth(self) -> DepthChunkReader:
        return DepthChunkReader(self.root / "depth")

    def depth(self, index: int) -> np.ndarray:
        """Exact depth of left frame ``index``: (376, 672) float32 Z in the rectified left camera, metres; NaN where
        there is none (sky, or farther than 65.5 m)."""
        return self._depth.get(index, "depth")

    def labels(self, index: int) -> np.ndarray:
        """(376, 672) uint8 surface labels of the rectified left frame (``render.LABEL_*``)."""
        return self._depth.get(index, "label")

    def glare(self, index: int) -> np.ndarray:
        """(376, 672) float32 sun-glare sensor level of the rectified left frame (0 = none, 1 = full scale)."""
        return self._depth.get(index, "glare").astype(np.float32) / 255.0

    def right_depth(self, index: int) -> np.ndarray:
        """Rectified right depth (only if simulated with ``right_depth=True``)."""
        return self._depth.get(index, "rdepth")

    def iter_depth(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, int, np.ndarray]]:
        """``(index, stamp_ns, depth)`` for frames ``start .. stop``."""
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for i in range(start, stop):
            yield i, self._depth.stamp_ns(i), self.depth(i)

    @cached_property
    def truth(self) -> dict[str, np.ndarray]:
        """Arrays of ``truth.npz`` (see :func:`simulate_sequence`)."""
        with np.load(self.root / self.meta["files"]["truth"]) as z:
            return {k: z[k] for k in z.files}

    def body_trajectory(self):
        """6-DoF IMU-frame ground truth (``eval.trajectory.Trajectory``, ENU, stamps in seconds)."""
        from eval.trajectory import read_tum

        return read_tum(self.body_gt_path)

    def antenna_ground_truth(self):
        """The Rosario-style antenna ground truth (``eval.trajectory.Trajectory``, identity orientations)."""
        from eval.trajectory import read_tum

        return read_tum(self.gt_path)
