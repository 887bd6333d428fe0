"""The streamed frame log (pipeline/frame_log.py): frames.npz equal to the in-memory log it replaced, summaries
equal, a diverged run still saved, no partial file on error."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from pipeline.frame_log import FEATURE_COLUMNS, FrameLog, GrowingArray


@dataclass
class _Debug:
    cam0_px: np.ndarray
    track_length: np.ndarray
    source: np.ndarray
    depth_m: np.ndarray | None = None
    depth_sigma_m: np.ndarray | None = None
    depth_measured: np.ndarray | None = None


@dataclass
class _Stats:
    ratio: np.ndarray
    n_gated: int
    n_gated_out: int

    def gate_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        dof = np.arange(len(self.ratio)) % 5 + 1.0                 # a mix of dof, as a real frame has
        return self.ratio * dof, dof


def _frames(n: int, seed: int = 0) -> list[tuple[float, _Debug | None, float, _Stats]]:
    """Synthetic frames: varying feature counts (some 0), holes, NaN and zero depths, frames without debug."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        k = int(rng.integers(0, 40)) if i % 7 else 0
        z = rng.uniform(0.5, 20.0, k).astype(np.float32)
        z[rng.random(k) < 0.3] = np.nan
        z[rng.random(k) < 0.05] = 0.0
        src = np.where(np.isfinite(z), rng.integers(1, 3, k), 0)
        dbg = None if i % 11 == 5 else _Debug(
            rng.uniform(0, 600, (k, 2)), rng.integers(1, 30, k), src,
            None if i % 13 == 3 else z, None if i % 13 == 3 else (0.02 * z * rng.uniform(1, 4, k)).astype(np.float32),
            None if i % 13 == 3 else (rng.random(k) < 0.6) & np.isfinite(z))
        g = rng.chisquare(2, int(rng.integers(0, 10)))
        out.append((1e9 + i / 15.0, dbg, rng.uniform(0.005, 0.05), _Stats(g, len(g) + 1, int(rng.integers(0, 2)))))
    return out


class _ReferenceLog:
    """The log as it was kept before streaming (whole lists in memory, saved once): the reference of equality."""

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.frame_ms: list[float] = []
        self.cols: list[list[np.ndarray]] = [[] for _ in FEATURE_COLUMNS]
        self.gate: list[np.ndarray] = []

    def add(self, stamp: float, debug: _Debug | None, elapsed: float) -> None:
        self.stamps.append(stamp)
        self.frame_ms.append(1e3 * elapsed)
        uv, tl, src = (np.zeros((0, 2)), np.zeros(0), np.zeros(0)) if debug is None else \
            (debug.cam0_px, debug.track_length, debug.source)
        n = len(src)
        d = getattr(debug, "depth_m", None)
        s = getattr(debug, "depth_sigma_m", None)
        m = getattr(debug, "depth_measured", None)
        for col, v in zip(self.cols, (np.asarray(uv, np.float32).reshape(-1, 2), np.asarray(tl, np.int32),
                                      np.asarray(src, np.uint8), np.full(n, np.nan, np.float32) if d is None else d,
                                      np.full(n, np.nan, np.float32) if s is None else s,
                                      np.zeros(n, bool) if m is None else m)):
            col.append(v)

    def arrays(self) -> dict[str, np.ndarray]:
        counts = np.array([len(u) for u in self.cols[0]], dtype=np.int64)
        out = {"stamps_s": np.array(self.stamps),
               "n_features": np.array([len(u) for u in self.cols[0]]),
               "n_depth": np.array([int(np.count_nonzero(s > 0)) for s in self.cols[2]]),
               "frame_ms": np.array(self.frame_ms), "feature_offsets": np.concatenate([[0], np.cumsum(counts)])}
        for (name, dtype, _), col in zip(FEATURE_COLUMNS, self.cols):
            out[name] = np.concatenate(col).astype(dtype) if col else np.zeros(0, dtype)
        out["feature_uv"] = out["feature_uv"].reshape(-1, 2)
        return out

    def summaries(self) -> tuple[dict, dict]:
        r = np.concatenate(self.gate).astype(np.float64) if self.gate else np.zeros(0)
        gate = {} if r.size == 0 else {"median": float(np.median(r)), "mean": float(np.mean(r))}
        a = self.arrays()
        z, sig, meas = (a["feature_depth_m"].astype(np.float64), a["feature_depth_sigma_m"].astype(np.float64),
                        a["feature_depth_measured"])
        has = np.isfinite(z)
        depth: dict = {}
        if has.any():
            depth = {"features_with_depth": int(has.sum()), "filled_fraction": float(np.mean(~meas[has]))}
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = sig / z
            for name, sel in (("measured", has & meas), ("filled", has & ~meas)):
                v = rel[sel & np.isfinite(rel)]
                if v.size:
                    depth[f"sigma_rel_median_{name}"] = float(np.median(v))
        return gate, depth


