"""Robot motion: a planned route, a speed profile, terrain-following attitude and vibration, as quintic B-splines.

The true trajectory of base_link (field frame F) is six uniform quintic B-splines in time (knots every
``motion.knot_dt_s``): position ``x, y, z`` and yaw/pitch/roll ``ψ, θ, φ`` with ``R_F_B = Rz(ψ) Ry(θ) Rx(φ)``.
Their control points are samples of the planned motion (route + speed profile + terrain + vibration), so the
spline smooths the plan slightly (a B-spline with control points ``c_i`` stays inside their hull). Because it is
C⁴, velocities, accelerations and angular rates are exact analytic derivatives: the IMU readings computed from
them integrate back to the trajectory (``tests/test_sim_imu.py``). Where all control points are equal (the
standing-still start, stops) the spline is exactly constant: zero velocity, zero angular rate.

Times are seconds since the sequence start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline
from scipy.ndimage import gaussian_filter1d

from pipeline.sim.config import SimConfig
from pipeline.sim.terrain import Terrain

WHEELBASE_M = 1.6
TRACK_M = 1.054
_DEG = np.pi / 180.0


# ---- route planning ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Segment:
    """A piece of the planar route: a straight line (``curvature == 0``) or a circular arc.

    Attributes:
        x0, y0: start point, metres (field frame).  heading0: start heading, rad (0 = +x, π/2 = +y).
        length: arc length, metres.  curvature: 1/radius, rad/m, positive = turning left (counter-clockwise).
        turn: True for headland turns and corners (driven at the turn speed).
    """

    x0: float
    y0: float
    heading0: float
    length: float
    curvature: float
    turn: bool

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, heading) at arc lengths ``s`` (0..length) along the segment."""
        k = self.curvature
        h = self.heading0 + k * s
        if abs(k) < 1e-12:
            return self.x0 + s * np.cos(self.heading0), self.y0 + s * np.sin(self.heading0), h
        return (self.x0 + (np.sin(h) - np.sin(self.heading0)) / k,
                self.y0 - (np.cos(h) - np.cos(self.heading0)) / k, h)

    def end(self) -> tuple[float, float, float]:
        x, y, h = self.at(np.array(self.length))
        return float(x), float(y), float(h)


def plan_route(cfg: SimConfig, min_length_m: float) -> list[Segment]:
    """The route's segments, at least ``min_length_m`` long in total."""
    r = cfg.route
    f = cfg.field
    segs: list[Segment] = []
    if r.kind == "rows":
        x = r.start_row * f.row_spacing_m
        y = r.start_y_m
        h = np.pi / 2
        y_far = f.row_length_m + 2.5
        y_near = -2.5
        rad = r.turn_rows * f.row_spacing_m / 2
        north = True
        side = 1.0  # +1: successive passes move towards +x
        x_max = (f.n_rows - 1) * f.row_spacing_m
        total = 0.0
        while total < min_length_m:
            target = y_far if north else y_near
            length = abs(target - y)
            segs.append(Segment(x, y, h, length, 0.0, False))
            x, y, h = segs[-1].end()
            if not (0.0 <= x + side * 2 * rad <= x_max):
                side = -side  # ran out of field: come back the other way
            k = (-side if north else side) / rad
            segs.append(Segment(x, y, h, np.pi * rad, k, True))
            x, y, h = segs[-1].end()
            total += length + np.pi * rad
            north = not north
    elif r.kind == "loop":
        x = r.start_row * f.row_spacing_m
        y = r.start_y_m if r.start_y_m > 0 else f.row_length_m / 2 - r.leg_m
        h = 0.0
        legs = (r.leg_m, 2 * r.leg_m)
        total = 0.0
        i = 0
        while total < min_length_m:
            length = legs[i % 2]
            segs.append(Segment(x, y, h, length, 0.0, False))
            x, y, h = segs[-1].end()
            arc = np.pi / 2 * r.corner_radius_m
            segs.append(Segment(x, y, h, arc, 1.0 / r.corner_radius_m, True))
            x, y, h = segs[-1].end()
            total += length + arc
            i += 1
    else:
        raise ValueError(f"route kind must be 'rows' or 'loop', got {r.kind!r}")
    return segs


