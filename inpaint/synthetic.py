"""Procedural field-like depth maps with exact ground truth (unit tests; training fallback only).

A pinhole camera (Rosario-like rectified intrinsics scaled to the requested size) at ``cam_height`` metres above
flat or gently undulating ground, pitched down; crop rows of leafy plants (clusters of spheres) along the
viewing direction; a tree line (vertical surface) far away and sky above it. Depth is the z-buffer of these
surfaces (optical frame: x right, y down, z forward), metres, float32. Sky pixels get ``sky_depth`` and are
flagged invalid in ``valid`` (no finite ground truth). A grey guide image in [0, 1] is rendered from the same
surfaces (textured ground, brighter leaves with shading, bright sky).

This generator is NOT the project's simulator (``pipeline/sim``); it exists so that the inpaint library can be
tested without the pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SyntheticFrame:
    """``depth``: H×W float32 metres; ``guide``: H×W float32 grey in [0, 1]; ``valid``: H×W bool (False = sky)."""

    depth: np.ndarray
    guide: np.ndarray
    valid: np.ndarray


def field_depth(height: int = 376, width: int = 672, seed: int = 0, cam_height: float = 1.0,
                pitch_deg: float | None = None, n_rows: int = 5, row_spacing: float = 0.7,
                sky_depth: float = 60.0) -> SyntheticFrame:
    """Render one procedural field frame (see module docstring); deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    s = width / 672.0
    fx = fy = 351.0 * s
    cx, cy = width / 2.0 + rng.uniform(-10, 10) * s, height / 2.0 + rng.uniform(-10, 10) * s
    pitch = np.deg2rad(rng.uniform(8.0, 18.0) if pitch_deg is None else pitch_deg)
    yaw = np.deg2rad(rng.uniform(-8.0, 8.0))
    # Camera-from-world rotation: world x right, y down (gravity), z forward; camera pitched down by `pitch`.
    cp, sp, cyw, syw = np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    r_pitch = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    r_yaw = np.array([[cyw, 0, syw], [0, 1, 0], [-syw, 0, cyw]])
    r_cw = r_pitch @ r_yaw  # maps world directions to camera
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays_c = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)  # camera rays (z = 1)
    rays_w = rays_c @ r_cw  # world directions (rows: r_wc · ray_c)
    depth = np.full((height, width), np.inf)
    label = np.zeros((height, width), np.int8)  # 0 sky, 1 ground, 2 plant, 3 tree line
    shade = np.zeros((height, width))

    # Ground: world y = cam_height + small undulation; solve along the ray (two fixed-point steps).
    amp, wl = rng.uniform(0.0, 0.08), rng.uniform(3.0, 8.0)
    dy = rays_w[..., 1]
    t = np.where(dy > 1e-6, cam_height / np.maximum(dy, 1e-6), np.inf)
    for _ in range(2):
        xz = np.where(np.isfinite(t), rays_w[..., 2] * np.where(np.isfinite(t), t, 0.0), 0.0)
        hgt = cam_height + amp * np.sin(xz / wl * 2 * np.pi)
        t = np.where(dy > 1e-6, hgt / np.maximum(dy, 1e-6), np.inf)
    zg = t * 1.0  # camera z of the point = t (rays_c has z = 1)
    ground = np.isfinite(zg) & (zg > 0) & (zg < sky_depth)
    depth[ground] = zg[ground]
    label[ground] = 1

    # Tree line: a vertical plane at world z = far, up to `tree_h` above the ground.
    far, tree_h = rng.uniform(18.0, 35.0), rng.uniform(3.0, 8.0)
    dz = rays_w[..., 2]
    tt = np.where(dz > 1e-6, far / np.maximum(dz, 1e-6), np.inf)
    yw = rays_w[..., 1] * tt
    tree_top = cam_height - tree_h + 1.5 * np.sin(rays_w[..., 0] * tt / 4.0 + rng.uniform(0, 6))
    tree = (yw > tree_top) & (tt < depth)
    depth[tree] = tt[tree]
    label[tree] = 3

    # Plants: clusters of spheres along crop rows (world x = row offsets), sorted far to near.
    offsets = (np.arange(n_rows) - (n_rows - 1) / 2.0) * row_spacing + rng.uniform(-0.2, 0.2)
    spheres = []
    for x0 in offsets:
        z = rng.uniform(1.0, 2.5)
        while z < 14.0:
            rad = rng.uniform(0.07, 0.22)
            n_leaf = rng.integers(2, 5)
            for _ in range(n_leaf):
                c = np.array([x0 + rng.normal(0, 0.06), cam_height - rad * rng.uniform(0.6, 1.6),
                              z + rng.normal(0, 0.05)])
                spheres.append((c, rad * rng.uniform(0.5, 1.0)))
            z += rng.uniform(0.25, 0.6)
    for cw, rad in spheres:
        cc = r_cw @ cw  # centre in camera frame
        if cc[2] <= rad + 0.05:
            continue
        uc, vc = fx * cc[0] / cc[2] + cx, fy * cc[1] / cc[2] + cy
        pr = fx * rad / cc[2] * 1.2 + 2
        u0, u1 = int(max(0, uc - pr)), int(min(width, uc + pr + 1))
        v0, v1 = int(max(0, vc - pr)), int(min(height, vc + pr + 1))
        if u0 >= u1 or v0 >= v1:
            continue
        rc = rays_c[v0:v1, u0:u1]
        nrm = np.linalg.norm(rc, axis=-1)
        dirs = rc / nrm[..., None]
        b = dirs @ cc
        disc = b * b - cc @ cc + rad * rad
        hit = disc > 0
        tt = b - np.sqrt(np.maximum(disc, 0))
        zz = tt / nrm  # camera z
        win = hit & (zz < depth[v0:v1, u0:u1]) & (zz > 0)
        sub_d = depth[v0:v1, u0:u1]
        sub_d[win] = zz[win]
        label[v0:v1, u0:u1][win] = 2
        pts = dirs * tt[..., None] - cc
        shade[v0:v1, u0:u1][win] = (0.5 + 0.5 * (pts[..., 1] / rad * -0.6 + pts[..., 0] / rad * 0.3))[win]

    valid = np.isfinite(depth)
    depth = np.where(valid, depth, sky_depth).astype(np.float32)
    guide = _guide(label, shade, depth, rng)
    return SyntheticFrame(depth=depth, guide=guide, valid=valid)


