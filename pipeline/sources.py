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


def _sim_meta(folder: Path) -> dict[str, Any] | None:
    """The simulator's ``meta.json`` of ``folder`` (None when it is not a finished simulated sequence)."""
    import json

    try:
        meta = json.loads((folder / "meta.json").read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) and "simulator_version" in meta and "files" in meta else None


def _simulated_folder(folder: Path, gt: str | None, camchain: str | None, source: str) -> ResolvedSource:
    """A folder written by ``agrivio simulate --out``: its bag, GT and camchain are found inside."""
    from pipeline.sim.sequence import SimulatedSequence

    if _sim_meta(folder) is None:
        raise AgrivioError(f"{folder}: a folder, but not one written by `agrivio simulate` (no valid meta.json); "
                           f"give a bag file or a simulator preset")
    if gt or camchain:
        raise AgrivioError(f"{folder}: --gt/--camchain apply to bags; a simulated folder brings its own")
    sim = SimulatedSequence(folder)
    for path in (sim.bag_path, sim.gt_path, sim.camchain_path):
        if not path.is_file():
            raise AgrivioError(f"{path}: missing from the simulated folder")
    return ResolvedSource(source, sim.name, sim.bag_path, sim.gt_path, sim.camchain_path, simulated=True,
                          sim_dir=folder)


def check_source(source: str) -> None:
    """Raise :class:`AgrivioError` naming ``source`` when it is neither a folder, a bag file (or the stem of
    byte-split parts) nor a simulator preset; reads and simulates nothing (for checks before any work starts)."""
    if not Path(source).expanduser().is_dir() and _bag_path(source) is None:
        _require_preset(source)


def _require_preset(source: str) -> None:
    """Raise :class:`AgrivioError` unless ``source`` names a simulator preset (the last thing a source can be)."""
    from pipeline.sim.presets import PRESETS

    if source not in PRESETS:
        raise AgrivioError(f"{source}: neither a bag file (nor byte-split parts {source}.00, …) nor a simulator "
                           f"preset ({', '.join(sorted(PRESETS))})")


def resolve_source(source: str, gt: str | None = None, camchain: str | None = None, duration_s: float | None = None,
                   seed: int = 0, cache_root: Path | None = None, progress: bool = True) -> ResolvedSource:
    """A bag path (with ``gt``/``camchain`` files), a folder written by ``agrivio simulate --out``, or a simulator
    preset name (simulated into ``cache_root``)."""
    folder = Path(source).expanduser()
    if folder.is_dir():
        return _simulated_folder(folder, gt, camchain, source)
    bag = _bag_path(source)
    if bag is not None:
        gt_path = Path(gt).expanduser() if gt else None
        if gt_path is not None and not gt_path.is_file():
            raise AgrivioError(f"{gt_path}: ground-truth file not found")
        cam = Path(camchain).expanduser() if camchain else None
        if cam is not None and not cam.is_file():
            raise AgrivioError(f"{cam}: camchain file not found")
        name = bag.name.split(".bag")[0] if ".bag" in bag.name else bag.stem
        # a bag that `agrivio simulate` wrote is simulated, whichever way it is named
        simulated = _sim_meta(bag.parent) is not None and _sim_meta(bag.parent).get("files", {}).get("bag") == bag.name
        return ResolvedSource(source, name, bag, gt_path, cam, simulated=simulated,
                              sim_dir=bag.parent if simulated else None)
    _require_preset(source)
    if gt or camchain:
        raise AgrivioError(f"{source}: --gt/--camchain apply to bags; a simulated sequence brings its own")
    from pipeline.sim_source import simulate_cached

    return simulate_cached(source, seed=seed, duration_s=duration_s, cache_root=cache_root, progress=progress)