def _sample_route(segs: list[Segment], ds: float) -> tuple[np.ndarray, ...]:
    """Route sampled every ``ds`` metres: (s, x, y, heading, is_turn)."""
    out = []
    s0 = 0.0
    for seg in segs:
        s = np.arange(0.0, seg.length, ds)
        x, y, h = seg.at(s)
        out.append((s0 + s, x, y, h, np.full(s.size, seg.turn)))
        s0 += seg.length
    return tuple(np.concatenate([o[j] for o in out]) for j in range(5))


def speed_profile(s: np.ndarray, is_turn: np.ndarray, cfg: SimConfig, stops_s: np.ndarray) -> np.ndarray:
    """Speed (m/s) along the route: cruise on straights (times the pass's ``route.speed_changes`` factor), turn
    speed in turns (reached before them), zero at stops, accelerations bounded by ``route.accel_mps2``
    (forward/backward passes), zero at the start."""
    r = cfg.route
    ds = s[1] - s[0]
    cruise = np.full(s.size, r.speed_mps)
    if r.speed_changes:
        # pass k: the k-th straight stretch (a new one starts where a turn ends)
        starts = np.concatenate([[0], (is_turn[:-1] & ~is_turn[1:]).astype(np.int64)])
        factors = np.asarray(r.speed_changes)
        cruise = r.speed_mps * factors[np.cumsum(starts) % factors.size]
    target = np.where(is_turn, r.turn_speed_mps, cruise)
    for sp in stops_s:
        target[np.argmin(np.abs(s - sp))] = 0.0
    v = target.copy()
    v[0] = 0.0
    a2 = 2 * r.accel_mps2 * ds
    for i in range(1, v.size):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + a2))
    for i in range(v.size - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + a2))
    return v


# ---- the spline trajectory -----------------------------------------------------------------------------------------
def _uniform_bspline(ctrl: np.ndarray, dt: float, t_first: float = 0.0, k: int = 5) -> BSpline:
    """Uniform B-spline whose basis function ``j`` peaks at ``t_first + j · dt``; ``ctrl`` (n, c) control points."""
    n = ctrl.shape[0]
    knots = t_first + (np.arange(n + k + 1) - (k + 1) / 2.0) * dt
    return BSpline(knots, ctrl, k, extrapolate=False)


def _elem(axis: str, a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    if axis == "x":
        m = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == "y":
        m = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        m = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.moveaxis(np.array(m), (0, 1), (-2, -1))


_SKEW = {"x": np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], float),
         "y": np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], float),
         "z": np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], float)}


@dataclass
class Kinematics:
    """Base and IMU kinematics at a set of times (arrays over N times, field frame F).

    Attributes:
        t: (N,) seconds.
        p_B, v_B, a_B: (N, 3) base_link position (m), velocity (m/s), acceleration (m/s²).
        R_FB: (N, 3, 3) base orientation.  omega_B: (N, 3) angular velocity in base axes, rad/s.
        euler: (N, 3) yaw, pitch, roll (rad).
        p_I, v_I, a_I: (N, 3) IMU position, velocity, acceleration.  R_FI: (N, 3, 3) IMU orientation.
        gyro: (N, 3) true angular velocity in IMU axes, rad/s.
        specific_force: (N, 3) true accelerometer reading ``R_FI^T (a_I - g)`` in IMU axes, m/s².
    """

    t: np.ndarray
    p_B: np.ndarray
    v_B: np.ndarray
    a_B: np.ndarray
    R_FB: np.ndarray
    omega_B: np.ndarray
    euler: np.ndarray
    p_I: np.ndarray
    v_I: np.ndarray
    a_I: np.ndarray
    R_FI: np.ndarray
    gyro: np.ndarray
    specific_force: np.ndarray