def _guide(label: np.ndarray, shade: np.ndarray, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    h, w = label.shape
    noise = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 1.2)
    g = np.zeros((h, w), np.float32)
    g[label == 0] = 0.9
    g[label == 1] = 0.35 + 0.08 * noise[label == 1]
    g[label == 2] = (0.25 + 0.35 * np.clip(shade, 0, 1) + 0.05 * noise)[label == 2]
    g[label == 3] = 0.2 + 0.1 * noise[label == 3]
    return np.clip(g, 0, 1).astype(np.float32)


def object_depth(height: int = 376, width: int = 672, seed: int = 0, sky_depth: float = 60.0) -> SyntheticFrame:
    """A non-field scene with exact depth: ground plane, a tilted back wall (or sky above a low wall), boxes at
    several distances (occluding one another), thin vertical poles and floating tilted plates. Deterministic in
    ``seed``. Same conventions as :func:`field_depth` (optical frame, metres, float32; sky invalid)."""
    rng = np.random.default_rng(seed)
    s = width / 672.0
    fx = fy = 351.0 * s
    cx, cy = width / 2.0, height / 2.0
    pitch = np.deg2rad(rng.uniform(0.0, 20.0))
    cam_h = rng.uniform(0.5, 1.8)
    cp, sp = np.cos(pitch), np.sin(pitch)
    r_cw = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays_c = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
    d = rays_c @ r_cw  # world directions (x right, y down, z forward), camera at (0, −cam_h, 0) above y = 0
    o = np.array([0.0, -cam_h, 0.0])
    depth = np.full((height, width), np.inf)  # ray parameter t; camera z = t because rays_c has z = 1
    label = np.zeros((height, width), np.int8)
    shade = np.zeros((height, width))

    def put(t: np.ndarray, lab: int, sh: np.ndarray | float) -> None:
        win = np.isfinite(t) & (t > 0.05) & (t < depth)
        depth[win] = t[win]
        label[win] = lab
        shade[win] = (np.broadcast_to(sh, t.shape))[win]

    with np.errstate(divide="ignore", invalid="ignore"):
        put(np.where(d[..., 1] > 1e-6, cam_h / d[..., 1], np.inf), 1, 0.4)  # ground y = 0
        far = rng.uniform(8.0, 30.0)
        tilt = rng.uniform(-0.4, 0.4)  # wall z = far + tilt·x
        denom = d[..., 2] - tilt * d[..., 0]
        tw = np.where(denom > 1e-6, far / denom, np.inf)
        wall_top = rng.uniform(1.0, 6.0) if rng.random() < 0.6 else 1e9
        yw = o[1] + tw * d[..., 1]
        put(np.where(yw > -wall_top, tw, np.inf), 2, 0.3)
        for _ in range(int(rng.integers(3, 9))):  # boxes (slab method)
            z0 = rng.uniform(1.2, min(far - 1.0, 14.0))
            size = rng.uniform(0.2, 1.8, 3)
            x0 = rng.uniform(-0.6, 0.6) * z0
            lo = np.array([x0 - size[0] / 2, -size[1], z0])
            hi = np.array([x0 + size[0] / 2, 0.0, z0 + size[2]])
            if rng.random() < 0.3:  # floating
                lift = rng.uniform(0.2, 1.0)
                lo[1] -= lift
                hi[1] -= lift
            t1 = (lo - o) / d
            t2 = (hi - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=-1)
            tf = np.nanmin(np.maximum(t1, t2), axis=-1)
            put(np.where((tf >= tn) & (tn > 0), tn, np.inf), 3, rng.uniform(0.2, 0.8))
        for _ in range(int(rng.integers(0, 6))):  # thin vertical poles (cylinders)
            pc = np.array([rng.uniform(-4, 4), rng.uniform(1.5, 12.0)])
            rad = rng.uniform(0.015, 0.08)
            top = rng.uniform(0.5, 3.0)
            ox, oz = o[0] - pc[0], o[2] - pc[1]
            a = d[..., 0] ** 2 + d[..., 2] ** 2
            b = 2 * (ox * d[..., 0] + oz * d[..., 2])
            c = ox * ox + oz * oz - rad * rad
            disc = b * b - 4 * a * c
            tp = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
            yp = o[1] + tp * d[..., 1]
            put(np.where((disc > 0) & (yp < 0) & (yp > -top), tp, np.inf), 4, 0.6)
        for _ in range(int(rng.integers(0, 4))):  # tilted plates: a plane patch n·(p − c) = 0 within a radius
            c0 = np.array([rng.uniform(-3, 3), -rng.uniform(0.3, 2.0), rng.uniform(2.0, 10.0)])
            n = rng.normal(size=3)
            n[2] = -abs(n[2]) - 0.5
            n /= np.linalg.norm(n)
            rad = rng.uniform(0.3, 1.2)
            den = d @ n
            tp = ((c0 - o) @ n) / den
            p = o + tp[..., None] * d
            put(np.where(np.linalg.norm(p - c0, axis=-1) < rad, tp, np.inf), 5, 0.7)
    valid = np.isfinite(depth) & (depth < sky_depth)
    depth = np.where(valid, depth, sky_depth).astype(np.float32)
    noise = cv2.GaussianBlur(rng.standard_normal((height, width)).astype(np.float32), (0, 0), 1.2)
    guide = np.clip(np.where(label == 0, 0.9, shade + 0.05 * noise), 0, 1).astype(np.float32)
    return SyntheticFrame(depth=depth, guide=guide, valid=valid)


