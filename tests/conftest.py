"""Shared pytest fixtures: the Rosario rig and a small synthetic Rosario-layout bag (written once per session)."""

from __future__ import annotations

import os

# Small dense algebra dominates the VIO tests; threaded OpenBLAS only adds contention on a 2-core machine.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

import pytest

from msckf.camera import StereoRig
from pipeline.calibration import rig_from_camchain
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.synthetic_scene import SyntheticBagTruth, write_synthetic_bag

SMALL_BAG_FRAMES = 6


@pytest.fixture(scope="session")
def rosario_rig() -> StereoRig:
    """The published Rosario stereo rig (shipped camchain, rectified with alpha=0)."""
    return rig_from_camchain(ROSARIO_CAMCHAIN)


@pytest.fixture(scope="session")
def small_bag(tmp_path_factory: pytest.TempPathFactory, rosario_rig: StereoRig) -> tuple[Path, SyntheticBagTruth]:
    """A 6-frame uncompressed Rosario-layout bag (stereo, camera_info, IMU, GPS, odom, tf_static) + its truth."""
    path = tmp_path_factory.mktemp("bags") / "small.bag"
    truth = write_synthetic_bag(path, n_frames=SMALL_BAG_FRAMES, rig=rosario_rig, seed=3)
    return path, truth


@pytest.fixture(scope="session")
def sim_cache(tmp_path_factory) -> Path:
    """A cache folder shared by the end-to-end tests: the ``tiny`` preset is simulated into it once."""
    return tmp_path_factory.mktemp("agrivio-cache")
