"""The sim-realism stage: simulate (or reuse) a preset and measure how realistic its stereo depth is.

:func:`realism_sequence` finds or simulates the preset's sequence (with the right camera's exact depth, so
occlusion holes are told apart); :func:`measure_realism` runs the depth stage on every ``stride``-th frame against
the exact depth (hole ratio and causes, depth error, FAST corners), tracks KLT over consecutive moving frames and
writes the preset's gallery PNG. The ``agrivio sim-realism`` command only parses its arguments, writes the report
files and prints. The measurements themselves are in :mod:`pipeline.sim.realism`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from pipeline.atomic import atomic_path
from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthParams, to_grey
from pipeline.errors import AgrivioError
from pipeline.paths import cache_dir
from pipeline.rosario_layout import RATE_CAMERA_HZ
from pipeline.sim.presets import get_preset
from pipeline.sim.realism import SequenceRealism, analyse_frame, gallery_png, klt_track_lengths
from pipeline.sim.sequence import SIM_VERSION, SimulatedSequence, resolve_config, simulate_sequence


@dataclass(frozen=True)
class RealismResult:
    """One preset's measurements: ``summary`` (:meth:`SequenceRealism.summary` plus the sequence folder and where
    occlusion came from) and ``per_frame`` (index, hole ratio, FAST corners of the analysed frames)."""

    summary: dict[str, Any]
    per_frame: dict[str, list]


def realism_sequence(preset: str, seed: int, duration_s: float, workers: int, resimulate: bool = False,
                     progress: bool = True) -> SimulatedSequence:
    """The preset's sequence under ``<cache>/sim/<preset>-s<seed>-<duration>s-realism``: reused when one of this
    simulator version, configuration and seed is there (and not ``resimulate``), else simulated with
    ``workers`` render processes."""
    try:
        cfg = resolve_config(get_preset(preset), duration_s)
    except KeyError as exc:
        raise AgrivioError(str(exc.args[0])) from None
    root = cache_dir() / "sim" / f"{preset}-s{seed}-{cfg.duration_s:g}s-realism"
    if not resimulate and (root / "meta.json").is_file():
        seq = SimulatedSequence(root)
        if seq.meta.get("config") == json.loads(json.dumps(cfg.to_dict())) and seq.meta["seed"] == seed \
                and seq.meta.get("simulator_version") == SIM_VERSION:
            return seq
    return simulate_sequence(cfg, root, seed=seed, right_depth=True, progress=progress, workers=workers)


def measure_realism(preset: str, seq: SimulatedSequence, params: DepthParams, stride: int, klt_frames: int,
                    gallery_dir: Path, progress: bool = True) -> RealismResult:
    """Measure ``seq`` (see the module docstring); writes ``gallery_<preset>.png`` into ``gallery_dir``.

    Args:
        stride: analyse every ``stride``-th frame (≥ 1). klt_frames: consecutive moving frames tracked (≥ 0),
            starting half a second after the route's standstill.
    """
    rig = seq.rig()
    first_moving = int(np.ceil((seq.config.route.still_s + 0.5) * RATE_CAMERA_HZ))
    n = seq.n_frames
    gallery_index = min(n - 1, max(first_moving, int(0.6 * n)))
    rep = SequenceRealism(preset)
    klt: list[np.ndarray] = []
    right = "rdepth" in seq.meta.get("depth", {}).get("stored", ["rdepth"])
    bar = tqdm(total=n, desc=f"realism {preset}", unit="frame", disable=not progress)
    with RosarioSequence(seq.bag_path, camchain=seq.camchain_path) as bag:
        for f in bag.stereo_frames():
            i = f.index
            if first_moving <= i < first_moving + klt_frames:
                klt.append(to_grey(f.left_bgr))
            if i % stride == 0 or i == gallery_index:
                try:
                    rd = seq.right_depth(i) if right else None
                except KeyError:
                    rd, right = None, False
                fr, d, causes = analyse_frame(i, rig, f.left_bgr, f.right_bgr, seq.depth(i), seq.labels(i),
                                              seq.glare(i), params, rd)
                if i % stride == 0:
                    rep.frames.append(fr)
                if i == gallery_index:
                    png = gallery_png(f.left_bgr, f.right_bgr, seq.depth(i), d.depth_m, causes,
                                      f"{preset} frame {i} (holes {100 * fr.hole_ratio:.1f} %)")
                    with atomic_path(gallery_dir / f"gallery_{preset}.png", suffix=".png") as tmp:
                        tmp.write_bytes(png)
            bar.update()
    bar.close()
    rep.klt = klt_track_lengths(klt)
    summary = rep.summary()
    summary["sequence"] = str(seq.root)
    summary["occlusion_from"] = "right exact depth" if right else "disparity jumps"
    per_frame = {"index": [f.index for f in rep.frames], "hole_ratio": [f.hole_ratio for f in rep.frames],
                 "fast_corners": [f.fast_corners for f in rep.frames]}
    return RealismResult(summary, per_frame)


__all__ = ["RealismResult", "measure_realism", "realism_sequence"]
