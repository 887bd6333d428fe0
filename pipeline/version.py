"""The code version stamped into run records: ``git describe`` of the checkout, else the package version."""

from __future__ import annotations

import functools
import subprocess
from importlib import metadata

from pipeline.paths import REPO_ROOT


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--tags"], cwd=REPO_ROOT,
                             capture_output=True, text=True, timeout=5, check=True)
        return f"git:{out.stdout.strip()}"
    except (OSError, subprocess.SubprocessError):
        try:
            return f"agrivio {metadata.version('agrivio')}"
        except metadata.PackageNotFoundError:
            return "unknown"
