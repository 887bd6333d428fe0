"""The per-frame log of a VIO run (``frames.npz``), streamed to disk while the run goes.

``frames.npz`` holds, per frame, the stamp, feature counts and time per frame, and the features themselves (raw
left pixels, track length, depth source, depth, its σ and whether it was measured), ragged arrays flattened with
an index (``feature_offsets``). Its array names and dtypes:

=========================  =========  =============================================================
``stamps_s``               float64    (F,) frame stamps, s
``n_features``             int64      (F,) features per frame (float64 when F = 0, as numpy makes it)
``n_depth``                int64      (F,) features with a depth per frame (likewise)
``frame_ms``               float64    (F,) VIO time per frame, ms
``feature_offsets``        int64      (F + 1,) frame i's features are rows ``off[i]:off[i + 1]``
``feature_uv``             float32    (N, 2) raw left-image pixels
``feature_track_length``   int32      (N,)
``feature_source``         uint8      (N,) ``msckf.types.DepthSource``
``feature_depth_m``        float32    (N,) NaN where the feature has no depth
``feature_depth_sigma_m``  float32    (N,) the σ the filter was given (NaN where none)
``feature_depth_measured`` bool       (N,)
=========================  =========  =============================================================

Memory does not grow with the features: :class:`FrameLog` gathers a chunk of frames, then appends each feature
column to its own file in a hidden spill folder next to the target; :meth:`FrameLog.save` streams those files into
the ``.npz`` (zip, deflate, like ``np.savez_compressed``) through a temporary file renamed onto the target
(:func:`pipeline.atomic.atomic_path`). :meth:`FrameLog.close` removes the spill folder, saved or not (a run that
raises leaves no log and no partial file). What stays in memory per frame: the four per-frame columns (32 B), the
γ/dof of the frame's gated features (8 B each) and σ_Z/Z of its features with a depth (8 B each), kept in typed
growing buffers so that the run's medians and means (:meth:`gate_summary`, :meth:`depth_summary`,
:meth:`timing_summary`) are computed from exactly the values, in exactly the order, that they always were.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from eval.gate_calibration import gate_statistics
from pipeline.atomic import atomic_path

# (name in frames.npz, dtype, trailing shape) of the per-feature columns, in the order they are saved
FEATURE_COLUMNS: tuple[tuple[str, np.dtype, tuple[int, ...]], ...] = (
    ("feature_uv", np.dtype(np.float32), (2,)),
    ("feature_track_length", np.dtype(np.int32), ()),
    ("feature_source", np.dtype(np.uint8), ()),
    ("feature_depth_m", np.dtype(np.float32), ()),
    ("feature_depth_sigma_m", np.dtype(np.float32), ()),
    ("feature_depth_measured", np.dtype(bool), ()),
)
_COPY_BYTES = 1 << 22  # bytes per read when streaming a spill file into the zip


class GrowingArray:
    """A 1-D (or (n, k)) typed array that grows by appending, with amortised doubling: ``view()`` is the data."""

    def __init__(self, dtype: Any, width: int | None = None, capacity: int = 256) -> None:
        self._shape_tail = () if width is None else (width,)
        self._buf = np.empty((capacity, *self._shape_tail), dtype=dtype)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def _reserve(self, n: int) -> None:
        if n > len(self._buf):
            new = np.empty((max(n, 2 * len(self._buf)), *self._shape_tail), dtype=self._buf.dtype)
            new[:self._n] = self._buf[:self._n]
            self._buf = new

    def append(self, value: Any) -> None:
        self._reserve(self._n + 1)
        self._buf[self._n] = value
        self._n += 1

    def extend(self, values: np.ndarray) -> None:
        values = np.asarray(values)
        k = len(values)
        self._reserve(self._n + k)
        self._buf[self._n:self._n + k] = values
        self._n += k

    def view(self) -> np.ndarray:
        return self._buf[:self._n]


class FrameLog:
    """Per-frame log of a VIO run (for the replay and timing figures), streamed to ``target`` (``frames.npz``).

    Use as a context manager (or call :meth:`close`): the spill folder is removed on exit, saved or not. Nothing
    touches the disk until the first frame; a log with no frame (odometry runs) only gives empty summaries.
    ``chunk_frames``: frames gathered in memory before their features are appended to the spill files.
    """

    def __init__(self, target: Path | str, chunk_frames: int = 200) -> None:
        self.target = Path(target)
        self.chunk_frames = int(chunk_frames)
        self.stamps = GrowingArray(np.float64)
        self.n_features = GrowingArray(np.int64)
        self.n_depth = GrowingArray(np.int64)
        self.frame_ms = GrowingArray(np.float64)
        self._gate_gamma = GrowingArray(np.float64)
        self._gate_dof = GrowingArray(np.float64)
        self._rel = {"measured": GrowingArray(np.float64), "filled": GrowingArray(np.float64)}
        self._n_has_depth = 0
        self._n_filled = 0
        self.gated = 0
        self.gated_out = 0
        self.zupt_frames = 0
        self.zupt_last_stamp_s = float("nan")
        self.fill_px = 0
        self.far_open_px = 0
        self.occlusion_edge_px = 0
        self._pending: list[list[np.ndarray]] = [[] for _ in FEATURE_COLUMNS]
        self._spill: Path | None = None
        self._files: list[Any] = []

    # ---- lifetime ---------------------------------------------------------------------------------------------
    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close and remove the spill files (idempotent)."""
        for fh in self._files:
            fh.close()
        self._files = []
        if self._spill is not None:
            shutil.rmtree(self._spill, ignore_errors=True)
            self._spill = None

    def __len__(self) -> int:
        return len(self.stamps)

    # ---- adding -----------------------------------------------------------------------------------------------
    def add_fills(self, n_filled_px: int, n_far_open_px: int, n_occlusion_edge_px: int) -> None:
        """Count one frame's inpainted pixels (raw SGBM holes the method filled), how many of them were dropped
        as open to the far field (:meth:`pipeline.depth_sigma.DepthSigmaModel.far_open`) and how many others as
        lying at an occlusion edge (:meth:`~pipeline.depth_sigma.DepthSigmaModel.occlusion_edge`)."""
        self.fill_px += int(n_filled_px)
        self.far_open_px += int(n_far_open_px)
        self.occlusion_edge_px += int(n_occlusion_edge_px)

    def add_gate(self, stats: Any) -> None:
        """Collect the χ² gate of one frame (``msckf.filter.FrameStats``): γ and dof of every gated feature
        (``FrameStats.gate_pairs``), and whether the frame got a zero-velocity update (``FrameStats.zupt``, stamp
        ``FrameStats.stamp_s``)."""
        gamma, dof = stats.gate_pairs()
        self._gate_gamma.extend(np.asarray(gamma, dtype=np.float64).reshape(-1))
        self._gate_dof.extend(np.asarray(dof, dtype=np.float64).reshape(-1))
        self.gated += stats.n_gated
        self.gated_out += int(stats.n_gated_out)
        if getattr(stats, "zupt", False):
            self.zupt_frames += 1
            self.zupt_last_stamp_s = float(stats.stamp_s)

    def add(self, stamp_s: float, debug: Any, elapsed_s: float) -> None:
        """One frame: its stamp, the VIO's per-frame debug (``msckf`` ``last_debug``, or None) and its VIO time."""
        self.stamps.append(stamp_s)
        self.frame_ms.append(1e3 * elapsed_s)
        if debug is None:
            uv, tl, src = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        else:
            uv, tl, src = debug.cam0_px, debug.track_length, debug.source
        n = len(src)
        depth = getattr(debug, "depth_m", None)
        sigma = getattr(debug, "depth_sigma_m", None)
        measured = getattr(debug, "depth_measured", None)
        cols: list[np.ndarray] = [np.asarray(uv, dtype=np.float32).reshape(-1, 2), np.asarray(tl, dtype=np.int32),
                                  np.asarray(src, dtype=np.uint8),
                                  np.full(n, np.nan, np.float32) if depth is None else np.asarray(depth, np.float32),
                                  np.full(n, np.nan, np.float32) if sigma is None else np.asarray(sigma, np.float32),
                                  np.zeros(n, bool) if measured is None else np.asarray(measured, bool)]
        for pending, col in zip(self._pending, cols):
            pending.append(col)
        self.n_features.append(len(cols[0]))
        self.n_depth.append(int(np.count_nonzero(cols[2] > 0)))
        self._summarise_depth(cols[3], cols[4], cols[5])
        if len(self._pending[0]) >= self.chunk_frames:
            self._flush()

    def _summarise_depth(self, depth: np.ndarray, sigma: np.ndarray, measured: np.ndarray) -> None:
        """Keep what :meth:`depth_summary` needs of one frame: counts, and σ_Z/Z of its features with a depth."""
        z, sig, meas = depth.astype(np.float64), sigma.astype(np.float64), measured.astype(bool)
        has = np.isfinite(z)
        self._n_has_depth += int(np.count_nonzero(has))
        self._n_filled += int(np.count_nonzero(has & ~meas))
        with np.errstate(divide="ignore", invalid="ignore"):  # no depth / zero depth: not finite, left out
            rel = sig / z
        for name, sel in (("measured", has & meas), ("filled", has & ~meas)):
            self._rel[name].extend(rel[sel & np.isfinite(rel)])

    def _flush(self) -> None:
        """Append the pending frames' feature columns to the spill files."""
        if not self._pending[0]:
            return
        if self._spill is None:
            self.target.parent.mkdir(parents=True, exist_ok=True)
            self._spill = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.", suffix=".spill",
                                                dir=self.target.parent))
            self._files = [open(self._spill / f"{name}.bin", "wb") for name, _, _ in FEATURE_COLUMNS]
        for fh, pending, (_, dtype, _) in zip(self._files, self._pending, FEATURE_COLUMNS):
            np.ascontiguousarray(np.concatenate(pending).astype(dtype, copy=False)).tofile(fh)
            pending.clear()

    # ---- output -----------------------------------------------------------------------------------------------
    def save(self) -> None:
        """Write ``frames.npz`` (atomically: temporary file + rename) from the spill files and per-frame columns."""
        self._flush()
        for fh in self._files:
            fh.flush()
        n_frames = len(self)
        counts = self.n_features.view()
        per_frame = {"stamps_s": self.stamps.view(), "n_features": counts, "n_depth": self.n_depth.view(),
                     "frame_ms": self.frame_ms.view(),
                     "feature_offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)}
        if n_frames == 0:  # numpy's dtype of an empty list, as frames.npz has always had it
            per_frame["n_features"] = np.zeros(0)
            per_frame["n_depth"] = np.zeros(0)
        n_rows = int(np.sum(counts))
        with atomic_path(self.target, suffix=".npz") as tmp:
            with zipfile.ZipFile(tmp, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
                for name, arr in per_frame.items():
                    with zf.open(name + ".npy", "w", force_zip64=True) as fid:
                        np.lib.format.write_array(fid, np.ascontiguousarray(arr), allow_pickle=False)
                for name, dtype, tail in FEATURE_COLUMNS:
                    with zf.open(name + ".npy", "w", force_zip64=True) as fid:
                        np.lib.format.write_array_header_1_0(fid, {"descr": np.lib.format.dtype_to_descr(dtype),
                                                                   "fortran_order": False,
                                                                   "shape": (n_rows, *tail)})
                        if self._spill is not None:
                            _copy_file(self._spill / f"{name}.bin", fid)

    def gate_summary(self) -> dict[str, float]:
        """The χ² gate over the run: median and mean γ/dof, the χ² noise scale c (1 when the residual covariance
        the filter states is right, whatever the features' dof: :func:`eval.gate_calibration.chi2_noise_scale`),
        the share of features above the χ²(dof) 95 % quantile (5 % when calibrated) and the fraction of gated
        features that were rejected."""
        g, d = self._gate_gamma.view(), self._gate_dof.view()
        if g.size == 0:
            return {}
        return {**gate_statistics(g, d), "features_gated": self.gated,
                "rejected_fraction": float(self.gated_out / max(self.gated, 1))}

    def zupt_summary(self) -> dict[str, float]:
        """The zero-velocity updates of the run (``msckf`` ``update.zupt_max_flow``): how many images got one and
        the last of them, in seconds after the run's first image; {} when none did."""
        if self.zupt_frames == 0 or len(self) == 0:
            return {}
        return {"frames": self.zupt_frames, "last_s": self.zupt_last_stamp_s - float(self.stamps.view()[0])}

    def depth_summary(self) -> dict[str, float]:
        """How much of the run's feature depth was measured vs filled, and its stated σ_Z/Z (medians)."""
        if self._n_has_depth == 0:
            return {}
        # the mean of a boolean array is its count of True over its size (an exact float64 sum, then one division)
        out: dict[str, float] = {"features_with_depth": self._n_has_depth,
                                 "filled_fraction": float(np.float64(self._n_filled) / np.float64(self._n_has_depth))}
        for name in ("measured", "filled"):
            r = self._rel[name].view()
            if r.size:
                out[f"sigma_rel_median_{name}"] = float(np.median(r))
        if self.fill_px:
            out["far_open_fill_fraction"] = float(self.far_open_px / self.fill_px)
            out["occlusion_edge_fill_fraction"] = float(self.occlusion_edge_px / self.fill_px)
        return out

    def timing_summary(self) -> dict[str, float]:
        ms = self.frame_ms.view()
        if ms.size == 0:
            return {}
        return {"frame_ms_median": float(np.median(ms)), "frame_ms_p95": float(np.percentile(ms, 95)),
                "fps": float(1e3 / np.mean(ms))}


def _copy_file(src: Path, fid: Any) -> None:
    with open(src, "rb") as fh:
        while block := fh.read(_COPY_BYTES):
            fid.write(block)


__all__ = ["FEATURE_COLUMNS", "FrameLog", "GrowingArray"]
