"""Filter state: the IMU state, the camera clones and the error-state covariance.

Error-state layout (S-MSCKF, msckf.md §1.1), all in the conventions of :mod:`msckf.rotation`:

=========  ======  =====================================================================
index      size    meaning
=========  ======  =====================================================================
0:3        3       δθ    IMU orientation (local, IMU frame), rad
3:6        3       δb_g  gyro bias, rad/s
6:9        3       δv    velocity (world), m/s
9:12       3       δb_a  accelerometer bias, m/s²
12:15      3       δp    IMU position (world), m
15:18      3       δθ_e  cam0–IMU extrinsic rotation (local, cam0 frame), rad
18:21      3       δp_e  cam0 origin in the IMU frame, m
21+6k      6       clone k (oldest first): [δθ_c (cam0 frame), δp_c (world)]
=========  ======  =====================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from msckf.options import InitOptions

IMU_DIM = 21
CLONE_DIM = 6
TH, BG, VEL, BA, POS, EXT_R, EXT_P = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                                      slice(15, 18), slice(18, 21))


@dataclass
class ImuState:
    """Nominal IMU state (mutable, internal to the filter).

    Attributes:
        time: seconds of the last propagation.
        R_w_i: (3, 3) IMU → world rotation. p: (3,) IMU position in world, m. v: (3,) world velocity, m/s.
        b_g: (3,) gyro bias, rad/s. b_a: (3,) accelerometer bias, m/s².
        R_c_i: (3, 3) IMU → cam0 rotation (extrinsic). p_i_c: (3,) cam0 origin in the IMU frame, m.
        R_w_i_null, p_null, v_null: OC-EKF first-estimate copies (values at the end of the last propagation).
        id: id of the IMU state (increments at each image), used as clone id.
    """

    time: float
    R_w_i: np.ndarray
    p: np.ndarray
    v: np.ndarray
    b_g: np.ndarray
    b_a: np.ndarray
    R_c_i: np.ndarray
    p_i_c: np.ndarray
    R_w_i_null: np.ndarray = field(default=None)  # type: ignore[arg-type]
    p_null: np.ndarray = field(default=None)  # type: ignore[arg-type]
    v_null: np.ndarray = field(default=None)  # type: ignore[arg-type]
    id: int = 0

    def __post_init__(self) -> None:
        if self.R_w_i_null is None:
            self.R_w_i_null = self.R_w_i.copy()
        if self.p_null is None:
            self.p_null = self.p.copy()
        if self.v_null is None:
            self.v_null = self.v.copy()


class CloneStore:
    """Camera clones in a fixed pool of slots (so feature observations can be indexed by slot).

    ``order`` lists the occupied slots oldest first; the covariance block of ``order[k]`` starts at
    ``21 + 6k``. Per slot: ``R_w_c`` (cam0 → world), ``p`` (cam0 position, world, m), the OC first-estimate
    ``R_c_w_null`` / ``p_null``, the IMU-state id and time.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.R_w_c = np.tile(np.eye(3), (capacity, 1, 1))
        self.p = np.zeros((capacity, 3))
        self.R_c_w_null = np.tile(np.eye(3), (capacity, 1, 1))
        self.p_null = np.zeros((capacity, 3))
        self.ids = np.full(capacity, -1, dtype=np.int64)
        self.times = np.zeros(capacity)
        self.order: list[int] = []

    def __len__(self) -> int:
        return len(self.order)

    def add(self, clone_id: int, time: float, R_w_c: np.ndarray, p: np.ndarray) -> int:
        """Occupy a free slot with a new (newest) clone; returns the slot."""
        used = set(self.order)
        slot = next(s for s in range(self.capacity) if s not in used)
        self.R_w_c[slot] = R_w_c
        self.p[slot] = p
        self.R_c_w_null[slot] = R_w_c.T
        self.p_null[slot] = p
        self.ids[slot] = clone_id
        self.times[slot] = time
        self.order.append(slot)
        return slot

    def remove(self, slots: list[int]) -> None:
        for s in slots:
            self.order.remove(s)
            self.ids[s] = -1

    def clear(self) -> None:
        self.order = []
        self.ids[:] = -1

    def position_in_order(self, slots: np.ndarray) -> np.ndarray:
        """Order positions (0 = oldest) of the given occupied slots."""
        lut = np.full(self.capacity, -1, dtype=np.int64)
        lut[np.asarray(self.order, dtype=np.int64)] = np.arange(len(self.order))
        return lut[slots]


