"""Checks of the user's inputs that run once, up front, before any depth, inpainting or VIO work.

Each check raises :class:`pipeline.errors.AgrivioError` (or a library's input error) whose message names the file
(and line) and the problem; the CLI prints it as one line and exits with status 2.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.errors import AgrivioError

if TYPE_CHECKING:
    from msckf.config import MsckfConfig

#: Fewest ground-truth poses inside the bag's time span for an evaluation (SE(3) alignment needs 3).
MIN_GT_POSES = 3


def check_positive_int(name: str, value: Any, allow_none: bool = True, minimum: int = 1) -> int | None:
    """``value`` as an int ≥ ``minimum`` (None allowed if ``allow_none``); else an error naming ``name``."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise AgrivioError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_unknown_keys(given: Iterable[str], known: Iterable[str], where: str, show_known: bool = False,
                       error: type[Exception] = AgrivioError) -> None:
    """Reject keys of a user's mapping that are not in ``known``: one error naming ``where`` and every bad key.

    The message is ``"<where>: unknown key(s) a, b"`` (sorted), plus ``"; known: …"`` when ``show_known``;
    ``error`` is the exception type raised (``AgrivioError`` by default: one line, exit 2).
    """
    known_set = set(known)
    bad = sorted(set(given) - known_set)
    if bad:
        tail = f"; known: {', '.join(sorted(known_set))}" if show_known else ""
        raise error(f"{where}: unknown key(s) {', '.join(bad)}{tail}")


def resolve_msckf_config(path: str | Path | None) -> MsckfConfig:
    """Parse and validate the MSCKF ``--config`` YAML once (defaults when None); return the resolved config.

    The one place the file is read: the result travels in the :class:`pipeline.run_plan.RunPlan` of every run.

    Raises:
        AgrivioError: the file does not exist.
        MsckfInputError: unknown key, wrong type or out-of-range value, naming the file and the key.
    """
    from msckf.config import load_config

    if path is not None and not Path(path).is_file():
        raise AgrivioError(f"{path}: msckf config file not found")
    return load_config(path)


def check_msckf_config(path: str | Path | None) -> dict[str, Any]:
    """:func:`resolve_msckf_config` in its flat form (``MsckfConfig.to_flat_dict()``, what enters the run key)."""
    return resolve_msckf_config(path).to_flat_dict()


def check_output_dir(out_dir: Path) -> None:
    """Create ``out_dir`` if needed and make sure files can be written in it (one line naming it otherwise)."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".agrivio-write-test.", dir=out_dir)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        why = "not writable" if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS) else (exc.strerror or str(exc))
        raise AgrivioError(f"{out_dir}: output folder {why}") from None


def check_ground_truth(path: Path | str, bag_start_s: float, bag_end_s: float) -> int:
    """Read the GT TUM file and check it overlaps the bag in time; return the number of poses inside the bag.

    Raises:
        EvalInputError: a malformed line (``file:line``), a byte-order mark or header text, no poses.
        AgrivioError: fewer than :data:`MIN_GT_POSES` poses, or fewer than that within the bag's time span.
    """
    from eval.trajectory import read_tum

    p = Path(path)
    try:
        head = p.read_bytes()[:3]
    except OSError as exc:
        raise AgrivioError(f"{p}: cannot read ground truth ({exc.strerror or exc})") from None
    if head.startswith(b"\xef\xbb\xbf"):
        raise AgrivioError(f"{p}:1: starts with a UTF-8 byte-order mark; save the TUM file as plain text")
    gt = read_tum(p)
    n = len(gt.stamps_s)
    if n < MIN_GT_POSES:
        raise AgrivioError(f"{p}: {n} pose(s); an evaluation needs at least {MIN_GT_POSES}")
    inside = int(np.count_nonzero((gt.stamps_s >= bag_start_s - 0.5) & (gt.stamps_s <= bag_end_s + 0.5)))
    if inside < MIN_GT_POSES:
        raise AgrivioError(f"{p}: no time overlap with the bag: ground truth spans {gt.stamps_s[0]:.3f}–"
                           f"{gt.stamps_s[-1]:.3f} s, the bag {bag_start_s:.3f}–{bag_end_s:.3f} s "
                           f"({inside} pose(s) inside)")
    return inside


__all__ = ["MIN_GT_POSES", "check_ground_truth", "check_msckf_config", "check_output_dir", "check_positive_int",
           "check_unknown_keys", "resolve_msckf_config"]
