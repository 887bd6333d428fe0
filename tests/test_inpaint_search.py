"""Block search: the vectorised masked search equals a brute-force evaluation of the documented Sim."""

import numpy as np
import pytest

from inpaint.block_search import LevelGrid, search_level


def _brute(fd, known, ok, cy, cx, t, r, w_depth):
    c_n = fd.shape[2] - 1
    m = known[cy - t:cy + t + 1, cx - t:cx + t + 1]
    n = m.sum()
    tpl = fd[cy - t:cy + t + 1, cx - t:cx + t + 1]
    best = (np.inf, -1, -1)
    for y in range(cy - r, cy + r + 1):
        for x in range(cx - r, cx + r + 1):
            if not ok[y, x]:
                continue
            c = fd[y - t:y + t + 1, x - t:x + t + 1]
            sf = (((tpl[..., :c_n] - c[..., :c_n]) ** 2) * m[..., None]).sum() / (n * c_n)
            dt = tpl[..., c_n] - (tpl[..., c_n] * m).sum() / n
            dc = c[..., c_n] - (c[..., c_n] * m).sum() / n
            s = sf + w_depth * (((dt - dc) ** 2) * m).sum() / n
            if s < best[0]:
                best = (s, y, x)
    return best


@pytest.mark.parametrize("w_depth", [0.0, 1.0, 3.0])
def test_search_matches_brute_force(w_depth):
    rng = np.random.default_rng(7)
    t, r, c_n = 3, 6, 4
    pad = t + r
    h, w = 40, 50
    fd = rng.standard_normal((h + 2 * pad, w + 2 * pad, c_n + 1)).astype(np.float32)
    fd[..., c_n] += 8.0  # depth offset: Sim must not care
    known = rng.random(fd.shape[:2]) > 0.3
    ok = rng.random(fd.shape[:2]) > 0.5
    grid = LevelGrid(0, pad, t, r, fd, known, ok)
    centres = np.array([[20, 25], [pad + 3, pad + 40], [35, 15]])
    ok[centres[:, 0], centres[:, 1]] = False  # a target is never its own candidate (its template has holes)
    res = search_level(grid, centres, w_depth)
    for k, (cy, cx) in enumerate(centres):
        s, y, x = _brute(fd, known, ok, cy, cx, t, r, w_depth)
        assert (res.best[k] == (y, x)).all()
        assert res.sim[k] == pytest.approx(s, rel=1e-3, abs=1e-5)


def test_offset_copy_is_found_exactly():
    """A block copied elsewhere with a depth offset is the best match, with Sim ≈ 0."""
    rng = np.random.default_rng(1)
    t, r = 4, 12
    pad = t + r
    fd = rng.standard_normal((60, 60, 3)).astype(np.float32)
    src = fd[20 - t:20 + t + 1, 26 - t:26 + t + 1].copy()
    src[..., 2] += 5.0
    fd[30 - t:30 + t + 1, 30 - t:30 + t + 1] = src  # target block = source block + 5 m
    known = np.ones((60, 60), bool)
    known[30:30 + t + 1, 30 - t:30 + t + 1] = False  # lower half of the target is a hole
    ok = np.zeros((60, 60), bool)
    ok[pad:60 - pad, pad:60 - pad] = True
    ok[30 - 2 * t:30 + 2 * t + 1, 30 - 2 * t:30 + 2 * t + 1] = False
    res = search_level(LevelGrid(0, pad, t, r, fd, known, ok), np.array([[30, 30]]), 1.0)
    assert tuple(res.best[0]) == (20, 26)
    assert res.sim[0] < 1e-4 and res.energy[0] > 0.1
