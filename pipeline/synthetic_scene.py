"""A tiny deterministic stereo scene: textured planes at known depths, rendered through a stereo rig.

For tests and the interim demo (the full agricultural simulator lives elsewhere). Tools:

* :func:`shifted_pair` — an already rectified grey pair with an exact, known disparity (right = left shifted).
* :class:`PlaneScene` + :func:`render_stereo` — raw (distorted, unrectified) BGR images of fronto-parallel
  textured rectangles seen by a :class:`msckf.camera.StereoRig`, with a z-buffer, plus the ground-truth depth in
  the rectified left frame (:func:`render_rectified_depth`). Rays miss every plane above the "horizon": those
  pixels show a flat sky, which stereo cannot match (real holes, not painted ones).
* :func:`write_synthetic_bag` — a short Rosario-layout bag of the camera sliding sideways past the scene, with
  IMU, GPS, odometry and tf_static.

World frame: the left camera's optical frame at time 0 (x right, y down, z forward), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from msckf.camera import PinholeRadtan, StereoRig
from pipeline.rosario_layout import RATE_CAMERA_HZ

_TEXTURE_SIZE = 1024  # texels per side of the tiled texture


def texture(seed: int, size: int = _TEXTURE_SIZE) -> np.ndarray:
    """A tileable multi-scale noise texture, (size, size) uint8, deterministic in ``seed``.

    Sum of octaves of uniform noise blurred with wrap-around padding (so it tiles), stretched to 0..255.
    """
    rng = np.random.default_rng(seed)
    acc = np.zeros((size, size), np.float32)
    for sigma, weight in ((0.0, 0.35), (1.5, 0.35), (4.0, 0.2), (16.0, 0.1)):
        noise = rng.random((size, size), dtype=np.float32)
        if sigma > 0:
            pad = int(np.ceil(4 * sigma))
            noise = cv2.GaussianBlur(np.pad(noise, pad, mode="wrap"), (0, 0), sigma)[pad:-pad, pad:-pad]
            noise = (noise - noise.mean()) / (noise.std() + 1e-6)
        else:
            noise = (noise - 0.5) / 0.29
        acc += weight * noise
    acc = (acc - acc.min()) / (acc.max() - acc.min() + 1e-9)
    return np.round(acc * 255.0).astype(np.uint8)


def shifted_pair(width: int = 672, height: int = 376, disparity_px: int = 20,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A rectified grey pair with constant disparity: ``left[y, x] == right[y, x - disparity_px]``.

    Returns:
        (left, right) uint8 (height, width) images; every point has disparity exactly ``disparity_px`` px.
    """
    tex = texture(seed, size=max(width + disparity_px, height) + 8)
    left = tex[:height, :width].copy()
    right = tex[:height, disparity_px:disparity_px + width].copy()
    return left, right


@dataclass(frozen=True)
class TexturedRect:
    """A fronto-parallel textured rectangle in the world frame.

    Attributes:
        z_m: depth of the plane (world z), metres.
        x_range_m, y_range_m: extent in world x and y (metres); ``None`` means unbounded on that side.
        texel_m: texture resolution, metres per texel (the texture tiles every ``1024 * texel_m`` metres).
        seed: texture seed.
        tint_bgr: per-channel gain applied to the grey texture (vegetation-like greens by default).
    """

    z_m: float
    x_range_m: tuple[float | None, float | None] = (None, None)
    y_range_m: tuple[float | None, float | None] = (None, None)
    texel_m: float = 0.004
    seed: int = 0
    tint_bgr: tuple[float, float, float] = (0.55, 1.0, 0.7)


def _default_planes() -> tuple[TexturedRect, ...]:
    return (
        TexturedRect(z_m=6.0, y_range_m=(-2.0, None), texel_m=0.008, seed=1, tint_bgr=(0.45, 0.9, 0.6)),
        TexturedRect(z_m=2.5, x_range_m=(-0.5, 0.6), y_range_m=(-0.3, None), texel_m=0.003, seed=2),
    )


