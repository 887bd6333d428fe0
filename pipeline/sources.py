"""Resolve what the user names as a sequence: a Rosario bag (plain, compressed or byte-split) or a simulator preset.

A preset is simulated once into the cache (keyed by preset, seed and duration) and then read exactly like a real
bag; the simulator's extras (exact depth, 6-DoF ground truth, the true antenna lever arm) come along.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.errors import AgrivioError


@dataclass(frozen=True)
class ResolvedSource:
    """A sequence ready to read.

    Attributes:
        source: what the user gave (bag path or preset name).
        name: sequence name for reports (bag stem or preset name).
        bag: the bag path (or the first byte-split part).
        gt: TUM ground truth (GPS antenna positions), or None.
        camchain: Kalibr camchain YAML, or None (the shipped Rosario one).
        simulated: True for a simulator preset.
        lever_arms: ``lever_arm_imu`` / ``lever_arm_base`` / ``R_base_imu`` when known exactly (simulator), else
            None (they are read from the bag's ``tf_static``).
        sim_dir: the simulator's output folder (exact depth etc.), or None.
    """

    source: str
    name: str
    bag: Path
    gt: Path | None
    camchain: Path | None
    simulated: bool
    lever_arms: dict[str, Any] | None = None
    sim_dir: Path | None = None


def _bag_path(source: str) -> Path | None:
    path = Path(source).expanduser()
    if path.is_file():
        return path
    first_part = path.with_name(path.name + ".00")
    if first_part.is_file():
        return path  # byte-split parts: the reader takes the stem and chains the parts
    return None


def resolve_source(source: str, gt: str | None = None, camchain: str | None = None, duration_s: float | None = None,
                   seed: int = 0, cache_root: Path | None = None, progress: bool = True) -> ResolvedSource:
    """A bag path (with ``gt``/``camchain`` files) or a simulator preset name (simulated into ``cache_root``)."""
    bag = _bag_path(source)
    if bag is not None:
        gt_path = Path(gt).expanduser() if gt else None
        if gt_path is not None and not gt_path.is_file():
            raise AgrivioError(f"{gt_path}: ground-truth file not found")
        cam = Path(camchain).expanduser() if camchain else None
        if cam is not None and not cam.is_file():
            raise AgrivioError(f"{cam}: camchain file not found")
        name = bag.name.split(".bag")[0] if ".bag" in bag.name else bag.stem
        return ResolvedSource(source, name, bag, gt_path, cam, simulated=False)
    from pipeline.sim.presets import PRESETS

    if source not in PRESETS:
        raise AgrivioError(f"{source}: neither a bag file (nor byte-split parts {source}.00, …) nor a simulator "
                           f"preset ({', '.join(sorted(PRESETS))})")
    if gt or camchain:
        raise AgrivioError(f"{source}: --gt/--camchain apply to bags; a simulated sequence brings its own")
    from pipeline.sim_source import simulate_cached

    return simulate_cached(source, seed=seed, duration_s=duration_s, cache_root=cache_root, progress=progress)
