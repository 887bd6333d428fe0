"""A tiny exact renderer for front-end tests and benchmarks: textured planes seen through the Rosario rig.

Every raw pixel's ray (undistorted through the camera model) is intersected with a textured plane, so a 3-D
point, its raw pixel in either camera and its rectified depth agree exactly (up to texture interpolation).
Used by the front-end tests (tests/test_msckf_frontend.py, tests/test_msckf_vio.py) and
benchmarks/bench_frontend.py; the renderer's own sanity tests are tests/test_plane_scene.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import yaml

from msckf.camera import PinholeRadtan, StereoRig
from pipeline.paths import ROSARIO_CAMCHAIN


@lru_cache(maxsize=1)
def scene_rig() -> StereoRig:
    """The Rosario rig (Kalibr camchain shipped in data/), rectified with OpenCV."""
    chain = yaml.safe_load(ROSARIO_CAMCHAIN.read_text())

    def cam(c: dict) -> PinholeRadtan:
        fx, fy, cx, cy = c["intrinsics"]
        return PinholeRadtan(*c["resolution"], fx, fy, cx, cy, tuple(c["distortion_coeffs"]))

    return StereoRig.from_extrinsics(cam(chain["cam0"]), cam(chain["cam1"]), np.array(chain["cam1"]["T_cn_cnm1"]),
                                     np.array(chain["cam0"]["T_cam_imu"]))


@lru_cache(maxsize=8)
def _pixel_rays(camera: PinholeRadtan) -> np.ndarray:
    """(H, W, 3) rays (Z = 1) of every raw pixel of ``camera``."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    xy = camera.undistort_points(np.stack([u.ravel(), v.ravel()], axis=1))
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return rays.reshape(camera.height, camera.width, 3)


