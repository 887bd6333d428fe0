"""Where generated data goes: a git-ignored cache folder, overridable with ``AGRIVIO_CACHE``."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
ROSARIO_CAMCHAIN = DATA_DIR / "rosario_camchain.yaml"


def cache_dir() -> Path:
    """Root of generated data (simulated bags, depth caches, runs, reports); created on demand."""
    root = Path(os.environ.get("AGRIVIO_CACHE", DATA_DIR / "cache")).expanduser()
    root.mkdir(parents=True, exist_ok=True)
    return root
