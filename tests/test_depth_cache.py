"""Depth cache: keyed by bag and parameters, streams frames in order, warm == cold; depth/demo commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.bag_reader import RosarioSequence
from pipeline.cli import main
from pipeline.depth import DepthFrame, DepthParams
from pipeline.depth_cache import DepthCache, depth_stream


def _same(a: DepthFrame, b: DepthFrame) -> bool:
    return (a.stamp_ns, a.index) == (b.stamp_ns, b.index) and np.array_equal(a.depth_m, b.depth_m, equal_nan=True) \
        and np.array_equal(a.valid, b.valid) and np.array_equal(a.left_rect_grey, b.left_rect_grey)


def test_stream_computes_then_reads_cache(tmp_path, small_bag):
    path, truth = small_bag
    seq = RosarioSequence(path)
    st: dict = {}
    part = list(depth_stream(seq, cache_root=tmp_path, progress=False, stats=st, stop_index=2))
    assert [f.index for f in part] == [0, 1] and st["computed"] == 2
    cold = list(depth_stream(seq, cache_root=tmp_path, progress=False, stats=st))  # resumes after frame 1
    assert (st["cached"], st["computed"]) == (2, len(truth.frame_stamps_ns) - 2)
    assert [f.stamp_ns for f in cold] == truth.frame_stamps_ns.tolist()
    warm = list(depth_stream(seq, cache_root=tmp_path, progress=False, stats=st))
    assert (st["cached"], st["computed"]) == (len(cold), 0)
    uncached = list(depth_stream(seq, cache=False, progress=False, stats=st))
    assert st["directory"] is None
    assert all(_same(a, b) and _same(a, c) for a, b, c in zip(cold, warm, uncached))
    assert all(0.05 < f.hole_ratio < 0.9 for f in cold)
    meta = json.loads((tmp_path / "depth" / seq.identity() / DepthParams().key() / "meta.json").read_text())
    assert meta["n_frames"] == len(truth.frame_stamps_ns) and meta["params"]["num_disparities"] == 64


def test_cache_keyed_by_params_and_bag(tmp_path, small_bag):
    seq = RosarioSequence(small_bag[0])
    list(depth_stream(seq, cache_root=tmp_path, progress=False, stop_index=1))
    st: dict = {}
    list(depth_stream(seq, DepthParams(block_size=7), cache_root=tmp_path, progress=False, stop_index=1, stats=st))
    assert st["computed"] == 1  # other parameters: other cache folder
    assert len(list((tmp_path / "depth" / seq.identity()).iterdir())) == 2


def test_cache_put_get_iter(tmp_path):
    cache = DepthCache(tmp_path, "bag-x", DepthParams(), chunk_size=2)
    rng = np.random.default_rng(0)

    def frame(i: int) -> DepthFrame:
        depth = rng.uniform(0.5, 40.0, (8, 10)).astype(np.float32)
        depth[0, :3] = np.nan
        return DepthFrame(100 + i, i, depth, np.isfinite(depth), rng.integers(0, 256, (8, 10), dtype=np.uint8))

    frames = [frame(i) for i in range(5)]
    for f in (frames[0], frames[1], frames[3]):
        cache.put(f)
    cache.flush()
    again = DepthCache(tmp_path, "bag-x", DepthParams(), chunk_size=99)
    assert again.chunk_size == 2  # an existing cache keeps its chunking
    assert [f.index for f in again.iter()] == [0, 1]  # stops at the gap
    assert again.get(2) is None and again.get(3) is not None
    got = again.get(1)
    assert np.array_equal(got.valid, frames[1].valid) and np.array_equal(got.left_rect_grey, frames[1].left_rect_grey)
    assert np.nanmax(np.abs(got.depth_m - frames[1].depth_m)) <= 0.0005 + 1e-6  # whole millimetres
    assert sorted(p.name for p in again.directory.iterdir()) == ["chunk_000000.npz", "chunk_000001.npz", "meta.json"]


def test_depth_command(tmp_path, small_bag, capsys):
    assert main(["depth", str(small_bag[0]), "--out", str(tmp_path), "--quiet", "--max-frames", "3"]) == 0
    out = capsys.readouterr().out
    assert "frames              3 (3 computed, 0 from cache)" in out and "hole ratio" in out
    summary = json.loads(next((tmp_path / "depth").rglob("summary.json")).read_text())
    assert summary["frames"] == 3 and 0 < summary["hole_ratio_median"] < 1


def test_info_command(small_bag, capsys):
    assert main(["info", str(small_bag[0])]) == 0
    out = capsys.readouterr().out
    assert "/stereo/left/image_raw" in out and "tf_static" in out and "baseline          0.11872 m" in out


def test_hole_ratios_are_read_without_decoding_images_and_old_chunks_still_work(tmp_path, monkeypatch):
    """A warm run's preparation reads the hole ratio of every frame from the chunk index, decoding no PNG; a chunk
    written before the ratios were stored falls back to decoding its depth."""
    import pipeline.depth_cache as dc

    cache = DepthCache(tmp_path, "bag-h", DepthParams(), chunk_size=2)
    rng = np.random.default_rng(1)
    frames = []
    for i in range(4):
        depth = rng.uniform(0.5, 40.0, (8, 10)).astype(np.float32)
        depth[: i + 1, :4] = np.nan
        frames.append(DepthFrame(100 + i, i, depth, np.isfinite(depth), np.zeros((8, 10), np.uint8)))
        cache.put(frames[-1])
    cache.flush()
    decoded = []
    real_decode = dc._depth_mm
    monkeypatch.setattr(dc, "_depth_mm", lambda buf: decoded.append(1) or real_decode(buf))
    fresh = DepthCache(tmp_path, "bag-h", DepthParams())
    assert np.allclose(fresh.hole_ratios(4), [f.hole_ratio for f in frames]) and not decoded
    assert fresh.hole_ratios(5) is None                               # frame 4 is not cached
    chunk = fresh.directory / "chunk_000001.npz"                      # rewrite one chunk without its ratios
    with np.load(chunk) as z:
        old = {k: z[k] for k in z.files if k != "hole_ratio"}
    np.savez(chunk, **old)
    older = DepthCache(tmp_path, "bag-h", DepthParams())
    assert np.allclose(older.hole_ratios(4), [f.hole_ratio for f in frames]) and len(decoded) == 2
    # the layout this cache wrote before pipeline.png_chunks (one array per image) is still read
    c0 = older.directory / "chunk_000000.npz"
    from pipeline.png_chunks import read_chunk

    c = read_chunk(c0)
    legacy = {"stamps_ns": c.stamp_ns, "indices": c.index}
    for k in range(len(c.index)):
        legacy[f"depth_{k}"], legacy[f"grey_{k}"] = c.blob("depth", k), c.blob("grey", k)
    np.savez(c0, **legacy)
    oldest = DepthCache(tmp_path, "bag-h", DepthParams())
    assert [f.index for f in oldest.iter(0, 4)] == [0, 1, 2, 3]
    for f in frames[:2]:
        got = oldest.get(f.index)
        assert np.array_equal(got.valid, f.valid) and np.array_equal(got.left_rect_grey, f.left_rect_grey)


def test_depth_is_stored_as_lz4_and_caches_with_png_depth_read_the_same_values(tmp_path):
    """Issue 16: the depth layer is an LZ4 map stream (decoded 12× faster than the PNG written before); a chunk
    whose depth streams are 16-bit PNG (every cache written before) reads back the same millimetres."""
    from pipeline.lz4_codec import decode_lz4_map, is_lz4_map
    from pipeline.png_chunks import read_chunk, write_chunk
    from pipeline.png_codec import encode_png

    cache = DepthCache(tmp_path, "bag-z", DepthParams(), chunk_size=3)
    rng = np.random.default_rng(7)
    frames = []
    for i in range(3):
        depth = rng.uniform(0.3, 60.0, (12, 16)).astype(np.float32)
        depth[rng.random((12, 16)) < 0.3] = np.nan
        frames.append(DepthFrame(500 + i, i, depth, np.isfinite(depth), rng.integers(0, 255, (12, 16), np.uint8)))
        cache.put(frames[-1])
    cache.flush()
    path = cache.directory / "chunk_000000.npz"
    c = read_chunk(path)
    assert all(is_lz4_map(c.blob("depth", k)) for k in range(3))
    new = [DepthCache(tmp_path, "bag-z", DepthParams()).get(i) for i in range(3)]
    for f, got in zip(frames, new):
        expected_mm = np.rint(np.nan_to_num(f.depth_m) * 1000).astype(np.uint16)
        assert np.array_equal(decode_lz4_map(c.blob("depth", f.index)), expected_mm)
        assert np.array_equal(got.valid, f.valid) and np.array_equal(got.left_rect_grey, f.left_rect_grey)
    # the same chunk with PNG depth streams, as caches before issue 16 hold it
    write_chunk(path, c.index, c.stamp_ns,
                {"depth": [encode_png(decode_lz4_map(c.blob("depth", k))) for k in range(3)],
                 "grey": [c.blob("grey", k) for k in range(3)]}, c.columns)
    assert not any(is_lz4_map(read_chunk(path).blob("depth", k)) for k in range(3))
    old = [DepthCache(tmp_path, "bag-z", DepthParams()).get(i) for i in range(3)]
    for a, b in zip(new, old):
        assert np.array_equal(a.depth_m, b.depth_m, equal_nan=True) and np.array_equal(a.valid, b.valid)
    assert np.allclose(DepthCache(tmp_path, "bag-z", DepthParams()).hole_ratios(3), [f.hole_ratio for f in frames])


def test_lz4_map_streams_are_lossless_and_a_garbled_one_names_its_store():
    from pipeline.lz4_codec import decode_lz4_map, encode_lz4_map, is_lz4_map

    img = np.random.default_rng(3).integers(0, 65535, (37, 53), dtype=np.uint16)
    buf = encode_lz4_map(img)
    assert is_lz4_map(buf) and np.array_equal(decode_lz4_map(buf), img)
    with pytest.raises(ValueError, match="depth cache"):
        decode_lz4_map(buf[: len(buf) // 2], "depth cache")
    with pytest.raises(ValueError, match="uint16"):
        encode_lz4_map(img.astype(np.float32))


def test_frames_without_a_grey_image_store_none_and_a_recorded_key_opens_the_same_cache(tmp_path):
    """Issue 15.5: inpainted frames carry no grey image, so none is stored (the raw cache keeps it); a run's
    recorded parameter key (``CacheKey``) opens the cache its parameters wrote, without rebuilding them."""
    from pipeline.depth_cache import CacheKey

    depth = np.full((8, 10), 3.0, dtype=np.float32)
    grey = np.arange(80, dtype=np.uint8).reshape(8, 10)
    params = DepthParams(num_disparities=32)
    cache = DepthCache(tmp_path, "bag-y", params, chunk_size=2)
    cache.put(DepthFrame(10, 0, depth, np.ones_like(depth, bool), grey))
    cache.put(DepthFrame(11, 1, depth, np.ones_like(depth, bool), None))
    cache.flush()
    again = DepthCache(tmp_path, "bag-y", CacheKey(params.key()))
    assert again.directory == cache.directory
    assert np.array_equal(again.get(0).left_rect_grey, grey)
    assert again.get(1).left_rect_grey is None and again.get(1, grey=False).left_rect_grey is None
    assert again.get(0, grey=False).left_rect_grey is None
    assert again.has(1) and not again.has(2)
    assert np.array_equal(again.get(1).depth_m, depth)