@dataclass(frozen=True)
class PlaneScene:
    """Textured rectangles plus a flat sky colour for rays that hit nothing."""

    planes: tuple[TexturedRect, ...] = field(default_factory=_default_planes)
    sky_bgr: tuple[int, int, int] = (235, 206, 170)


def _pixel_rays(cam: PinholeRadtan) -> np.ndarray:
    """Unit-z rays (H, W, 3) in the raw camera frame for every raw pixel centre."""
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    rays = cam.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    return rays.reshape(cam.height, cam.width, 3)


def _trace(origin: np.ndarray, dirs: np.ndarray, scene: PlaneScene) -> tuple[np.ndarray, np.ndarray]:
    """Nearest plane hit per ray: (t (H, W) float64, inf for misses; plane index (H, W) int, -1 for misses).

    Args:
        origin: (3,) ray origin in world; dirs: (H, W, 3) ray directions in world (not normalised).
    """
    t_best = np.full(dirs.shape[:2], np.inf)
    idx = np.full(dirs.shape[:2], -1, dtype=np.int32)
    dz = dirs[..., 2]
    for k, plane in enumerate(scene.planes):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane.z_m - origin[2]) / dz
        hit = np.isfinite(t) & (t > 0)
        x = origin[0] + t * dirs[..., 0]
        y = origin[1] + t * dirs[..., 1]
        for coord, (lo, hi) in ((x, plane.x_range_m), (y, plane.y_range_m)):
            if lo is not None:
                hit &= coord >= lo
            if hi is not None:
                hit &= coord <= hi
        closer = hit & (t < t_best)
        t_best[closer] = t[closer]
        idx[closer] = k
    return t_best, idx


_TEXTURES: dict[int, np.ndarray] = {}


def _texture_cached(seed: int) -> np.ndarray:
    if seed not in _TEXTURES:
        _TEXTURES[seed] = texture(seed)
    return _TEXTURES[seed]


