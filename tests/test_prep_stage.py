"""The one-pass depth preparation (pipeline.prep_stage) stores exactly what the staged depth / inpainting path
stored, resumes from what is cached, and depth-only cache reads lose nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.bag_reader import RosarioSequence
from pipeline.depth import DepthFrame, DepthParams
from pipeline.depth_cache import CacheKey, DepthCache, depth_stream
from pipeline.errors import AgrivioError
from pipeline.inpaint_stage import InpaintParams, ensure_inpainted
from pipeline.prep_stage import prepare_depth_caches

METHODS = ("telea", "ns")  # fast methods: the stage, not the methods, is under test


def _arrays(root: Path) -> dict[str, bytes]:
    """Every array of every depth-cache chunk below ``root``, and each cache's frame count."""
    out: dict[str, bytes] = {}
    for path in sorted((root / "depth").rglob("chunk_*.npz")):
        with np.load(path) as z:
            for name in z.files:
                out[f"{path.relative_to(root)}/{name}"] = z[name].tobytes()
    for meta in sorted((root / "depth").rglob("meta.json")):
        out[str(meta.relative_to(root))] = str(DepthCache(root, meta.parent.parent.name,
                                                          CacheKey(meta.parent.name)).n_frames).encode()
    return out


def _staged(seq: RosarioSequence, root: Path) -> None:
    for _ in depth_stream(seq, DepthParams(), cache=True, progress=False, cache_root=root):
        pass
    for m in METHODS:
        ensure_inpainted(seq, InpaintParams(DepthParams(), m), root, progress=False)


@pytest.mark.parametrize("workers", [1, 2])
def test_one_pass_stores_byte_for_byte_what_the_staged_stages_stored(small_bag, tmp_path, workers):
    seq = RosarioSequence(small_bag[0])
    _staged(seq, tmp_path / "staged")
    params = [InpaintParams(DepthParams(), m) for m in METHODS]
    stats = prepare_depth_caches(seq, DepthParams(), params, tmp_path / "pass", workers=workers, progress=False)
    staged, one_pass = _arrays(tmp_path / "staged"), _arrays(tmp_path / "pass")
    assert len(staged) > 3 * 5 and staged.keys() == one_pass.keys()
    assert [k for k in staged if staged[k] != one_pass[k]] == []
    n = seq.count("/stereo/left/image_raw")
    assert stats["frames"] == n and stats["depth_computed"] == n and stats["inpainted"] == {m: n for m in METHODS}


def test_resumes_computing_only_what_is_missing(small_bag, tmp_path):
    seq = RosarioSequence(small_bag[0])
    d = DepthParams()
    telea, ns = InpaintParams(d, "telea"), InpaintParams(d, "ns")
    first = prepare_depth_caches(seq, d, [telea], tmp_path, workers=1, progress=False)
    n = first["frames"]
    again = prepare_depth_caches(seq, d, [telea, ns], tmp_path, workers=1, progress=False)
    assert again["depth_computed"] == 0 and again["inpainted"] == {"telea": 0, "ns": n}
    done = prepare_depth_caches(seq, d, [telea, ns], tmp_path, workers=1, progress=False)
    assert done["frames"] == 0 and done["inpainted"] == {"telea": 0, "ns": 0}
    # a lost chunk of the raw depth: recomputed from the bag, the inpainted caches untouched
    raw = DepthCache(tmp_path, seq.identity(), d)
    before = raw.get(1, grey=True)
    (raw.directory / "chunk_000000.npz").unlink()
    redo = prepare_depth_caches(seq, d, [telea, ns], tmp_path, workers=1, progress=False)
    assert redo["depth_computed"] == n and redo["inpainted"] == {"telea": 0, "ns": 0}
    after = DepthCache(tmp_path, seq.identity(), d).get(1, grey=True)
    assert np.array_equal(after.depth_m, before.depth_m, equal_nan=True)
    assert np.array_equal(after.left_rect_grey, before.left_rect_grey)


def test_unknown_method_or_foreign_depth_parameters_are_refused(small_bag, tmp_path):
    seq = RosarioSequence(small_bag[0])
    with pytest.raises(AgrivioError, match="unknown inpainting method"):
        prepare_depth_caches(seq, DepthParams(), [InpaintParams(DepthParams(), "nope")], tmp_path, progress=False)
    other = DepthParams(block_size=7)
    with pytest.raises(ValueError, match="other depth parameters"):
        prepare_depth_caches(seq, DepthParams(), [InpaintParams(other, "telea")], tmp_path, progress=False)


def _frame(i: int) -> DepthFrame:
    rng = np.random.default_rng(i)
    depth = rng.uniform(1, 9, (12, 16)).astype(np.float32)
    valid = rng.random((12, 16)) < 0.7
    return DepthFrame(1000 + i, i, np.where(valid, depth, np.nan).astype(np.float32), valid,
                      rng.integers(0, 255, (12, 16), dtype=np.uint8))


def test_depth_only_reads_never_drop_the_grey_images_of_a_chunk_written_again(tmp_path):
    cache = DepthCache(tmp_path, "bag", DepthParams(), chunk_size=4)
    for i in (0, 1):
        cache.put(_frame(i))
    cache.flush()  # a partial chunk on disk
    again = DepthCache(tmp_path, "bag", DepthParams())
    depth_only = again.get(0, grey=False)
    assert depth_only.left_rect_grey is None and again.encoded(0, grey=False).grey_png.size == 0
    again.put(_frame(2))  # joins the chunk read without its grey images
    again.flush()
    final = DepthCache(tmp_path, "bag", DepthParams())
    for i in (0, 1, 2):
        got = final.get(i, grey=True)
        assert np.array_equal(got.left_rect_grey, _frame(i).left_rect_grey), i
        assert np.array_equal(got.valid, _frame(i).valid)
