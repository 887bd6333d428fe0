"""Does the χ² gate keep bad depths out? Its verdicts on features whose depth errors are known (oracle runs).

The gate's noise scale c (:mod:`eval.gate_calibration`) says whether the residual covariance is right; this module
says whether the gate *works*: of the features that reach it carrying a bad depth reading — off by at least ``bad_px``
of disparity *and* by more than ``cover_sigmas`` of the σ the filter was given for it (a reading whose stated σ covers
its error is harmless by design: the update weighs it by that σ) — how many get that reading into the update, and of
the features whose every reading is within ``good_px``, how many it throws away. Bad readings whose σ covers them
are counted separately (``gate_flagged_depth_*``). It needs the true depth of the tracked points, so only the depth
oracle (:mod:`pipeline.depth_oracle`) feeds it.

Per frame, :meth:`GatePower.add_readings` records the disparity error ``Δd = f·B · |1/Z − 1/Z_true|`` (px) of each
depth reading the back end was given (NaN where the reading has no truth), its stated σ in disparity px
(``f·B · σ_Z / Z²``; NaN where none was stated) and whether it was a fill. After the
back end has processed the frame, :meth:`GatePower.add_verdicts` takes the gate's verdicts (``msckf.filter.FrameStats.
gate_ids`` / ``gate_verdict``) and the time of the oldest clone in the window: a feature's readings are those of its
track since then. What the gate was offered follows the filter's own rules: with ``fills_only_unmeasured`` a track
with a measured reading in the window offers its measured readings only (``DepthOptions.depth_fills_only_unmeasured``);
a feature accepted by the depth fallback (verdict 2) enters without its filled readings (without any with
``fallback_measured``).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

__all__ = ["GatePower", "BAD_DEPTH_PX", "GOOD_DEPTH_PX", "COVER_SIGMAS"]

#: A depth reading off by at least this much disparity (px) is bad (issue 17: such fills passed the gate 85–95 %).
BAD_DEPTH_PX = 5.0
#: A feature whose every reading is within this much disparity (px) is good (≈ 4.6 σ of raw SGBM, 0.545 px).
GOOD_DEPTH_PX = 2.5
#: A bad reading whose error is within this many of its stated σ is flagged (the filter was told), not bad.
COVER_SIGMAS = 3.0


@dataclass
class GatePower:
    """Counts, over one run, the gate's verdicts on features with bad and with good depth readings.

    Attributes:
        fills_only_unmeasured, fallback_measured: the filter's ``depth.depth_fills_only_unmeasured`` and
            ``update.depth_fallback_measured`` (which readings a feature offers, which the fallback drops).
        bad_px, good_px: thresholds on the disparity error, px. cover_sigmas: a bad reading within this many of
            its stated σ is flagged, not bad.
    """

    fills_only_unmeasured: bool = True
    fallback_measured: bool = False
    bad_px: float = BAD_DEPTH_PX
    good_px: float = GOOD_DEPTH_PX
    cover_sigmas: float = COVER_SIGMAS
    n_bad: int = 0
    n_bad_passed: int = 0
    n_flagged: int = 0
    n_flagged_passed: int = 0
    n_good: int = 0
    n_good_rejected: int = 0
    # track id → [(stamp s, |Δd| px, stated σ_d px, filled)]
    _readings: dict[int, list[tuple[float, float, float, bool]]] = field(default_factory=lambda: defaultdict(list))

    def add_readings(self, stamp_s: float, ids: np.ndarray, disparity_error_px: np.ndarray, sigma_px: np.ndarray,
                     filled: np.ndarray) -> None:
        """One frame's depth readings: ids (N,) of the features given a depth, their |Δd| (N,) px (NaN: no
        truth), their stated σ in disparity px (N,) (NaN: none stated) and whether each is a fill (N,)."""
        columns = (np.asarray(ids).tolist(), np.asarray(disparity_error_px, dtype=np.float64).tolist(),
                   np.asarray(sigma_px, dtype=np.float64).tolist(), np.asarray(filled, dtype=bool).tolist())
        for i, dd, sd, f in zip(*columns):
            self._readings[int(i)].append((float(stamp_s), dd, sd, f))

    def _kind(self, dd: float, sd: float) -> str | None:
        """``"bad"`` (≥ ``bad_px`` and not covered by ``cover_sigmas`` of its σ), ``"flagged"`` (≥ ``bad_px``,
        covered) or None."""
        if not (np.isfinite(dd) and dd >= self.bad_px):
            return None
        return "flagged" if np.isfinite(sd) and dd <= self.cover_sigmas * sd else "bad"

    def add_verdicts(self, window_start_s: float, now_s: float, ids: np.ndarray, verdicts: np.ndarray) -> None:
        """The gate's verdicts (0 rejected, 1 accepted, 2 accepted without fills) on features ``ids``, whose
        readings are those stamped within [``window_start_s``, ``now_s``]."""
        for i, v in zip(np.asarray(ids).tolist(), np.asarray(verdicts).tolist()):
            rs = [r for r in self._readings.get(int(i), ()) if window_start_s <= r[0] <= now_s]
            if self.fills_only_unmeasured and any(not r[3] for r in rs):
                rs = [r for r in rs if not r[3]]
            known = [r[1] for r in rs if np.isfinite(r[1])]
            if not known:
                continue
            offered = {self._kind(r[1], r[2]) for r in rs}
            entered = {self._kind(r[1], r[2]) for r in rs
                       if v == 1 or (v == 2 and not r[3] and not self.fallback_measured)}
            if "bad" in offered:
                self.n_bad += 1
                self.n_bad_passed += "bad" in entered
            elif "flagged" in offered:
                self.n_flagged += 1
                self.n_flagged_passed += "flagged" in entered
            elif max(known) < self.good_px:
                self.n_good += 1
                self.n_good_rejected += v == 0

    def forget_before(self, t_s: float) -> None:
        """Drop readings older than ``t_s`` (they can no longer be in a window); keeps memory bounded."""
        for i in list(self._readings):
            rs = [r for r in self._readings[i] if r[0] >= t_s]
            if rs:
                self._readings[i] = rs
            else:
                del self._readings[i]

    def stats(self) -> dict[str, float]:
        """``gate_bad_depth_features`` / ``gate_bad_depth_passed`` (fraction of them whose bad reading entered the
        update; NaN when none), ``gate_flagged_depth_features`` / ``gate_flagged_depth_passed`` (bad readings whose
        stated σ covers them, a feature with both counting as bad) and ``gate_good_depth_features`` /
        ``gate_good_depth_rejected``."""
        return {"gate_bad_depth_features": float(self.n_bad),
                "gate_bad_depth_passed": self.n_bad_passed / self.n_bad if self.n_bad else float("nan"),
                "gate_flagged_depth_features": float(self.n_flagged),
                "gate_flagged_depth_passed": self.n_flagged_passed / self.n_flagged if self.n_flagged else float("nan"),
                "gate_good_depth_features": float(self.n_good),
                "gate_good_depth_rejected": self.n_good_rejected / self.n_good if self.n_good else float("nan")}