def _shade(origin: np.ndarray, dirs: np.ndarray, scene: PlaneScene) -> np.ndarray:
    t, idx = _trace(origin, dirs, scene)
    h, w = idx.shape
    out = np.empty((h, w, 3), np.uint8)
    out[:] = np.asarray(scene.sky_bgr, np.uint8)
    for k, plane in enumerate(scene.planes):
        mask = idx == k
        if not mask.any():
            continue
        tk = np.where(mask, t, 0.0)
        mx = ((origin[0] + tk * dirs[..., 0]) / plane.texel_m).astype(np.float32)
        my = ((origin[1] + tk * dirs[..., 1]) / plane.texel_m).astype(np.float32)
        grey = cv2.remap(_texture_cached(plane.seed), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        for c in range(3):
            chan = np.clip(grey.astype(np.float32) * plane.tint_bgr[c], 0, 255).astype(np.uint8)
            out[..., c][mask] = chan[mask]
    return out


class StereoRenderer:
    """Renders a :class:`PlaneScene` through a rig; caches the per-pixel rays of both cameras.

    Args:
        rig: the stereo rig (raw intrinsics + distortion of both cameras, ``T_right_left``).
        scene: the planes.
    """

    def __init__(self, rig: StereoRig, scene: PlaneScene | None = None) -> None:
        self.rig = rig
        self.scene = scene or PlaneScene()
        self._rays_left = _pixel_rays(rig.left)
        self._rays_right = _pixel_rays(rig.right)
        T_left_right = np.linalg.inv(rig.T_right_left)
        self._R_left_right = T_left_right[:3, :3]
        self._t_left_right = T_left_right[:3, 3]
        w, h = rig.left.size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rect = np.stack([(u - rig.cx) / rig.fx, (v - rig.cy) / rig.P_left[1, 1], np.ones_like(u)], axis=-1)
        self._rays_rect = rect  # in the rectified left frame, z = 1

    def render(self, T_world_left: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Raw (distorted) left and right BGR uint8 images, (H, W, 3), for the left camera at ``T_world_left``."""
        T = np.eye(4) if T_world_left is None else np.asarray(T_world_left, np.float64)
        R, t = T[:3, :3], T[:3, 3]
        left = _shade(t, self._rays_left @ R.T, self.scene)
        R_wr = R @ self._R_left_right
        t_wr = R @ self._t_left_right + t
        right = _shade(t_wr, self._rays_right @ R_wr.T, self.scene)
        return left, right

    def rectified_depth(self, T_world_left: np.ndarray | None = None) -> np.ndarray:
        """Ground-truth depth Z (metres, float32, NaN where no plane) in the rectified left frame, (H, W)."""
        T = np.eye(4) if T_world_left is None else np.asarray(T_world_left, np.float64)
        R_world_rect = T[:3, :3] @ self.rig.R_left.T  # rect → raw left → world
        dirs = self._rays_rect @ R_world_rect.T
        t_hit, idx = _trace(T[:3, 3], dirs, self.scene)
        depth = np.where(idx >= 0, t_hit, np.nan)  # rays have z = 1 in the rectified frame, so t is the depth
        return depth.astype(np.float32)


def render_stereo(rig: StereoRig, scene: PlaneScene | None = None,
                  T_world_left: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-off :meth:`StereoRenderer.render` (builds the ray cache each call; use the class for sequences)."""
    return StereoRenderer(rig, scene).render(T_world_left)


def render_rectified_depth(rig: StereoRig, scene: PlaneScene | None = None,
                           T_world_left: np.ndarray | None = None) -> np.ndarray:
    """One-off :meth:`StereoRenderer.rectified_depth`."""
    return StereoRenderer(rig, scene).rectified_depth(T_world_left)


@dataclass(frozen=True)
class SyntheticBagTruth:
    """What :func:`write_synthetic_bag` wrote, for checks (stamps int64 ns).

    Attributes:
        frame_stamps_ns: (F,). imu_stamps_ns: (N,); imu_gyro, imu_accel: (N, 3) rad/s, m/s².
        gps_stamps_ns: (G,); gps: (G, 3) ``[lat_deg, lon_deg, alt_m]``; gps_vel: (G, 2) ``[east, north]`` m/s.
        odom_stamps_ns: (O,); odom: (O, 5) ``[x, y, yaw, v, yaw_rate]``.
        static_transforms: the ``(parent, child, T_parent_child)`` written with each odometry sample.
        positions_left: (F, 3) left camera position in the world frame at each frame, metres.
        shift_px_per_frame: image shift of the farthest plane between frames, pixels (rectified).
    """

    frame_stamps_ns: np.ndarray
    imu_stamps_ns: np.ndarray
    imu_gyro: np.ndarray
    imu_accel: np.ndarray
    gps_stamps_ns: np.ndarray
    gps: np.ndarray
    gps_vel: np.ndarray
    odom_stamps_ns: np.ndarray
    odom: np.ndarray
    static_transforms: tuple[tuple[str, str, np.ndarray], ...]
    positions_left: np.ndarray
    shift_px_per_frame: float


def write_synthetic_bag(path: Path | str, n_frames: int = 8, rig: StereoRig | None = None, *, seed: int = 0,
                        compression: str | None = None, speed_m_s: float = 0.5,
                        t0_ns: int = 1_600_000_000_000_000_000, scene: PlaneScene | None = None,
                        overwrite: bool = False) -> SyntheticBagTruth:
    """Write a short Rosario-layout bag: the rig slides right (+x of the left camera) at ``speed_m_s``.

    Streams: stereo 15 Hz + camera_info, IMU 142 Hz (zero rotation, constant velocity: gyro = seeded noise,
    accel = gravity reaction in the IMU frame plus noise), GPS fix and velocity 5 Hz, odometry and tf_static
    10 Hz. ``rig`` defaults to the shipped Rosario calibration. Deterministic in ``seed``.
    """
    from pipeline.bag_writer import RosarioBagWriter
    from pipeline.calibration import rig_from_camchain
    from pipeline.paths import ROSARIO_CAMCHAIN

    rig = rig or rig_from_camchain(ROSARIO_CAMCHAIN)
    rng = np.random.default_rng(seed)
    renderer = StereoRenderer(rig, scene)
    dt_cam = 1.0 / RATE_CAMERA_HZ
    duration = n_frames * dt_cam

    def stamps(rate_hz: float) -> np.ndarray:
        n = int(duration * rate_hz) + 1
        return t0_ns + np.round(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)

    frame_t = t0_ns + np.round(np.arange(n_frames) * dt_cam * 1e9).astype(np.int64)
    imu_t, gps_t, odom_t = stamps(142.0), stamps(5.0), stamps(10.0)

    R_imu_left = rig.T_left_imu[:3, :3].T
    g_reaction_world = np.array([0.0, -9.81, 0.0])  # world y points down; the reaction to gravity points up
    gyro = rng.normal(0.0, 0.002, (len(imu_t), 3))
    accel = R_imu_left @ g_reaction_world + rng.normal(0.0, 0.02, (len(imu_t), 3))

    lat0, lon0, alt0 = -33.0337693, -60.8846327, 25.0
    m_per_deg_lon = 111_320.0 * np.cos(np.radians(lat0))
    t_gps_s = (gps_t - t0_ns) / 1e9
    gps = np.stack([np.full_like(t_gps_s, lat0), lon0 + speed_m_s * t_gps_s / m_per_deg_lon,
                    np.full_like(t_gps_s, alt0)], axis=1)
    gps_vel = np.tile([speed_m_s, 0.0], (len(gps_t), 1))
    t_odom_s = (odom_t - t0_ns) / 1e9
    odom = np.stack([speed_m_s * t_odom_s, np.zeros_like(t_odom_s), np.zeros_like(t_odom_s),
                     np.full_like(t_odom_s, speed_m_s), np.zeros_like(t_odom_s)], axis=1)

    T_base_imu = np.eye(4)
    T_base_imu[:3, :3] = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])  # x up, y right, z fwd
    T_base_imu[:3, 3] = (1.96, -0.017, 1.02)
    T_base_gps = np.eye(4)
    T_base_gps[:3, 3] = (1.80, -0.03, 1.59)
    statics = (("base_link", "imu", T_base_imu), ("imu", "left", np.linalg.inv(rig.T_left_imu)),
               ("imu", "right", np.linalg.inv(rig.T_right_imu)), ("base_link", "gps", T_base_gps))

    positions = np.zeros((n_frames, 3))
    events = sorted([(int(t), 0, i) for i, t in enumerate(frame_t)] + [(int(t), 1, i) for i, t in enumerate(imu_t)]
                    + [(int(t), 2, i) for i, t in enumerate(gps_t)] + [(int(t), 3, i) for i, t in enumerate(odom_t)])
    with RosarioBagWriter(path, compression=compression, overwrite=overwrite) as w:
        w.set_camera_info(rig)
        for t, kind, i in events:
            if kind == 0:
                pose = np.eye(4)
                pose[0, 3] = speed_m_s * (t - t0_ns) / 1e9
                positions[i] = pose[:3, 3]
                w.write_stereo(t, *renderer.render(pose))
            elif kind == 1:
                w.write_imu(t, gyro[i], accel[i])
            elif kind == 2:
                w.write_gps_fix(t, *gps[i])
                w.write_gps_vel(t, *gps_vel[i])
            else:
                w.write_odom(t, *odom[i])
                w.write_tf_static(t, statics)
    far_z = max(p.z_m for p in renderer.scene.planes)
    return SyntheticBagTruth(frame_t, imu_t, gyro, accel, gps_t, gps, gps_vel, odom_t, odom, statics, positions,
                             rig.fx * speed_m_s * dt_cam / far_z)