def make_texture(seed: int, size: int = 2048) -> np.ndarray:
    """(size, size) float32 texture in [0, 255]: multi-scale blurred noise (corners for FAST, gradients for KLT)."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size), np.float32)
    for sigma, weight in ((1.5, 1.0), (4.0, 1.5), (12.0, 2.0)):
        noise = rng.standard_normal((size, size)).astype(np.float32)
        layer = cv2.GaussianBlur(noise, (0, 0), sigma)
        tex += weight * layer / layer.std()
    tex -= tex.min()
    return (255.0 * tex / tex.max()).astype(np.float32)


@dataclass(frozen=True)
class Plane:
    """A textured plane ``{X : n·X = d}`` in the world frame, texture axes ``e1``, ``e2`` (unit, in-plane).

    Texture pixel ``(i, j)`` (column, row) sits at ``origin + (i - W/2) s e1 + (j - H/2) s e2`` with ``s`` =
    ``metres_per_texel``.
    """

    normal: np.ndarray
    d: float
    e1: np.ndarray
    e2: np.ndarray
    texture: np.ndarray
    metres_per_texel: float

    @classmethod
    def wall(cls, z: float, texture: np.ndarray, metres_per_texel: float = 0.005) -> Plane:
        """A fronto-parallel wall at world Z = ``z`` (world axes = camera axes at the identity pose)."""
        return cls(np.array([0.0, 0.0, 1.0]), float(z), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                   texture, metres_per_texel)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray parameters ``lam`` (...,) and world points (..., 3) of rays ``origin + lam * dirs``."""
        denom = dirs @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (self.d - origin @ self.normal) / denom
        return lam, origin + lam[..., None] * dirs

    def texel(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) texture coordinates of world points on the plane."""
        p0 = self.normal * self.d
        rel = points - p0
        h, w = self.texture.shape
        return np.stack([rel @ self.e1 / self.metres_per_texel + w / 2, rel @ self.e2 / self.metres_per_texel + h / 2],
                        axis=-1)


def _first_hit(origin: np.ndarray, dirs: np.ndarray, planes: Plane | list[Plane]) -> tuple[np.ndarray, np.ndarray]:
    """Nearest positive ray parameter over ``planes`` (z-buffer) and the index of the plane hit (-1: none)."""
    planes = [planes] if isinstance(planes, Plane) else list(planes)
    best = np.full(dirs.shape[:-1], np.inf)
    which = np.full(dirs.shape[:-1], -1)
    for k, plane in enumerate(planes):
        lam, _ = plane.intersect(origin, dirs)
        hit = (lam > 0) & (lam < best)
        best[hit] = lam[hit]
        which[hit] = k
    return best, which


_MIP_CACHE: dict[int, list[np.ndarray]] = {}


def _mip_levels(texture: np.ndarray) -> list[np.ndarray]:
    key = id(texture)
    if key not in _MIP_CACHE:
        levels = [texture]
        while min(levels[-1].shape) > 8:
            levels.append(cv2.pyrDown(levels[-1], borderType=cv2.BORDER_REFLECT_101))
        _MIP_CACHE[key] = levels
    return _MIP_CACHE[key]


def _sample_mipmapped(texture: np.ndarray, tex: np.ndarray) -> np.ndarray:
    """Trilinear (mip-mapped) texture look-up at (H, W, 2) texel coordinates: no aliasing where a pixel covers
    many texels (a ground plane at a grazing angle), plain bilinear where it covers one or fewer."""
    levels = _mip_levels(texture)
    du = np.gradient(tex, axis=1)
    dv = np.gradient(tex, axis=0)
    foot = np.maximum(np.hypot(du[..., 0], du[..., 1]), np.hypot(dv[..., 0], dv[..., 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        lev = np.clip(np.nan_to_num(np.log2(foot), nan=len(levels) - 1.0), 0.0, len(levels) - 1.0)
    lo = np.floor(lev).astype(int)
    frac = (lev - lo).astype(np.float32)
    out = np.zeros(tex.shape[:2], np.float32)
    for k in range(int(lo.min()), min(int(lo.max()) + 2, len(levels))):
        weight = np.where(lo == k, 1.0 - frac, 0.0) + np.where(lo + 1 == k, frac, 0.0)
        if not weight.any():
            continue
        scale = 2.0 ** k      # pixel centres: x_k = (x + 0.5) / 2^k - 0.5
        map_x = ((tex[..., 0] + 0.5) / scale - 0.5).astype(np.float32)
        map_y = ((tex[..., 1] + 0.5) / scale - 0.5).astype(np.float32)
        out += weight * cv2.remap(levels[k], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    return out


def render(camera: PinholeRadtan, T_cam_world: np.ndarray, planes: Plane | list[Plane]) -> np.ndarray:
    """Raw (distorted) uint8 grey image of ``planes`` (z-buffered) seen by ``camera`` at ``T_cam_world`` (4×4).

    Textures are mip-mapped (no aliasing at grazing angles) and mirrored outside their extent; pixels whose ray
    hits no plane are 0 (a featureless sky).
    """
    planes = [planes] if isinstance(planes, Plane) else list(planes)
    T_world_cam = np.linalg.inv(T_cam_world)
    origin = T_world_cam[:3, 3]
    dirs = _pixel_rays(camera) @ T_world_cam[:3, :3].T
    _, which = _first_hit(origin, dirs, planes)
    img = np.zeros(which.shape, np.float32)
    for k, plane in enumerate(planes):
        if not np.any(which == k):
            continue
        lam, pts = plane.intersect(origin, dirs)   # this plane's own hits, occluded or not: smooth gradients
        tex = plane.texel(np.where((lam > 0)[..., None], pts, origin))
        img += np.where(which == k, _sample_mipmapped(plane.texture, tex), 0.0)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def rectified_depth(rig: StereoRig, T_cam0_world: np.ndarray, planes: Plane | list[Plane]) -> np.ndarray:
    """(H, W) float32 depth Z (metres) in the rectified left frame seen from cam0 at ``T_cam0_world``; NaN: sky."""
    h, w = rig.left.height, rig.left.width
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays_rect = np.stack([(u - rig.cx) / rig.fx, (v - rig.cy) / rig.P_left[1, 1], np.ones_like(u)], axis=-1)
    rays_cam0 = rays_rect @ rig.R_left   # R_left^T applied to row vectors
    T_world_cam = np.linalg.inv(T_cam0_world)
    lam, which = _first_hit(T_world_cam[:3, 3], rays_cam0 @ T_world_cam[:3, :3].T, planes)
    return np.where(which >= 0, lam, np.nan).astype(np.float32)   # rays_rect has Z = 1, so lam is Z_rect


def world_points(camera: PinholeRadtan, T_cam_world: np.ndarray, px: np.ndarray,
                 planes: Plane | list[Plane]) -> np.ndarray:
    """(N, 3) world points (z-buffered) seen at raw pixels ``px`` (N, 2) of ``camera`` at ``T_cam_world``; NaN: sky."""
    T_world_cam = np.linalg.inv(T_cam_world)
    dirs = camera.unproject(px) @ T_world_cam[:3, :3].T
    lam, which = _first_hit(T_world_cam[:3, 3], dirs, planes)
    pts = T_world_cam[:3, 3] + lam[:, None] * dirs
    pts[which < 0] = np.nan
    return pts


def pose(rotvec: np.ndarray | tuple = (0.0, 0.0, 0.0), centre: np.ndarray | tuple = (0.0, 0.0, 0.0)) -> np.ndarray:
    """``T_cam_world`` of a camera with orientation ``R_world_cam = exp(rotvec)`` at world position ``centre``."""
    R_wc = cv2.Rodrigues(np.asarray(rotvec, dtype=np.float64))[0]
    T = np.eye(4)
    T[:3, :3] = R_wc.T
    T[:3, 3] = -R_wc.T @ np.asarray(centre, dtype=np.float64)
    return T


def stereo_pose(rig: StereoRig, T_cam0_world: np.ndarray) -> np.ndarray:
    """``T_cam1_world`` of the right camera."""
    return rig.T_right_left @ T_cam0_world


def pose_from(R_world_cam: np.ndarray, centre: np.ndarray | tuple) -> np.ndarray:
    """``T_cam_world`` of a camera with orientation ``R_world_cam`` (3×3) at world position ``centre``."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R_world_cam).T
    T[:3, 3] = -T[:3, :3] @ np.asarray(centre, dtype=np.float64)
    return T


def gyro_samples(pose_fn, t0: float, t1: float, rate_hz: float, R_cam_imu: np.ndarray
                 ) -> list[tuple[float, np.ndarray]]:
    """IMU-frame gyro samples (rad/s) at ``rate_hz`` over ``(t0, t1]`` of a camera moving as ``pose_fn(t)``.

    ``pose_fn(t)`` returns ``T_cam_world``; the rate is the central finite difference of the camera rotation,
    rotated into the IMU frame with ``R_cam_imu``.
    """
    out = []
    n = max(1, int(round((t1 - t0) * rate_hz)))
    h = 1e-4
    for t in np.linspace(t0, t1, n + 1)[1:]:
        R_a = pose_fn(t - h)[:3, :3].T   # R_world_cam
        R_b = pose_fn(t + h)[:3, :3].T
        w_cam = cv2.Rodrigues(R_a.T @ R_b)[0].ravel() / (2 * h)
        out.append((float(t), R_cam_imu.T @ w_cam))
    return out
