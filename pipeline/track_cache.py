"""Recorded depth-front-end tracks, shared by the depth variants of one seed (issue 16: the cost of a matrix).

The depth front end's tracking (KLT, RANSAC, FAST: ≈ 60 % of a ``depth-*`` run's VIO time) never reads the depth
map, so ``depth-raw`` and every ``depth-inpainted`` run of one (sequence, seed, front-end configuration) compute
identical tracks. The first such run to finish records them here; the others replay them
(:class:`msckf.frontend_replay.RecordedDepthFrontend`) and only read their depth. Their estimates are
bit-identical to a live front end's (tested).

Layout: ``<cache>/tracks/<bag identity>/<key>/`` with ``manifest.json`` (format, key parts, frame count) and
``chunk_NNNNNN.npz`` (uncompressed) of :data:`CHUNK_FRAMES` frames each:

==============  =======  ======================================================================
``stamps_s``    float64  (F,) frame stamps, s (exactly the image stamps the run saw)
``offsets``     int64    (F + 1,) frame i's tracks are rows ``offsets[i]:offsets[i + 1]``
``ids``         int64    (N,) track ids
``px0``         float64  (N, 2) raw left pixels
``xy0``         float64  (N, 2) cam0 normalised coordinates
``life``        int32    (N,) frames observed
``counts``      int64    (F, 5) ``prev, tracked, ransac_ok, new, pruned`` (−1: absent on that frame)
==============  =======  ======================================================================

The key (:func:`track_key_parts`) holds everything the tracks depend on: the bag's content identity, the
camchain, the frame limit, the front-end configuration, the seed and the code fingerprint (any code change makes
a new key: a stale recording is never replayed). A recording is written into a hidden folder and renamed into
place only when the run saw every frame (a diverged run records nothing); two runs finishing the same key keep
the first. A missing or incomplete recording (no manifest, other key parts, a chunk file missing) is not used: the
run tracks live. A chunk that exists but cannot be read fails the run with a message naming it.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from eval.records import config_hash
from msckf.frontend import DepthTracks
from msckf.frontend_config import FrontendConfig
from pipeline.errors import AgrivioError

#: Bump when the recorded content or its layout changes.
TRACKS_VERSION = 1
CHUNK_FRAMES = 100
COUNT_NAMES = ("prev", "tracked", "ransac_ok", "new", "pruned")
MANIFEST = "manifest.json"
_ARRAYS = ("stamps_s", "offsets", "ids", "px0", "xy0", "life", "counts")


def track_key_parts(sequence_parts: dict[str, Any], frontend: FrontendConfig, seed: int) -> dict[str, Any]:
    """What a seed's tracks depend on, from a run's sequence-level key parts (:mod:`pipeline.run_key`)."""
    return {"tracks_version": TRACKS_VERSION, "bag": sequence_parts.get("bag"),
            "camchain": sequence_parts.get("camchain"), "max_frames": sequence_parts.get("max_frames"),
            "code_version": sequence_parts.get("code_version"), "frontend": asdict(frontend), "seed": int(seed)}


class TrackCache:
    """The recording of one key: ``<cache_root>/tracks/<bag_identity>/<config_hash(parts)>``."""

    def __init__(self, cache_root: Path | str, bag_identity: str, parts: dict[str, Any]) -> None:
        self.parts = parts
        self.key = config_hash(parts)
        self.directory = Path(cache_root) / "tracks" / bag_identity / self.key

    def n_frames(self) -> int | None:
        """Frames recorded (None: no complete recording of this key)."""
        try:
            manifest = json.loads((self.directory / MANIFEST).read_text())
        except (OSError, ValueError):
            return None
        if manifest.get("tracks_version") != TRACKS_VERSION or manifest.get("parts") != self.parts:
            return None
        n = manifest.get("n_frames")
        if not isinstance(n, int) or not all(self._chunk_path(k).is_file() for k in range(-(-n // CHUNK_FRAMES))):
            return None
        return n

    def _chunk_path(self, chunk: int) -> Path:
        return self.directory / _chunk_name(chunk)

    def frames(self, n_frames: int | None = None) -> Iterator[DepthTracks]:
        """The recorded frames in order, read one chunk at a time; AgrivioError naming a chunk it cannot read.

        ``n_frames``: what :meth:`n_frames` returned (saves reading the manifest again); None: read it."""
        n = (self.n_frames() if n_frames is None else n_frames) or 0
        for start in range(0, n, CHUNK_FRAMES):
            path = self._chunk_path(start // CHUNK_FRAMES)
            try:
                with np.load(path) as z:
                    arrays = {k: z[k] for k in _ARRAYS}
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
                raise AgrivioError(f"{path}: cannot read recorded tracks ({type(exc).__name__}: {exc}); delete "
                                   f"{self.directory} to record them again") from None
            yield from _unpack(arrays)

    def recorder(self) -> TrackRecorder:
        return TrackRecorder(self)


class TrackRecorder:
    """Streams a run's tracks into a hidden folder; :meth:`commit` publishes them, :meth:`close` drops the rest.

    Memory holds at most one chunk of frames.
    """

    def __init__(self, cache: TrackCache) -> None:
        self.cache = cache
        self._pending: list[DepthTracks] = []
        self._n = 0
        self._tmp: Path | None = None

    def __enter__(self) -> TrackRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add(self, tracks: DepthTracks) -> None:
        self._pending.append(tracks)
        self._n += 1
        if len(self._pending) == CHUNK_FRAMES:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        if self._tmp is None:
            parent = self.cache.directory.parent
            parent.mkdir(parents=True, exist_ok=True)
            self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.cache.key}.", dir=parent))
        chunk = (self._n - len(self._pending)) // CHUNK_FRAMES
        np.savez(self._tmp / _chunk_name(chunk), **_pack(self._pending))
        self._pending = []

    def commit(self) -> bool:
        """Publish the recording (all frames added so far); False if another run published this key first."""
        self._flush()
        if self._tmp is None:
            return False
        manifest = {"tracks_version": TRACKS_VERSION, "parts": self.cache.parts, "n_frames": self._n,
                    "chunk_frames": CHUNK_FRAMES}
        (self._tmp / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
        try:
            os.rename(self._tmp, self.cache.directory)
        except OSError:  # another run of the same key published first (a non-empty folder is not replaced)
            return False
        self._tmp = None
        return True

    def close(self) -> None:
        """Remove what was not published."""
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
        self._pending = []


def _chunk_name(chunk: int) -> str:
    return f"chunk_{chunk:06d}.npz"


def _pack(frames: list[DepthTracks]) -> dict[str, np.ndarray]:
    sizes = np.array([len(f.ids) for f in frames], np.int64)
    return {
        "stamps_s": np.array([f.stamp_s for f in frames], np.float64),
        "offsets": np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        "ids": np.concatenate([f.ids for f in frames]).astype(np.int64),
        "px0": np.concatenate([f.px0 for f in frames]).astype(np.float64).reshape(-1, 2),
        "xy0": np.concatenate([f.xy0 for f in frames]).astype(np.float64).reshape(-1, 2),
        "life": np.concatenate([f.life for f in frames]).astype(np.int32),
        "counts": np.array([[f.counts.get(k, -1) for k in COUNT_NAMES] for f in frames], np.int64).reshape(-1, 5),
    }


def _unpack(a: dict[str, np.ndarray]) -> Iterator[DepthTracks]:
    off = a["offsets"]
    for i, stamp in enumerate(a["stamps_s"]):
        rows = slice(int(off[i]), int(off[i + 1]))
        counts = {k: int(v) for k, v in zip(COUNT_NAMES, a["counts"][i]) if v >= 0}
        yield DepthTracks(float(stamp), a["ids"][rows], a["px0"][rows], a["xy0"][rows], a["life"][rows], counts)


__all__ = ["CHUNK_FRAMES", "TRACKS_VERSION", "TrackCache", "TrackRecorder", "track_key_parts"]
