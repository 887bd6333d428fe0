"""Turns of a reference trajectory, found from its positions alone (Rosario's GT has no orientation).

The heading is the direction of the chord over ``chord_m`` metres of path (so GPS jitter and standing still do
not make a turn); a turn is where the heading changes faster than ``1 / max_radius_m`` rad per metre of path, kept
when it turns by at least ``min_angle_deg`` in total (a headland U-turn: 180°, a loop's corner: 90°; steering
wander along a row: a few degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eval.trajectory import Trajectory

__all__ = ["Turn", "find_turns"]


@dataclass(frozen=True)
class Turn:
    """One turn: ``start_s``/``end_s`` (trajectory stamps, seconds) and the signed heading change (degrees, left +)."""

    start_s: float
    end_s: float
    angle_deg: float


def find_turns(ref: Trajectory, chord_m: float = 1.0, max_radius_m: float = 8.0, min_angle_deg: float = 45.0,
               step_m: float = 0.1) -> list[Turn]:
    """The turns of ``ref`` in time order (see the module docstring); [] for a path shorter than two chords.

    Args:
        ref: reference trajectory (positions in a world frame with z up; only x and y are used).
        chord_m: heading baseline, metres of path.
        max_radius_m: curvature threshold: turning radius below this counts as turning, metres.
        min_angle_deg: smallest total heading change of a kept turn, degrees.
        step_m: path resampling step, metres.
    """
    if len(ref) < 3:
        return []
    xy = ref.positions[:, :2]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    if s[-1] < 2 * chord_m:
        return []
    # resample by arc length (strictly increasing s only: standing still adds no path)
    keep = np.concatenate([[True], np.diff(s) > 1e-9])
    s_k, xy_k, t_k = s[keep], xy[keep], ref.stamps_s[keep]
    grid = np.arange(0.0, s_k[-1], step_m)
    gx, gy = np.interp(grid, s_k, xy_k[:, 0]), np.interp(grid, s_k, xy_k[:, 1])
    half = max(1, int(round(0.5 * chord_m / step_m)))
    if grid.size <= 2 * half + 1:
        return []
    heading = np.unwrap(np.arctan2(gy[2 * half:] - gy[:-2 * half], gx[2 * half:] - gx[:-2 * half]))
    mid = grid[half:-half]
    rate = np.gradient(heading, mid)  # rad per metre of path
    turning = np.abs(rate) > 1.0 / max_radius_m
    turns: list[Turn] = []
    edges = np.diff(np.concatenate([[0], turning.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        angle = float(np.degrees(heading[b - 1] - heading[a]))
        if abs(angle) >= min_angle_deg:
            t0, t1 = np.interp([mid[a], mid[b - 1]], s_k, t_k)
            turns.append(Turn(float(t0), float(t1), angle))
    return turns
