"""Recorded depth-front-end tracks shared by the depth variants of a seed (pipeline.track_cache)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pipeline.run_job as rj
from msckf.frontend import DepthTracks
from pipeline.cli import main
from pipeline.errors import AgrivioError
from pipeline.track_cache import CHUNK_FRAMES, TrackCache


def _frames(n: int, seed: int = 0) -> list[DepthTracks]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        m = int(rng.integers(0, 7))
        counts = {"prev": m, "new": 1, "pruned": 0} if k == 0 else {"prev": m, "tracked": m, "ransac_ok": m,
                                                                     "new": 1, "pruned": 0}
        out.append(DepthTracks(0.1 * k + 1e-7, np.sort(rng.choice(1000, m, replace=False)).astype(np.int64),
                               rng.normal(size=(m, 2)), rng.normal(size=(m, 2)),
                               rng.integers(1, 9, m).astype(np.int32), counts))
    return out


def test_recording_round_trips_exactly_over_several_chunks(tmp_path):
    parts = {"bag": "b", "seed": 1}
    frames = _frames(CHUNK_FRAMES + 37)
    cache = TrackCache(tmp_path, "bag-id", parts)
    assert cache.n_frames() is None and list(cache.frames()) == []
    with cache.recorder() as rec:
        for f in frames:
            rec.add(f)
        assert cache.n_frames() is None  # nothing visible before the commit
        assert rec.commit()
    assert cache.n_frames() == len(frames)
    got = list(TrackCache(tmp_path, "bag-id", dict(parts)).frames())
    assert len(got) == len(frames)
    for a, b in zip(frames, got):
        assert a.stamp_s == b.stamp_s and a.counts == b.counts
        for name in ("ids", "px0", "xy0", "life"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            assert getattr(a, name).dtype == getattr(b, name).dtype
    assert [p.name for p in cache.directory.parent.iterdir()] == [cache.key]  # no hidden folder left


def test_first_commit_wins_and_unfinished_or_foreign_recordings_are_not_used(tmp_path):
    parts = {"bag": "b", "seed": 1}
    first, second = TrackCache(tmp_path, "bag-id", parts), TrackCache(tmp_path, "bag-id", parts)
    with first.recorder() as r1, second.recorder() as r2:
        for f in _frames(5, seed=1):
            r1.add(f)
        for f in _frames(3, seed=2):
            r2.add(f)
        assert r1.commit() and not r2.commit()
    assert first.n_frames() == 5 and len(list(second.frames())) == 5
    assert sorted(p.name for p in first.directory.parent.iterdir()) == [first.key]
    with TrackCache(tmp_path, "bag-id", {"bag": "b", "seed": 2}).recorder() as r:  # never committed
        r.add(_frames(1)[0])
    assert TrackCache(tmp_path, "bag-id", {"bag": "b", "seed": 2}).n_frames() is None
    assert sorted(p.name for p in first.directory.parent.iterdir()) == [first.key]
    manifest = first.directory / "manifest.json"  # a manifest of other parts (hash collision, edited) is ignored
    m = json.loads(manifest.read_text())
    manifest.write_text(json.dumps(dict(m, parts={"bag": "other"})))
    assert first.n_frames() is None


def test_a_missing_chunk_is_not_used_and_a_corrupt_one_is_named(tmp_path):
    cache = TrackCache(tmp_path, "bag-id", {"bag": "b"})
    with cache.recorder() as rec:
        for f in _frames(CHUNK_FRAMES + 1):
            rec.add(f)
        assert rec.commit()
    last = cache.directory / "chunk_000001.npz"
    data = last.read_bytes()
    last.unlink()
    assert cache.n_frames() is None  # incomplete: the run would track live
    last.write_bytes(data[: len(data) // 2])  # present but truncated
    assert cache.n_frames() == CHUNK_FRAMES + 1
    with pytest.raises(AgrivioError, match="chunk_000001.npz: cannot read recorded tracks"):
        list(cache.frames())


def _records(out):
    return {p.parent.parent.name: json.loads(p.read_text()) for p in out.glob("tiny/*/seed0/record.json")}


def test_replayed_depth_runs_equal_live_ones(sim_cache, tmp_path, monkeypatch):
    """Through the CLI on the tiny preset: depth-raw records its seed's tracks, depth-inpainted replays them; the
    replayed run's estimate and frame log are byte-identical to the same run tracking live."""
    monkeypatch.setenv("AGRIVIO_CACHE", str(sim_cache))
    argv = ["run-sequence", "tiny", "--runs", "1", "--variants", "depth-raw,depth-inpainted", "--inpaint", "telea",
            "--executor", "serial"]
    assert main([*argv, "--out", str(tmp_path / "shared")]) == 0
    shared = _records(tmp_path / "shared")
    assert shared["depth-raw"]["tracks"] in ("recorded", "replayed")  # replayed if another test recorded them
    assert shared["depth-inpainted"]["tracks"] == "replayed"
    monkeypatch.setenv(rj.TRACK_CACHE_ENV, "off")  # no recording: every run tracks live
    assert main([*argv, "--out", str(tmp_path / "live")]) == 0
    live = _records(tmp_path / "live")
    assert {r["tracks"] for r in live.values()} == {"live"}
    for variant in ("depth-raw", "depth-inpainted"):
        a, b = (tmp_path / d / "tiny" / variant / "seed0" for d in ("shared", "live"))
        assert (a / "estimate.tum").read_bytes() == (b / "estimate.tum").read_bytes(), variant
        with np.load(a / "frames.npz") as za, np.load(b / "frames.npz") as zb:
            for name in za.files:
                if name != "frame_ms":
                    np.testing.assert_array_equal(za[name], zb[name], err_msg=name)
        assert shared[variant]["metrics"] == live[variant]["metrics"]


@pytest.mark.parametrize("change", ["seed", "frontend"])
def test_the_key_changes_with_what_the_tracks_depend_on(change):
    from msckf.frontend_config import FrontendConfig
    from pipeline.track_cache import track_key_parts

    seq = {"bag": "b", "camchain": "c", "max_frames": None, "code_version": "v", "msckf": {"x": 1}}
    base = TrackCache("/x", "id", track_key_parts(seq, FrontendConfig(), 0)).key
    other = (track_key_parts(seq, FrontendConfig(), 1) if change == "seed"
             else track_key_parts(seq, FrontendConfig(fast_threshold=11), 0))
    assert TrackCache("/x", "id", other).key != base
    # the back end's configuration is not a tracking input: the same tracks serve every depth variant
    assert TrackCache("/x", "id", track_key_parts(dict(seq, msckf={"x": 2}), FrontendConfig(), 0)).key == base
