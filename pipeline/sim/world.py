"""The soybean field: rows, plants, leaves, weeds, canopy level of detail and leaf shadows (field frame F).

Geometry is generated lazily per *row block* (row ``i``, 4 m of row ``b``) from ``(world_seed, i, b)``, so any part
of an arbitrarily large field can be produced in any order with identical results, and memory stays bounded (an
LRU cache of blocks). Everything is world-fixed: what the camera sees of a place does not depend on when or from
where it is seen, except for the level of detail (below).

Level of detail, by horizontal distance from the camera to a row segment (hierarchy 4 m → 1 m → 0.25 m):

* ``< render.leaf_range_m``: every leaflet and weed leaf is a textured planar polygon;
* up to 12 m: 0.25 m canopy prisms (triangular cross-section, height and width from the plants they stand for,
  missing where the row has a gap);
* up to 30 m: 1 m prisms; beyond: a flat canopy plane at the mean canopy height over the field's rows (drawn by
  the renderer per pixel). At that range the soil between rows is hidden by the canopy anyway.

Polygons are planar; a leaflet is an ovate 14-gon with its own plane, texture axes and colour.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from pipeline.sim.config import FieldConfig
from pipeline.sim.hashing import hash_normal, hash_uniform
from pipeline.sim.terrain import Terrain
from pipeline.sim.textures import srgb_to_linear
from pipeline.sim.trace_kernels import max_vertex_distance, raster_polygons

BLOCK_M = 4.0
SEG0_M = 0.25
SEG1_M = 1.0
SEGS0_PER_BLOCK = int(BLOCK_M / SEG0_M)
PRISM0_RANGE_M = 12.0
PRISM1_RANGE_M = 30.0

MAT_LEAF, MAT_WEED, MAT_CANOPY = 1, 2, 3

SHADOW_TILE_M = 2.0
SHADOW_TEXEL_M = 0.01
SHADOW_NONE = -10.0  # map value where nothing casts a shadow


@dataclass
class PolySet:
    """A batch of planar textured polygons (field frame).

    Attributes:
        verts: (N, V, 3) vertices in metres (shorter polygons repeat their last vertex).
        origin: (N, 3) a point of each polygon's plane (texture origin).
        e1, e2: (N, 3) unit in-plane texture axes (leaf: midrib, across; prism: along the row, down the slope).
        normal: (N, 3) unit plane normal ``e1 × e2``.
        size: (N,) texture scale in metres (leaflet length; 1 for prisms).
        albedo: (N, 3) float32 linear-RGB base albedo.
        material: (N,) uint8 ``MAT_*``.
        extra: (N,) float32 per-polygon random value in [0, 1) (texture variation).
        ground: (N,) ground height under the polygon's plant or prism, metres (for canopy occlusion and shadows).
        table: optional per-frame packed float32 attributes (``render.poly_table``), not carried by take/concat.
    """

    verts: np.ndarray
    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    size: np.ndarray
    albedo: np.ndarray
    material: np.ndarray
    extra: np.ndarray
    ground: np.ndarray
    table: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.verts.shape[0])

    @property
    def radius(self) -> np.ndarray:
        """(N,) largest distance from ``origin`` to a vertex, metres."""
        out = np.empty(len(self), np.float64)
        max_vertex_distance(np.ascontiguousarray(self.verts, np.float64), np.ascontiguousarray(self.origin, np.float64),
                            out)
        return out

    @staticmethod
    def empty(n_verts: int = 3) -> PolySet:
        z3 = np.zeros((0, 3))
        return PolySet(np.zeros((0, n_verts, 3)), z3, z3, z3, z3, np.zeros(0), np.zeros((0, 3), np.float32),
                       np.zeros(0, np.uint8), np.zeros(0, np.float32), np.zeros(0))

    def take(self, idx: np.ndarray) -> PolySet:
        return PolySet(self.verts[idx], self.origin[idx], self.e1[idx], self.e2[idx], self.normal[idx],
                       self.size[idx], self.albedo[idx], self.material[idx], self.extra[idx], self.ground[idx])

    @staticmethod
    def concat(sets: list[PolySet]) -> PolySet:
        sets = [s for s in sets if len(s)]
        if not sets:
            return PolySet.empty()
        v = max(s.verts.shape[1] for s in sets)
        verts = [np.concatenate([s.verts, np.repeat(s.verts[:, -1:], v - s.verts.shape[1], 1)], 1)
                 if s.verts.shape[1] < v else s.verts for s in sets]
        return PolySet(np.concatenate(verts), *(np.concatenate([getattr(s, f) for s in sets]) for f in
                                                ("origin", "e1", "e2", "normal", "size", "albedo", "material",
                                                 "extra", "ground")))


@dataclass
class PlantBlock:
    """Plants of one row block: stem base positions (n, 3) m, heights (n,) m, level-0 segment index (n,), and
    per segment (16,): tallest plant (m), mean plant x (m), plant count."""

    base: np.ndarray
    height: np.ndarray
    seg: np.ndarray
    seg_hmax: np.ndarray
    seg_x: np.ndarray
    seg_count: np.ndarray


@dataclass
class LeafBlock:
    """Leaf and weed polygons of one row block, sorted by level-0 segment: segment ``j`` (0..15) owns polygons
    ``starts[j]:starts[j+1]`` (weeds belong to the segment their base lies in)."""

    polys: PolySet
    starts: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ovate leaflet outline: (s along the midrib 0..1, half-width factor); 14 vertices counter-clockwise in (e1, e2)
_S = np.array([0.0, 0.08, 0.22, 0.42, 0.62, 0.8, 0.93])
_W = np.sin(np.pi * _S ** 0.8) ** 0.75
_OUTLINE = np.concatenate([np.stack([_S, -_W], 1), [[1.0, 0.0]], np.stack([_S[1:][::-1], _W[1:][::-1]], 1)])


def _lanceolate(n: int) -> np.ndarray:
    s = np.linspace(0, 1, n)
    w = np.sin(np.pi * s) ** 0.6
    return np.concatenate([np.stack([s, -w], 1), np.stack([s[1:-1][::-1], w[1:-1][::-1]], 1)])


_OUTLINE_WEED = _lanceolate(6)


class Field:
    """The field's rows, plants and leaves (lazy, cached, deterministic from ``seed``).

    Args:
        cfg: field parameters.
        seed: world seed.
        terrain: the ground (plants stand on it).
        cache_blocks: how many row blocks of leaves to keep in memory.
    """

    def __init__(self, cfg: FieldConfig, seed: int, terrain: Terrain, cache_blocks: int = 240) -> None:
        self.cfg = cfg
        self.seed = int(seed)
        self.terrain = terrain
        self._plants: OrderedDict[tuple[int, int], PlantBlock] = OrderedDict()
        self._leaves: OrderedDict[tuple[int, int], LeafBlock] = OrderedDict()
        self._shadow: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._cache_blocks = cache_blocks
        self.n_blocks = int(np.ceil(cfg.row_length_m / BLOCK_M))
        self.leaf_green = srgb_to_linear((66, 104, 40))
        self.sun_dir: np.ndarray | None = None  # unit vector towards the sun, set by the renderer

    # ---- layout ------------------------------------------------------------------------------------------------
    def row_x(self, i: np.ndarray | int) -> np.ndarray:
        """Centre-line x of row(s) ``i`` (a straight line per row, sown with ≈1 cm lateral error), metres."""
        i = np.asarray(i)
        return i * self.cfg.row_spacing_m + 0.01 * hash_normal(self.seed, 300, i)

    def row_factor(self, i: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Slowly varying relative canopy vigour of row ``i`` around block ``b`` (≈1 ± 0.1)."""
        return 1.0 + 0.07 * hash_normal(self.seed, 303, i, b) + 0.05 * hash_normal(self.seed, 304, i // 3, b // 3)

    def cell_gap(self, i: np.ndarray, q: np.ndarray) -> np.ndarray:
        """True where the 1 m row cell ``q`` of row ``i`` is a long gap (no plants at all)."""
        p_cell = min(0.5, self.cfg.long_gap_probability / max(self.cfg.plant_spacing_m, 1e-3))
        return hash_uniform(self.seed, 302, i, q) < p_cell

    def canopy_height(self) -> float:
        """Mean canopy top height above the ground (far LOD plane), metres."""
        return 0.82 * self.cfg.plant_height_m

    @staticmethod
    def canopy_half_width(height: np.ndarray) -> np.ndarray:
        """Half width (m) of the row canopy of a given height (young soybean: about as wide as tall)."""
        return np.clip(0.5 * height + 0.04, 0.06, 0.3)

    @property
    def row_extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the planted area, metres."""
        return (-0.3, (self.cfg.n_rows - 1) * self.cfg.row_spacing_m + 0.3, 0.0, self.cfg.row_length_m)

    # ---- plants ------------------------------------------------------------------------------------------------
    def plants(self, i: int, b: int) -> PlantBlock:
        """Plants of row ``i``, block ``b`` (cached)."""
        key = (int(i), int(b))
        hit = self._plants.get(key)
        if hit is not None:
            self._plants.move_to_end(key)
            return hit
        cfg = self.cfg
        rng = np.random.default_rng([self.seed, 310, i + 1_000_000, b + 1_000_000])
        sp = cfg.plant_spacing_m
        n = int(np.ceil(BLOCK_M / sp))
        y = b * BLOCK_M + (np.arange(n) + 0.5) * sp + rng.uniform(-0.3, 0.3, n) * sp
        keep = (rng.random(n) >= cfg.gap_probability) & (y >= 0) & (y <= cfg.row_length_m)
        keep &= (y >= b * BLOCK_M) & (y < (b + 1) * BLOCK_M)
        keep &= ~self.cell_gap(np.full(n, i), np.floor(y / SEG1_M).astype(np.int64))
        if not (0 <= i < cfg.n_rows):
            keep[:] = False
        x = self.row_x(i) + rng.normal(0, 0.012, n)
        hgt = cfg.plant_height_m * float(self.row_factor(np.int64(i), np.int64(b))) * \
            np.clip(1 + cfg.plant_height_rel_std * rng.standard_normal(n), 0.45, 1.6)
        x, y, hgt = x[keep], y[keep], hgt[keep]
        base = np.stack([x, y, self.terrain.height(x, y)], 1)
        seg = np.clip(((y - b * BLOCK_M) / SEG0_M).astype(np.int32), 0, SEGS0_PER_BLOCK - 1)
        hmax = np.zeros(SEGS0_PER_BLOCK)
        np.maximum.at(hmax, seg, hgt)
        cnt = np.bincount(seg, minlength=SEGS0_PER_BLOCK).astype(np.float64)
        xs = np.bincount(seg, weights=x, minlength=SEGS0_PER_BLOCK) / np.maximum(cnt, 1)
        out = PlantBlock(base, hgt, seg, hmax, xs, cnt)
        self._plants[key] = out
        if len(self._plants) > 8 * self._cache_blocks:
            self._plants.popitem(last=False)
        return out

    def leaves(self, i: int, b: int) -> LeafBlock:
        """Leaf and weed polygons of row ``i``, block ``b`` (weeds: the strip between rows ``i`` and ``i+1``)."""
        key = (int(i), int(b))
        hit = self._leaves.get(key)
        if hit is not None:
            self._leaves.move_to_end(key)
            return hit
        pb = self.plants(i, b)
        rng = np.random.default_rng([self.seed, 311, i + 1_000_000, b + 1_000_000])
        soy, seg = self._soy_leaves(pb, rng)
        weeds = self._weeds(i, b, rng)
        wseg = np.clip(((weeds.origin[:, 1] - b * BLOCK_M) / SEG0_M).astype(np.int64), 0, SEGS0_PER_BLOCK - 1)
        allseg = np.concatenate([seg.astype(np.int64), wseg])
        order = np.argsort(allseg, kind="stable")
        polys = PolySet.concat([soy, weeds])
        if len(polys):
            polys = polys.take(order)
        starts = np.searchsorted(allseg[order], np.arange(SEGS0_PER_BLOCK + 1))
        out = LeafBlock(polys, starts)
        self._leaves[key] = out
        if len(self._leaves) > self._cache_blocks:
            self._leaves.popitem(last=False)
        return out

    def _soy_leaves(self, pb: PlantBlock, rng: np.random.Generator) -> tuple[PolySet, np.ndarray]:
        cfg = self.cfg
        n_p = len(pb.height)
        if n_p == 0:
            return PolySet.empty(len(_OUTLINE)), np.zeros(0, np.int32)
        hrel = pb.height / cfg.plant_height_m
        t_lo, t_hi = cfg.trifoliates
        nt = np.clip(np.round(t_lo + (t_hi - t_lo) * (hrel - 0.6) / 0.8 + rng.normal(0, 0.6, n_p)), t_lo,
                     t_hi).astype(np.int64)
        pid = np.repeat(np.arange(n_p), nt)
        j = np.arange(pid.size) - np.repeat(np.cumsum(nt) - nt, nt)
        frac = (j + 1) / nt[pid]
        m = pid.size
        hp = pb.height[pid]
        z_node = hp * (0.28 + 0.6 * frac) * rng.uniform(0.92, 1.05, m)
        a0 = rng.uniform(0, 2 * np.pi, n_p)[pid]
        az = a0 + j * np.radians(rng.uniform(120, 150, m)) + rng.normal(0, 0.35, m)
        lp = hp * rng.uniform(0.22, 0.5, m) * (1.15 - 0.55 * frac)
        rise = lp * rng.uniform(0.15, 0.6, m)
        centre = pb.base[pid] + np.stack([lp * np.cos(az), lp * np.sin(az), z_node + rise], 1)
        sf = np.sqrt(hrel[pid]) * (0.8 + 0.35 * (1 - frac)) * rng.uniform(0.85, 1.15, m)
        # three leaflets per trifoliate
        k = np.tile(np.arange(3), m)
        tri = np.repeat(np.arange(m), 3)
        side = np.array([0.0, 1.0, -1.0])[k]
        beta = az[tri] + side * np.radians(rng.uniform(55, 85, 3 * m))
        length = cfg.leaflet_length_m * sf[tri] * np.where(k == 0, 1.1, 0.9)
        width = length * rng.uniform(0.5, 0.66, 3 * m)
        gamma = rng.normal(-0.05, 0.28, 3 * m)
        rho = rng.normal(0, 0.4, 3 * m)
        e1 = np.stack([np.cos(gamma) * np.cos(beta), np.cos(gamma) * np.sin(beta), np.sin(gamma)], 1)
        h = np.stack([-np.sin(beta), np.cos(beta), np.zeros_like(beta)], 1)
        e2 = h * np.cos(rho)[:, None] + np.cross(e1, h) * np.sin(rho)[:, None]
        normal = np.cross(e1, e2)
        offs = np.where(k == 0, 0.015, 0.004)
        origin = centre[tri] + offs[:, None] * np.stack([np.cos(beta), np.sin(beta), np.zeros_like(beta)], 1)
        verts = (origin[:, None, :] + _OUTLINE[None, :, 0:1] * length[:, None, None] * e1[:, None, :]
                 + _OUTLINE[None, :, 1:2] * (0.5 * width)[:, None, None] * e2[:, None, :])
        # colour: per-plant hue/brightness, lower leaves darker, a few yellowing, young top leaves lighter
        plant_tint = rng.uniform(0.85, 1.15, (n_p, 1)) * np.array([1.0, 1.0, 1.0]) + \
            rng.normal(0, 0.06, (n_p, 3)) * np.array([1.0, 0.4, 1.0])
        fr = frac[tri]
        albedo = self.leaf_green[None] * plant_tint[pid[tri]] * rng.uniform(0.9, 1.1, (3 * m, 1)) * \
            (0.82 + 0.3 * fr)[:, None]
        yellow = rng.random(3 * m) < 0.035 * (1.5 - fr)
        albedo[yellow] = albedo[yellow] * 0.4 + srgb_to_linear((150, 146, 62))[None] * 0.6
        polys = PolySet(verts, origin, e1, e2, normal, length, albedo.astype(np.float32),
                        np.full(3 * m, MAT_LEAF, np.uint8), rng.random(3 * m).astype(np.float32),
                        pb.base[pid[tri], 2])
        return polys, pb.seg[pid[tri]].astype(np.int32)

    def _weeds(self, i: int, b: int, rng: np.random.Generator) -> PolySet:
        cfg = self.cfg
        if not (0 <= i < cfg.n_rows - 1) or cfg.weeds_per_m2 <= 0:
            return PolySet.empty(len(_OUTLINE_WEED))
        n_w = rng.poisson(cfg.weeds_per_m2 * cfg.row_spacing_m * BLOCK_M)
        if n_w == 0:
            return PolySet.empty(len(_OUTLINE_WEED))
        x0 = float(self.row_x(i))
        cx = x0 + rng.uniform(0.12, cfg.row_spacing_m - 0.12, n_w)
        cy = b * BLOCK_M + rng.uniform(0, BLOCK_M, n_w)
        inside = (cy >= 0) & (cy <= cfg.row_length_m)
        grassy = rng.random(n_w) < 0.35
        nl = rng.integers(4, 9, n_w)
        wid = np.repeat(np.arange(n_w), nl)
        m = wid.size
        jj = np.arange(m) - np.repeat(np.cumsum(nl) - nl, nl)
        az = rng.uniform(0, 2 * np.pi, n_w)[wid] + 2 * np.pi * jj / nl[wid] + rng.normal(0, 0.3, m)
        g = grassy[wid]
        length = np.where(g, rng.uniform(0.06, 0.16, m), rng.uniform(0.02, 0.06, m))
        width = length * np.where(g, rng.uniform(0.06, 0.12, m), rng.uniform(0.2, 0.4, m))
        pitch = np.where(g, rng.uniform(0.5, 1.2, m), rng.uniform(0.1, 0.5, m))
        e1 = np.stack([np.cos(pitch) * np.cos(az), np.cos(pitch) * np.sin(az), np.sin(pitch)], 1)
        e2 = np.stack([-np.sin(az), np.cos(az), np.zeros(m)], 1)
        normal = np.cross(e1, e2)
        base = np.stack([cx[wid], cy[wid], self.terrain.height(cx[wid], cy[wid]) + 0.004], 1)
        verts = (base[:, None, :] + _OUTLINE_WEED[None, :, 0:1] * length[:, None, None] * e1[:, None, :]
                 + _OUTLINE_WEED[None, :, 1:2] * (0.5 * width)[:, None, None] * e2[:, None, :])
        col = np.where(g[:, None], srgb_to_linear((104, 128, 66))[None], srgb_to_linear((92, 136, 58))[None])
        col = col * rng.uniform(0.8, 1.2, (m, 1))
        keep = inside[wid]
        ps = PolySet(verts, base, e1, e2, normal, length, col.astype(np.float32), np.full(m, MAT_WEED, np.uint8),
                     rng.random(m).astype(np.float32), base[:, 2] - 0.004)
        return ps.take(np.flatnonzero(keep))

    # ---- level of detail -----------------------------------------------------------------------------------------
    def select(self, cam_xy: np.ndarray, fwd_xy: np.ndarray, leaf_range: float, half_fov: float) -> tuple[
            PolySet, PolySet]:
        """Polygons to draw for a camera at ``cam_xy`` looking along ``fwd_xy`` (horizontal unit vector).

        Returns:
            ``(leaves, prisms)``: leaf/weed polygons of the near row segments and canopy prism faces of the
            farther ones (the canopy plane beyond ``PRISM1_RANGE_M`` is the renderer's).
        """
        cfg = self.cfg
        s = cfg.row_spacing_m
        r_max = PRISM1_RANGE_M + BLOCK_M
        i_lo = max(0, int(np.floor((cam_xy[0] - r_max) / s)))
        i_hi = min(cfg.n_rows - 1, int(np.ceil((cam_xy[0] + r_max) / s)))
        b_lo = max(0, int(np.floor((cam_xy[1] - r_max) / BLOCK_M)))
        b_hi = min(self.n_blocks - 1, int(np.floor((cam_xy[1] + r_max) / BLOCK_M)))
        if i_hi < i_lo or b_hi < b_lo:
            return PolySet.empty(), PolySet.empty()
        ii, bb = np.meshgrid(np.arange(i_lo, i_hi + 1), np.arange(b_lo, b_hi + 1), indexing="ij")
        ii, bb = ii.ravel(), bb.ravel()

        def visible(cx: np.ndarray, cy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
            dx, dy = cx - cam_xy[0], cy - cam_xy[1]
            d = np.hypot(dx, dy)
            cosang = (dx * fwd_xy[0] + dy * fwd_xy[1]) / np.maximum(d, 1e-6)
            ang = np.arccos(np.clip(cosang, -1, 1))
            ok = (d <= radius + 0.5) | (ang <= half_fov + np.arcsin(np.clip(radius / np.maximum(d, 1e-6), 0, 1)))
            return ok, d

        # level 1 (1 m) cells of the candidate blocks
        ii1 = np.repeat(ii, 4)
        qq1 = np.repeat(bb, 4) * 4 + np.tile(np.arange(4), len(bb))
        cy1 = (qq1 + 0.5) * SEG1_M
        ok1, d1 = visible(self.row_x(ii1), cy1, 0.8)
        ok1 &= (d1 <= PRISM1_RANGE_M) & (cy1 <= cfg.row_length_m + SEG1_M)
        far1 = ok1 & (d1 >= PRISM0_RANGE_M) & ~self.cell_gap(ii1, qq1)
        prisms = [self._prisms_coarse(ii1[far1], qq1[far1])]
        near1 = ok1 & (d1 < PRISM0_RANGE_M)
        # level 0 (0.25 m) segments of near cells
        ii0 = np.repeat(ii1[near1], 4)
        ss0 = np.repeat(qq1[near1], 4) * 4 + np.tile(np.arange(4), int(near1.sum()))
        ok0, d0 = visible(self.row_x(ii0), (ss0 + 0.5) * SEG0_M, 0.35)
        leaf_seg = ok0 & (d0 < leaf_range)
        prism_seg = ok0 & (d0 >= leaf_range)
        # group by block
        leaves = []
        blocks0 = ss0 // SEGS0_PER_BLOCK
        groups: dict[tuple[int, int], list[int]] = {}
        for i, b, sg in zip(ii0[leaf_seg].tolist(), blocks0[leaf_seg].tolist(), ss0[leaf_seg].tolist()):
            groups.setdefault((i, b), []).append(sg - b * SEGS0_PER_BLOCK)
        for (i, b) in sorted(groups):
            lb = self.leaves(i, b)
            if not len(lb.polys):
                continue
            segs = sorted(groups[(i, b)])
            if len(segs) == SEGS0_PER_BLOCK:
                leaves.append(lb.polys)
                continue
            idx = np.concatenate([np.arange(lb.starts[j], lb.starts[j + 1]) for j in segs])
            if idx.size:
                leaves.append(lb.polys.take(idx))
        # fine prisms: per-segment summaries of the plants they stand for, then one batch of faces
        xs, y0s, hs = [], [], []
        pi, pb_, ps = ii0[prism_seg], blocks0[prism_seg], ss0[prism_seg]
        order = np.lexsort((ps, pb_, pi))
        pi, pb_, ps = pi[order], pb_[order], ps[order]
        if pi.size:
            cut = np.flatnonzero((np.diff(pi) != 0) | (np.diff(pb_) != 0)) + 1
            for lo, hi in zip(np.concatenate([[0], cut]), np.concatenate([cut, [pi.size]])):
                i, b = int(pi[lo]), int(pb_[lo])
                plants = self.plants(i, b)
                segs = ps[lo:hi] - b * SEGS0_PER_BLOCK
                segs = segs[plants.seg_count[segs] > 0]
                xs.append(plants.seg_x[segs])
                y0s.append(b * BLOCK_M + segs * SEG0_M)
                hs.append(0.92 * plants.seg_hmax[segs])
        if xs:
            y0 = np.concatenate(y0s)
            prisms.append(self._prism_faces(np.concatenate(xs), y0, y0 + SEG0_M, np.concatenate(hs), caps=True))
        return PolySet.concat(leaves), PolySet.concat(prisms)

    def _prism_faces(self, xc: np.ndarray, y0: np.ndarray, y1: np.ndarray, height: np.ndarray,
                     caps: bool) -> PolySet:
        """Faces (two roof quads, optional end triangles) of prisms along rows; back faces culled later."""
        n = xc.size
        if n == 0:
            return PolySet.empty(4)
        yc = 0.5 * (y0 + y1)
        zb = self.terrain.height(xc, yc) - 0.03
        zr = zb + 0.03 + height
        w = self.canopy_half_width(height)
        ridge0 = np.stack([xc, y0, zr], 1)
        ridge1 = np.stack([xc, y1, zr], 1)
        left0 = np.stack([xc - w, y0, zb], 1)
        left1 = np.stack([xc - w, y1, zb], 1)
        right0 = np.stack([xc + w, y0, zb], 1)
        right1 = np.stack([xc + w, y1, zb], 1)
        faces = [np.stack([ridge0, ridge1, left1, left0], 1), np.stack([ridge1, ridge0, right0, right1], 1)]
        origins = [ridge0, ridge0]
        ey = np.tile([0.0, 1.0, 0.0], (n, 1))
        down_l = _unit(left0 - ridge0)
        down_r = _unit(right0 - ridge0)
        e1s = [ey, ey]
        e2s = [down_l, down_r]
        if caps:
            faces += [np.stack([left0, ridge0, right0, right0], 1), np.stack([right1, ridge1, left1, left1], 1)]
            origins += [ridge0, ridge1]
            ex = np.tile([1.0, 0.0, 0.0], (n, 1))
            ez = np.tile([0.0, 0.0, -1.0], (n, 1))
            e1s += [ex, -ex]
            e2s += [ez, ez]
        verts = np.concatenate(faces)
        e1 = np.concatenate(e1s)
        e2 = np.concatenate(e2s)
        normal = _unit(np.cross(e1, e2))
        # orient normals outwards (away from the prism's axis)
        centre = np.tile(np.stack([xc, yc, zb + 0.3 * (zr - zb)], 1), (len(faces), 1))
        face_c = verts.mean(1)
        flip = np.einsum("ij,ij->i", normal, face_c - centre) < 0
        normal[flip] *= -1
        e2[flip] *= -1
        k = len(faces)
        var = hash_uniform(self.seed, 320, np.round(xc * 100).astype(np.int64), np.round(y0 * 100).astype(np.int64))
        shade = (0.85 + 0.3 * var)[:, None] * self.leaf_green[None]
        return PolySet(verts, np.concatenate(origins), e1, e2, normal, np.ones(k * n),
                       np.tile(shade, (k, 1)).astype(np.float32), np.full(k * n, MAT_CANOPY, np.uint8),
                       np.tile(var, k).astype(np.float32), np.tile(zb + 0.03, k))

    def _prisms_coarse(self, ii: np.ndarray, qq: np.ndarray) -> PolySet:
        if not ii.size:
            return PolySet.empty(4)
        h = self.canopy_height() * 1.05 * self.row_factor(ii, qq // 4)
        y0 = qq * SEG1_M
        y1 = np.minimum(y0 + SEG1_M, self.cfg.row_length_m)
        return self._prism_faces(self.row_x(ii), y0, y1, h, caps=False)

    # ---- shadows -------------------------------------------------------------------------------------------------
    def shadow_tile(self, tx: int, ty: int) -> np.ndarray:
        """Max occluder height map (float32, metres; ``SHADOW_NONE`` where free) of one 2 m × 2 m ground tile.

        Each texel holds the height of the highest leaf whose sun-ray shadow falls there (leaves projected along
        the sun direction onto the ground). Requires ``sun_dir`` (set by the renderer).
        """
        key = (int(tx), int(ty))
        hit = self._shadow.get(key)
        if hit is not None:
            self._shadow.move_to_end(key)
            return hit
        assert self.sun_dir is not None
        n = int(round(SHADOW_TILE_M / SHADOW_TEXEL_M))
        out = np.full((n, n), SHADOW_NONE, np.float32)
        disp = -self.sun_dir[:2] / max(self.sun_dir[2], 0.05)  # ground displacement per metre of height
        hmax = 1.7 * self.cfg.plant_height_m + 0.1
        x0, y0 = tx * SHADOW_TILE_M, ty * SHADOW_TILE_M
        # source region: the tile moved back towards the sun by up to hmax of height, plus the canopy half width
        xs = (x0 - max(0.0, disp[0] * hmax) - 0.35, x0 + SHADOW_TILE_M - min(0.0, disp[0] * hmax) + 0.35)
        ys = (y0 - max(0.0, disp[1] * hmax) - 0.35, y0 + SHADOW_TILE_M - min(0.0, disp[1] * hmax) + 0.35)
        s = self.cfg.row_spacing_m
        rows = range(max(0, int(np.floor(xs[0] / s))), min(self.cfg.n_rows - 1, int(np.ceil(xs[1] / s))) + 1)
        blocks = range(max(0, int(np.floor(ys[0] / BLOCK_M))), min(self.n_blocks - 1, int(np.floor(ys[1] / BLOCK_M)))
                       + 1)
        sets = [self.leaves(i, b).polys for i in rows for b in blocks]
        ps = PolySet.concat(sets)
        if len(ps):
            gz = self.terrain.height(ps.origin[:, 0], ps.origin[:, 1])
            hz = ps.verts[..., 2] - gz[:, None]
            q = ps.verts[..., :2] + hz[..., None] * disp[None, None, :]
            px = (q - np.array([x0, y0])) / SHADOW_TEXEL_M
            inside = (px.max(1) >= 0).all(1) & (px.min(1) < n).all(1)
            order = np.argsort(ps.origin[:, 2], kind="stable")  # higher leaves drawn last: the max height wins
            ids = np.zeros((n, n), np.int32)
            # texel (i, j) is centred at ((j, i) + 0.5) texels: the raster samples integer coordinates
            raster_polygons(np.clip(px - 0.5, -1e4, 1e4).astype(np.float64), order[inside[order]], ids)
            out = np.where(ids > 0, ps.origin[np.maximum(ids - 1, 0), 2], SHADOW_NONE).astype(np.float32)
        self._shadow[key] = out
        if len(self._shadow) > 160:
            self._shadow.popitem(last=False)
        return out