def room_depth(height: int = 376, width: int = 672, seed: int = 0) -> SyntheticFrame:
    """A piecewise-planar indoor / built scene with exact depth: floor, ceiling, side walls and a back wall of a
    room or corridor (random width, height, depth and yaw), door-like openings in the back wall that show a farther
    wall, a staircase of steps, slanted panels and thin vertical posts (occluding edges at several distances).
    Deterministic in ``seed``; every pixel has ground truth. Same conventions as :func:`field_depth`."""
    rng = np.random.default_rng(seed)
    s = width / 672.0
    fx = fy = 351.0 * s
    cx, cy = width / 2.0 + rng.uniform(-8, 8) * s, height / 2.0 + rng.uniform(-8, 8) * s
    pitch, yaw = np.deg2rad(rng.uniform(-6.0, 12.0)), np.deg2rad(rng.uniform(-25.0, 25.0))
    cp, sp, cyw, syw = np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    r_cw = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]]) @ np.array([[cyw, 0, syw], [0, 1, 0], [-syw, 0, cyw]])
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays_c = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
    d = rays_c @ r_cw  # world directions (x right, y down, z forward); camera at the origin
    depth = np.full((height, width), np.inf)  # ray parameter = camera z (rays_c has z = 1)
    half_w, cam_h, ceil_h = rng.uniform(1.2, 4.0), rng.uniform(0.4, 1.7), rng.uniform(2.2, 4.0)
    back = rng.uniform(5.0, 25.0)

    def plane(n: np.ndarray, c: float, inside=None) -> None:
        """Put the plane n·p = c (world) where it is nearer, optionally only where ``inside(p)`` holds."""
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(np.abs(den) > 1e-9, c / den, np.inf)
        ok = np.isfinite(t) & (t > 0.05) & (t < depth)
        if inside is not None:
            p = t[..., None] * d
            ok &= inside(p)
        depth[ok] = t[ok]

    plane(np.array([0.0, 1.0, 0.0]), cam_h)  # floor y = cam_h
    plane(np.array([0.0, 1.0, 0.0]), cam_h - ceil_h)  # ceiling
    plane(np.array([1.0, 0.0, 0.0]), -half_w)  # left wall
    plane(np.array([1.0, 0.0, 0.0]), half_w)  # right wall
    doors = [(rng.uniform(-half_w + 0.3, half_w - 1.2), rng.uniform(0.7, 1.4)) for _ in range(int(rng.integers(0, 3)))]
    door_top = cam_h - rng.uniform(1.8, 2.1)
    plane(np.array([0.0, 0.0, 1.0]), back + rng.uniform(2.0, 6.0))  # farther wall seen through the doors

    def not_door(p: np.ndarray) -> np.ndarray:
        ok = np.ones(p.shape[:2], bool)
        for x0, wd in doors:
            ok &= ~((p[..., 0] > x0) & (p[..., 0] < x0 + wd) & (p[..., 1] > door_top))
        return ok

    plane(np.array([0.0, 0.0, 1.0]), back, not_door)
    if rng.random() < 0.6:  # a staircase: steps of riser r and tread t rising away from the camera
        z0, rise, tread = rng.uniform(2.0, back - 2.0), rng.uniform(0.12, 0.2), rng.uniform(0.25, 0.35)
        x0, x1 = sorted(rng.uniform(-half_w, half_w, 2))
        for k in range(int(rng.integers(3, 8))):
            zk, yk = z0 + k * tread, cam_h - (k + 1) * rise
            plane(np.array([0.0, 0.0, 1.0]), zk, lambda p, yk=yk, x0=x0, x1=x1: (p[..., 1] > yk) & (p[..., 1] < cam_h)
                  & (p[..., 0] > x0) & (p[..., 0] < x1))
            plane(np.array([0.0, 1.0, 0.0]), yk, lambda p, zk=zk, x0=x0, x1=x1: (p[..., 2] > zk) & (p[..., 0] > x0)
                  & (p[..., 0] < x1))
    for _ in range(int(rng.integers(1, 5))):  # slanted rectangular panels
        c0 = np.array([rng.uniform(-half_w, half_w), cam_h - rng.uniform(0.3, 1.8), rng.uniform(1.5, back - 0.5)])
        n = rng.normal(size=3)
        n[2] = -abs(n[2]) - 0.3
        n /= np.linalg.norm(n)
        e1 = np.cross(n, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        a, b = rng.uniform(0.3, 1.2, 2)
        plane(n, float(n @ c0), lambda p, c0=c0, e1=e1, e2=e2, a=a, b=b: (np.abs((p - c0) @ e1) < a)
              & (np.abs((p - c0) @ e2) < b))
    for _ in range(int(rng.integers(0, 5))):  # thin posts: front faces of narrow boxes
        x0, z0, wd = rng.uniform(-half_w, half_w), rng.uniform(1.2, back - 0.5), rng.uniform(0.03, 0.12)
        plane(np.array([0.0, 0.0, 1.0]), z0, lambda p, x0=x0, wd=wd: (p[..., 0] > x0) & (p[..., 0] < x0 + wd))
    valid = np.isfinite(depth)
    depth = np.where(valid, depth, 60.0).astype(np.float32)
    noise = cv2.GaussianBlur(rng.standard_normal((height, width)).astype(np.float32), (0, 0), 1.2)
    guide = np.clip(0.5 + 0.1 * noise - 0.01 * depth, 0, 1).astype(np.float32)
    return SyntheticFrame(depth=depth, guide=guide, valid=valid)


def stereo_noise(depth: np.ndarray, seed: int = 0, focal_baseline: float = 351.06 * 0.1187,
                 sigma_px: float = 0.15, step_px: float = 1.0 / 16.0) -> np.ndarray:
    """``depth`` (float32 H×W metres) as a stereo matcher measures it: disparity f·B/z plus Gaussian noise of
    ``sigma_px`` pixels (spatially smoothed over ~2 px, as block matching correlates neighbours), quantised to
    ``step_px`` (StereoSGBM's 1/16 px), back to depth. Deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    disp = focal_baseline / np.maximum(depth.astype(np.float64), 1e-3)
    n = cv2.GaussianBlur(rng.standard_normal(depth.shape).astype(np.float32), (0, 0), 1.0)
    n *= sigma_px / max(float(n.std()), 1e-9)
    disp = np.maximum(np.round((disp + n) / step_px) * step_px, step_px)
    return (focal_baseline / disp).astype(np.float32)