class FeatureStore:
    """Tracked features in a growable pool of rows; observations indexed by clone slot.

    Per row: the track id, ``alive``, ``obs`` (capacity_slots, 4) normalised ``(u0, v0, u1, v1)`` with NaN
    cam1 where monocular, ``depth`` (slots,) measured Z in cam0 (NaN where none), ``depth_sigma`` (slots,) its σ in
    metres (NaN: the configured depth noise model applies), ``depth_filled`` (slots,) bool, True where that depth
    is not known to be a direct measurement (a fill, or unknown), ``has`` (slots,) bool,
    ``src`` (slots,) :class:`~msckf.types.DepthSource` of each observation,
    ``initialized`` and the triangulated world position ``pos`` (m).
    Active ids are kept sorted (``_ids_sorted`` / ``_rows_sorted``) for vectorised id → row look-ups.
    """

    def __init__(self, n_slots: int, capacity: int = 1024) -> None:
        self.n_slots = n_slots
        self._alloc(capacity)
        self._ids_sorted = np.zeros(0, dtype=np.int64)
        self._rows_sorted = np.zeros(0, dtype=np.int64)
        self._free = list(range(capacity - 1, -1, -1))

    def _alloc(self, capacity: int) -> None:
        self.capacity = capacity
        self.ids = np.full(capacity, -1, dtype=np.int64)
        self.alive = np.zeros(capacity, dtype=bool)
        self.obs = np.full((capacity, self.n_slots, 4), np.nan)
        self.depth = np.full((capacity, self.n_slots), np.nan)
        self.depth_sigma = np.full((capacity, self.n_slots), np.nan)
        self.depth_filled = np.zeros((capacity, self.n_slots), dtype=bool)
        self.has = np.zeros((capacity, self.n_slots), dtype=bool)
        self.src = np.zeros((capacity, self.n_slots), dtype=np.uint8)
        self.initialized = np.zeros(capacity, dtype=bool)
        self.pos = np.zeros((capacity, 3))

    #: the per-row arrays that :meth:`_alloc` creates (all grow together)
    _ROW_ARRAYS = ("ids", "alive", "obs", "depth", "depth_sigma", "depth_filled", "has", "src", "initialized", "pos")

    def _grow(self, need: int) -> None:
        old = self.capacity
        new = max(2 * old, old + need)
        before = [getattr(self, name) for name in self._ROW_ARRAYS]
        self._alloc(new)
        for name, src in zip(self._ROW_ARRAYS, before):
            getattr(self, name)[:old] = src
        self._free = list(range(new - 1, old - 1, -1)) + self._free

    @property
    def n_alive(self) -> int:
        return len(self._ids_sorted)

    def lookup(self, ids: np.ndarray) -> np.ndarray:
        """Rows of the given track ids; −1 for ids not in the store."""
        if len(self._ids_sorted) == 0:
            return np.full(len(ids), -1, dtype=np.int64)
        pos = np.searchsorted(self._ids_sorted, ids)
        pos_c = np.minimum(pos, len(self._ids_sorted) - 1)
        found = self._ids_sorted[pos_c] == ids
        return np.where(found, self._rows_sorted[pos_c], -1)

    def add(self, ids: np.ndarray) -> np.ndarray:
        """Create rows for new track ids; returns their rows."""
        n = len(ids)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        if n > len(self._free):
            self._grow(n - len(self._free))
        rows = np.array([self._free.pop() for _ in range(n)], dtype=np.int64)
        self.ids[rows] = ids
        self.alive[rows] = True
        self.obs[rows] = np.nan
        self.depth[rows] = np.nan
        self.depth_sigma[rows] = np.nan
        self.depth_filled[rows] = False
        self.has[rows] = False
        self.initialized[rows] = False
        all_ids = np.concatenate([self._ids_sorted, ids])
        all_rows = np.concatenate([self._rows_sorted, rows])
        o = np.argsort(all_ids, kind="stable")
        self._ids_sorted, self._rows_sorted = all_ids[o], all_rows[o]
        return rows

    def remove(self, rows: np.ndarray) -> None:
        rows = np.asarray(rows, dtype=np.int64)
        if len(rows) == 0:
            return
        self.alive[rows] = False
        self.has[rows] = False
        self.ids[rows] = -1
        self._free.extend(rows.tolist())
        keep = self.alive[self._rows_sorted]
        self._ids_sorted, self._rows_sorted = self._ids_sorted[keep], self._rows_sorted[keep]

    def clear(self) -> None:
        self.remove(self._rows_sorted.copy())

    def alive_rows(self) -> np.ndarray:
        """Rows of all live features, in id order."""
        return self._rows_sorted.copy()


def initial_covariance(options: InitOptions) -> np.ndarray:
    """The 21×21 initial (and reset) covariance of S-MSCKF: zero for θ and p (they define the world frame); the
    variances of v, b_g, b_a and the extrinsics are ``options.velocity_cov`` … ``extrinsic_translation_cov``."""
    P = np.zeros((IMU_DIM, IMU_DIM))
    d = np.zeros(IMU_DIM)
    d[BG] = options.gyro_bias_cov
    d[VEL] = options.velocity_cov
    d[BA] = options.acc_bias_cov
    d[EXT_R] = options.extrinsic_rotation_cov
    d[EXT_P] = options.extrinsic_translation_cov
    P[np.diag_indices(IMU_DIM)] = d
    return P