def _fill(frames, chunk: int, target: Path) -> tuple[FrameLog, _ReferenceLog]:
    log, ref = FrameLog(target, chunk_frames=chunk), _ReferenceLog()
    with np.errstate(divide="ignore", invalid="ignore"):
        for stamp, dbg, el, st in frames:
            log.add(stamp, dbg, el)
            log.add_gate(st)
            ref.add(stamp, dbg, el)
            ref.gate.append(np.divide(*st.gate_pairs()))
    return log, ref


def _assert_same(path: Path, ref: dict[str, np.ndarray]) -> None:
    with np.load(path) as z:
        assert z.files == list(ref)
        for name, want in ref.items():
            got = z[name]
            assert got.dtype == want.dtype and got.shape == want.shape, name
            assert np.array_equal(got, want, equal_nan=want.dtype.kind == "f"), name


@pytest.mark.parametrize("chunk", [1, 4, 1000])
def test_round_trip_equals_the_in_memory_log_and_summaries(tmp_path, chunk):
    frames = _frames(60)
    target = tmp_path / "frames.npz"
    log, ref = _fill(frames, chunk, target)
    with log:
        log.save()
    _assert_same(target, ref.arrays())
    gate, depth = ref.summaries()
    got_gate = log.gate_summary()
    assert (got_gate["gamma_per_dof_median"], got_gate["gamma_per_dof_mean"]) == (gate["median"], gate["mean"])
    assert 0.0 < got_gate["chi2_noise_scale"] < np.inf and 0.0 <= got_gate["above_chi2_95"] <= 1.0
    got_depth = log.depth_summary()
    assert {k: got_depth[k] for k in depth} == depth and depth["sigma_rel_median_filled"] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames.npz"]  # spill folder gone


def test_empty_log_saves_numpy_empty_dtypes_and_no_summaries(tmp_path):
    with FrameLog(tmp_path / "frames.npz") as log:
        log.save()
    _assert_same(tmp_path / "frames.npz", _ReferenceLog().arrays())
    assert log.gate_summary() == {} and log.depth_summary() == {} and log.timing_summary() == {}


def test_a_diverged_run_still_saves_its_log(tmp_path):
    """run_job saves the log after _run_vio returns a divergence reason: frames up to the divergence."""
    frames = _frames(30)
    target = tmp_path / "frames.npz"
    log, ref = _fill(frames[:17], 4, target)  # the filter diverged at frame 17
    with log:
        log.save()
    _assert_same(target, ref.arrays())
    with np.load(target) as z:
        assert len(z["stamps_s"]) == 17


def test_error_leaves_no_partial_file_and_no_spill(tmp_path, monkeypatch):
    target = tmp_path / "frames.npz"
    with pytest.raises(RuntimeError):  # the run raises mid-way: nothing saved, spill removed
        with FrameLog(target, chunk_frames=2) as log:
            for stamp, dbg, el, _ in _frames(9):
                log.add(stamp, dbg, el)
            assert any(p.name.endswith(".spill") for p in tmp_path.iterdir())
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []

    def fail(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("pipeline.frame_log._copy_file", fail)  # the save itself fails half-written
    with pytest.raises(OSError):
        with FrameLog(target, chunk_frames=2) as log:
            for stamp, dbg, el, _ in _frames(9):
                log.add(stamp, dbg, el)
            log.save()
    assert list(tmp_path.iterdir()) == []


def test_growing_array_appends_and_extends_past_capacity():
    g = GrowingArray(np.float64, capacity=2)
    g.append(1.0)
    g.extend(np.arange(5.0))
    g.append(7.0)
    assert np.array_equal(g.view(), [1.0, 0, 1, 2, 3, 4, 7]) and len(g) == 7
    rows = GrowingArray(np.float64, width=3, capacity=1)
    for i in range(5):
        rows.append([i, i + 1, i + 2])
    assert rows.view().shape == (5, 3) and rows.view()[4, 2] == 6


def test_fixed_mmap_threshold_is_set_where_glibc_is():
    import platform

    from pipeline.run_job import fixed_mmap_threshold

    assert fixed_mmap_threshold() is (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")


@dataclass
class _ZuptStats(_Stats):
    zupt: bool = False
    stamp_s: float = 0.0


def test_zero_velocity_summary_counts_the_images_that_got_one_and_the_last_of_them(tmp_path):
    """The record's ``zero_velocity`` entry: images with a zero-velocity update (``FrameStats.zupt``) and the last
    one's time after the run's first image; none: {} (no entry claims a count of 0 s)."""
    log = FrameLog(tmp_path / "frames.npz")
    t0 = 1e9
    for i in range(30):
        t = t0 + i / 15.0
        log.add(t, None, 0.01)
        log.add_gate(_ZuptStats(np.zeros(0), 0, 0, zupt=i in (1, 2, 3, 7), stamp_s=t))
    assert log.zupt_summary() == {"frames": 4, "last_s": pytest.approx(7 / 15.0, abs=1e-6)}
    quiet = FrameLog(tmp_path / "quiet.npz")
    quiet.add(t0, None, 0.01)
    quiet.add_gate(_Stats(np.zeros(0), 0, 0))                     # a stats object without the field: no update
    assert quiet.zupt_summary() == {}
