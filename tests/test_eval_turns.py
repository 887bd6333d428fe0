"""Turns found from positions only: a headland U-turn and a loop corner, not GPS jitter or standing still."""

from __future__ import annotations

import numpy as np

from eval.trajectory import Trajectory
from eval.turns import find_turns


def _path(points: np.ndarray, speed: float = 0.8, noise_m: float = 0.0, still_s: float = 0.0) -> Trajectory:
    points = points[np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-6])]
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    t = np.concatenate([[0.0], np.cumsum(seg / speed)]) + still_s
    if still_s:  # standing still at the start, sampled at 5 Hz
        t = np.concatenate([np.arange(0.0, still_s, 0.2), t])
        points = np.concatenate([np.repeat(points[:1], t.size - len(points), axis=0), points])
    rng = np.random.default_rng(0)
    xyz = np.column_stack([points, np.zeros(len(points))]) + noise_m * rng.standard_normal((len(points), 3))
    return Trajectory(t, xyz, np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)), has_orientation=False)


def _u_turn_route(radius: float = 2.6, leg: float = 20.0, ds: float = 0.16) -> np.ndarray:
    up = np.column_stack([np.zeros(int(leg / ds)), np.arange(0.0, leg, ds)])
    a = np.linspace(np.pi, 0.0, int(np.pi * radius / ds))  # centre (radius, leg), from x=0 to x=2·radius
    arc = np.column_stack([radius + radius * np.cos(a), leg + radius * np.sin(a)])
    down = np.column_stack([np.full(int(leg / ds), 2 * radius), leg - np.arange(0.0, leg, ds)])
    return np.concatenate([up, arc, down])


def test_one_u_turn_found_with_its_angle_and_time() -> None:
    ref = _path(_u_turn_route(), noise_m=0.01, still_s=3.0)  # 1 cm GPS-like jitter, standing still first
    turns = find_turns(ref)
    assert len(turns) == 1
    turn = turns[0]
    assert abs(abs(turn.angle_deg) - 180.0) < 15.0
    # the arc is driven from 3 s + 20 m / 0.8 m/s = 28 s for π·2.6 m / 0.8 m/s ≈ 10.2 s
    assert 26.0 < turn.start_s < 30.0 and 36.0 < turn.end_s < 40.0
    assert turn.angle_deg < 0  # a right turn (heading +y → −y through +x)


def test_straight_row_with_wander_has_no_turn() -> None:
    y = np.arange(0.0, 60.0, 0.16)
    x = 0.05 * np.sin(y / 6.0)  # lateral steering wander of 5 cm
    assert find_turns(_path(np.column_stack([x, y]), noise_m=0.01)) == []


def test_loop_corners_counted_short_path_has_none() -> None:
    r, ds = 3.0, 0.1
    pts = [np.column_stack([np.arange(0.0, 12.0, ds), np.zeros(120)])]
    a = np.linspace(-np.pi / 2, 0.0, int(np.pi / 2 * r / ds))
    pts.append(np.column_stack([12.0 + r * np.cos(a), r + r * np.sin(a)]))
    pts.append(np.column_stack([np.full(120, 15.0), r + np.arange(0.0, 12.0, ds)]))
    turns = find_turns(_path(np.concatenate(pts)))
    assert [round(t.angle_deg / 90.0) for t in turns] == [1]  # one 90° left corner
    assert find_turns(_path(np.column_stack([np.zeros(10), np.arange(10) * 0.1]))) == []