class RobotTrajectory:
    """The true motion of the robot (see the module docstring).

    Args:
        cfg: simulation config (route, motion, field, imu gravity, duration).
        terrain: the ground the wheels roll on.
        T_base_imu: (4, 4) IMU mounting (maps IMU points into base_link).
        seed: vibration and wander seed.
    """

    def __init__(self, cfg: SimConfig, terrain: Terrain, T_base_imu: np.ndarray, seed: int) -> None:
        self.cfg = cfg
        self.T_BI = np.asarray(T_base_imu, np.float64)
        self.gravity = np.array([0.0, 0.0, -cfg.imu.gravity_mps2])
        m = cfg.motion
        r = cfg.route
        dt = m.knot_dt_s
        self.duration = float(cfg.duration_s)
        n = int(np.ceil((self.duration + 1.0) / dt)) + 12
        tk = (np.arange(n) - 6) * dt  # control-point times (a few before 0 and after the end)
        # ---- plan: route sampled at 5 cm, speed profile, time parameterisation ------------------------------------
        route_len = max(r.speed_mps * r.max_speed_factor(), 0.1) * self.duration + 20.0
        segs = plan_route(cfg, route_len)
        s, x, y, hd, turn = _sample_route(segs, 0.05)
        stops = np.zeros(0)
        if r.stop_every_s:
            stops = np.arange(r.stop_every_s * r.speed_mps, s[-1], r.stop_every_s * r.speed_mps)
        v = speed_profile(s, turn, cfg, stops)
        vm = np.maximum(0.5 * (v[1:] + v[:-1]), 1e-3)
        t_s = np.concatenate([[0.0], np.cumsum(np.diff(s) / vm)])
        stop_idx = [int(np.argmin(np.abs(s - sp))) for sp in stops]
        for i in stop_idx:
            t_s[i:] += r.stop_s
        t_s = t_s + r.still_s
        # at each control time: arc length reached (0 before the start)
        s_k = np.interp(tk, t_s, s, left=0.0, right=s[-1])
        xk = np.interp(s_k, s, x)
        yk = np.interp(s_k, s, y)
        hk = np.interp(s_k, s, np.unwrap(hd))
        speed_k = np.interp(tk, t_s, v, left=0.0, right=0.0)
        moving = np.clip(speed_k / 0.15, 0.0, 1.0)
        # ---- wander and vibration (zero while standing still) -------------------------------------------------------
        rng = np.random.default_rng([seed, 501])
        rough = max(cfg.field.roughness_m, 0.0) / 0.02
        env = np.clip(speed_k, 0, None) * rough  # vibration amplitude ∝ speed (per 1 m/s) and roughness
        lat = r.lateral_wander_m * gaussian_filter1d(rng.standard_normal(n), 1.5 / dt, mode="wrap") * moving
        lat /= max(gaussian_filter1d(np.random.default_rng([seed, 502]).standard_normal(n), 1.5 / dt).std(), 1e-9)
        yaw_w = r.yaw_wander_deg * _DEG * gaussian_filter1d(rng.standard_normal(n), 1.0 / dt, mode="wrap") * moving
        yaw_w /= max(gaussian_filter1d(np.random.default_rng([seed, 503]).standard_normal(n), 1.0 / dt).std(), 1e-9)

        def vib(target_rms: float, order: int) -> np.ndarray:
            # rotations: body modes are slower than the heave/shake of the head (twice the smoothing)
            raw = gaussian_filter1d(rng.standard_normal(n), m.smooth_knots * (2.0 if order == 1 else 1.0),
                                    mode="wrap")
            spl = _uniform_bspline(raw[:, None], dt, tk[0])
            tt = tk[6:-6]
            rms = np.sqrt(np.mean(spl.derivative(order)(tt)[:, 0] ** 2))
            return raw * (target_rms / max(rms, 1e-12)) * env

        heave = vib(m.heave_acc_rms, 2)
        side = vib(m.lateral_acc_rms, 2)
        along = vib(0.5 * m.lateral_acc_rms, 2)
        d_pitch = vib(m.rate_rms_deg_s * _DEG, 1)
        d_roll = vib(m.rate_rms_deg_s * _DEG, 1)
        d_yaw = vib(0.5 * m.rate_rms_deg_s * _DEG, 1)
        # ---- terrain following ---------------------------------------------------------------------------------------
        yaw = hk + yaw_w + d_yaw
        c, sn = np.cos(hk), np.sin(hk)
        px = xk + (lat + side) * -sn + along * c
        py = yk + (lat + side) * c + along * sn
        z_base, pitch, roll = self._attitude(terrain, px, py, yaw)
        ctrl = np.stack([px, py, z_base + heave, yaw, pitch + d_pitch, roll + d_roll], 1)
        self._spline = _uniform_bspline(ctrl, dt, tk[0])
        self._d1 = self._spline.derivative(1)
        self._d2 = self._spline.derivative(2)
        self.knot_dt = dt
        self._speed_plan = (tk, speed_k)
        self.still_until_s = float(r.still_s - 3 * dt)  # exact stillness holds up to here (B-spline support)
        self.route = segs

    @staticmethod
    def _attitude(terrain: Terrain, x: np.ndarray, y: np.ndarray, yaw: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Base height, pitch and roll from the four wheel contacts (heights averaged over a tyre footprint)."""
        fwd = np.stack([np.cos(yaw), np.sin(yaw)], 1)
        left = np.stack([-np.sin(yaw), np.cos(yaw)], 1)
        base = np.stack([x, y], 1)

        def wheel(off_fwd: float, off_left: float) -> np.ndarray:
            c = base + off_fwd * fwd + off_left * left
            hs = [terrain.height(c[:, 0] + dx * fwd[:, 0], c[:, 1] + dx * fwd[:, 1]) for dx in (-0.12, 0.0, 0.12)]
            return np.mean(hs, axis=0)

        rl, rr = wheel(0.0, TRACK_M / 2), wheel(0.0, -TRACK_M / 2)
        fl, fr = wheel(WHEELBASE_M, TRACK_M / 2), wheel(WHEELBASE_M, -TRACK_M / 2)
        rear = 0.5 * (rl + rr)
        front = 0.5 * (fl + fr)
        pitch = np.arctan2(rear - front, WHEELBASE_M)  # nose down positive (rotation about +y, left)
        roll = np.arctan2(0.5 * (rl + fl) - 0.5 * (rr + fr), TRACK_M)  # left side up positive
        return rear, pitch, roll

    # ---- evaluation ------------------------------------------------------------------------------------------------
    def kinematics(self, t: np.ndarray) -> Kinematics:
        """Exact kinematics at times ``t`` (seconds, within [0, duration])."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        q, dq, ddq = self._spline(t), self._d1(t), self._d2(t)
        if np.any(~np.isfinite(q)):
            raise ValueError("trajectory evaluated outside its time span")
        ang = q[:, 3:6]
        rates = dq[:, 3:6]
        acc = ddq[:, 3:6]
        mats = [_elem("z", ang[:, 0]), _elem("y", ang[:, 1]), _elem("x", ang[:, 2])]
        skews = [_SKEW["z"], _SKEW["y"], _SKEW["x"]]
        d1 = [mats[j] @ skews[j] * rates[:, j, None, None] for j in range(3)]
        d2 = [mats[j] @ (skews[j] * acc[:, j, None, None] + skews[j] @ skews[j] * rates[:, j, None, None] ** 2)
              for j in range(3)]
        Rz, Ry, Rx = mats
        R = Rz @ Ry @ Rx
        Rd = d1[0] @ Ry @ Rx + Rz @ d1[1] @ Rx + Rz @ Ry @ d1[2]
        Rdd = (d2[0] @ Ry @ Rx + Rz @ d2[1] @ Rx + Rz @ Ry @ d2[2]
               + 2 * (d1[0] @ d1[1] @ Rx + d1[0] @ Ry @ d1[2] + Rz @ d1[1] @ d1[2]))
        W = np.transpose(R, (0, 2, 1)) @ Rd
        omega_B = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], 1)
        t_bi = self.T_BI[:3, 3]
        R_bi = self.T_BI[:3, :3]
        p_B, v_B, a_B = q[:, :3], dq[:, :3], ddq[:, :3]
        p_I = p_B + R @ t_bi
        v_I = v_B + Rd @ t_bi
        a_I = a_B + Rdd @ t_bi
        R_FI = R @ R_bi
        gyro = omega_B @ R_bi  # R_bi^T ω_B for row vectors
        f = np.einsum("nji,nj->ni", R_FI, a_I - self.gravity)
        return Kinematics(t, p_B, v_B, a_B, R, omega_B, ang, p_I, v_I, a_I, R_FI, gyro, f)

    def pose_imu(self, t: float) -> np.ndarray:
        """T_F_I (4, 4) at time ``t``."""
        k = self.kinematics(np.array([t]))
        T = np.eye(4)
        T[:3, :3] = k.R_FI[0]
        T[:3, 3] = k.p_I[0]
        return T

    def planned_speed(self, t: np.ndarray) -> np.ndarray:
        """Planned forward speed (m/s) at times ``t`` (before smoothing; scales the IMU's structural vibration)."""
        return np.interp(t, *self._speed_plan)
