"""Atomic file output: write to a temporary file in the same folder, then rename over the target."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def remove_stale_temporaries(target: Path | str) -> list[tuple[Path, int]]:
    """Remove the temporary files :func:`atomic_path` left next to ``target`` when a process writing it was killed
    (``SIGKILL``/``SIGTERM`` run no ``finally``; a simulated 450 s bag's temporary is ≈ 10 GB). Only names of
    :func:`atomic_path`'s pattern for this target (``.<target name>.*``) are touched. Call it only when no other
    process may be writing ``target`` now. Returns (path, bytes) of each file removed."""
    target = Path(target)
    removed = []
    if target.parent.is_dir():
        for p in sorted(target.parent.glob(f".{glob.escape(target.name)}.*")):
            if p.is_file():
                size = p.stat().st_size
                p.unlink()
                removed.append((p, size))
    return removed


@contextlib.contextmanager
def atomic_path(target: Path | str, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``target``; on success it is renamed onto ``target``, on error removed.

    An ``OSError`` without a file name (e.g. ENOSPC from a write) is re-raised naming ``target``.

    ``suffix`` keeps the extension libraries use to pick a format (e.g. ``.npz``, ``.bag``).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or ".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    tmp.unlink()  # let the writer create it (some writers refuse existing files)
    try:
        yield tmp
        os.replace(tmp, target)
    except OSError as exc:
        if exc.errno is None or exc.filename is not None:
            raise
        # a failed write() (disk full) names no file: name the target, so the user knows what was not written
        raise OSError(exc.errno, exc.strerror, str(target)) from exc
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(target: Path | str, text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text)


def write_json_atomic(target: Path | str, obj: Any) -> None:
    write_text_atomic(target, json.dumps(obj, indent=2, sort_keys=True) + "\n")
