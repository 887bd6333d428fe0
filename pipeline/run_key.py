"""The input key of a run: everything that determines its record, hashed, so a record is reused only for the inputs
that made it.

The key of a ``(sequence, variant, seed)`` run is :func:`eval.records.config_hash` of a mapping of

* ``bag``: the bag's content identity (:meth:`RosarioSequence.identity`: name, size, hash of the first MiB and the
  index region) — a different bag of the same name, or the same bag re-recorded, gets another key. The file's
  mtime is deliberately not part of it: copying or touching a bag does not change its content;
* ``gt``: BLAKE2 hash of the ground-truth file's bytes (None without GT);
* ``camchain``: BLAKE2 hash of the Kalibr camchain file used (the shipped one when none is given);
* ``max_frames``, the lever arms and the IMU → base_link rotation;
* ``msckf``: the fully resolved MSCKF configuration (defaults + ``--config``), for VIO variants;
* ``depth``: the depth stage's parameter key (:meth:`DepthParams.key`), for ``depth-*`` variants;
* ``inpaint``: the inpainting parameter key (method, options, stage version, weights), for ``depth-inpainted``;
* ``code_version``: :func:`code_fingerprint` (``git describe --dirty`` or the package version, plus a hash of the
  uncommitted changes to the four packages, so two different edits of a dirty checkout never share a key),
  ``variant`` and ``seed``.

Only the parts a variant uses enter its key: changing the inpainting method does not invalidate stereo runs.
"""

from __future__ import annotations

import functools
import hashlib
import subprocess
from pathlib import Path
from typing import Any

from eval.records import config_hash
from eval.variants import DEPTH_INPAINTED, ODOMETRY

KEY_VERSION = 1


def file_digest(path: Path | str | None) -> str | None:
    """BLAKE2b (16 hex digits) of a file's bytes, or None for no file. Meant for small files (GT, YAML)."""
    if path is None:
        return None
    digest = hashlib.blake2b(digest_size=8)
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


#: The packages whose code determines a run's outputs.
CODE_DIRS = ("pipeline", "msckf", "inpaint", "eval")


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """:func:`pipeline.version.code_version`, plus ``+<hash>`` of uncommitted changes under :data:`CODE_DIRS`.

    ``git describe --dirty`` says only *that* the checkout differs from its commit; the hash says *how*, so a
    record made before an uncommitted edit is not reused after it.
    """
    from pipeline.paths import REPO_ROOT
    from pipeline.version import code_version

    version = code_version()
    if not version.endswith("-dirty"):
        return version
    digest = hashlib.blake2b(digest_size=6)
    try:
        for cmd in (["git", "diff", "HEAD", "--", *CODE_DIRS],
                    ["git", "ls-files", "--others", "--exclude-standard", "--", *CODE_DIRS]):
            out = subprocess.run(cmd, cwd=REPO_ROOT, capture_output=True, timeout=20, check=True).stdout
            digest.update(out)
    except (OSError, subprocess.SubprocessError):
        return version
    return f"{version}+{digest.hexdigest()}"


def sequence_key_parts(bag_identity: str, gt: Path | str | None, camchain: Path | str, max_frames: int | None,
                       levers: dict[str, Any], msckf: dict[str, Any], depth_key: str, inpaint_key: str | None,
                       code_version: str) -> dict[str, Any]:
    """The sequence-level parts of the key (see the module docstring); JSON-able.

    Args:
        bag_identity: :meth:`RosarioSequence.identity` of the bag.
        gt: ground-truth TUM file or None.
        camchain: the camchain file actually used (the shipped one by default).
        max_frames: frame limit of every stage (None: the whole sequence).
        levers: ``lever_arm_imu`` (m), ``lever_arm_base`` (m), ``R_base_imu`` as given to the runs.
        msckf: resolved MSCKF configuration, flat (``MsckfConfig.to_flat_dict()``: the same mapping as before the
            config was grouped, so keys of unchanged configs do not move).
        depth_key: :meth:`DepthParams.key`.
        inpaint_key: :meth:`InpaintParams.key` of the ``depth-inpainted`` method, or None.
        code_version: :func:`pipeline.version.code_version`.
    """
    return {"key_version": KEY_VERSION, "bag": bag_identity, "gt": file_digest(gt), "camchain": file_digest(camchain),
            "max_frames": max_frames, "levers": {k: levers.get(k) for k in sorted(levers)}, "msckf": msckf,
            "depth": depth_key, "inpaint": inpaint_key, "code_version": code_version}


def job_key_parts(sequence_parts: dict[str, Any], variant: str, seed: int) -> dict[str, Any]:
    """The parts that determine one run of ``variant`` with ``seed`` (unused parts left out)."""
    parts = dict(sequence_parts, variant=variant, seed=int(seed))
    if variant == ODOMETRY:
        parts.pop("msckf", None)
    if not variant.startswith("depth"):
        parts.pop("depth", None)
    if variant != DEPTH_INPAINTED:
        parts.pop("inpaint", None)
    return parts


def input_key(parts: dict[str, Any]) -> str:
    """The key itself: a 16-hex-digit hash of ``parts``."""
    return config_hash(parts)


__all__ = ["KEY_VERSION", "file_digest", "input_key", "job_key_parts", "sequence_key_parts"]
