"""CPU renderer of the field through the Rosario stereo rig (numpy/OpenCV/numba, headless).

Per camera and frame:

1. An *ideal* pinhole image is rendered in the camera's **rectified** frame (``p_rect = R_rect · p_raw_cam``) with
   the rectified intrinsics (``P_left``/``P_right``) and an integer margin, so that it covers every ray of the raw
   distorted image. Rays have ``z = 1`` in that frame, so a ray parameter *is* the rectified depth ``Z``.
2. Surfaces: terrain (heightfield, Newton ray intersection), the far canopy plane, two tree lines
   (ray/cylinder), and planar polygons (leaflets, weeds, canopy prisms) drawn far-to-near into an id buffer
   (filled like ``cv2.fillPoly``); each id pixel then gets its exact depth from the ray/plane intersection and
   wins over the terrain only where it is nearer (a per-pixel z-test).
3. Shading in linear radiance: sun (Lambert, leaf translucency, glossy highlights) with leaf shadows from a
   shadow map, sky light with ambient occlusion, bump-mapped soil, mip-mapped textures, sky with clouds and the
   sun, aerial haze, veiling glare and lens-flare ghosts when the sun is near the view.
4. Camera: exposure, optics blur (on linear radiance), vignetting, per-camera gain, gamma, shot and read noise,
   8-bit BGR. The raw (distorted) image is shaded directly from one ray per raw pixel (the calibration's exact
   undistortion of every pixel, computed once), so no resampling blurs it.

The per-ray and per-pixel loops (terrain intersection, surface tracing, polygon projection and raster, texture
sampling, polygon and soil shading, leaf shadows, glare and haze, sensor) are numba kernels in
``pipeline/sim/*_kernels.py``; numpy and OpenCV do the rest.

Depth comes from the same z-buffer: ``Z`` in the rectified camera frame, metres (``inf`` for the sky). A 3-D
point, its pixel and its depth therefore agree exactly.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from msckf.camera import PinholeRadtan, StereoRig
from pipeline.sim.config import CameraConfig, FieldConfig, LightingConfig, RenderConfig
from pipeline.sim.ground_kernels import atlas_occlusion, soil_footprints, soil_radiance
from pipeline.sim.lighting import SUN_RADIUS_RAD, Sky
from pipeline.sim.noise import MipTexture, fbm, sample_level, smooth_noise_1d
from pipeline.sim.optics_kernels import glare_field, haze_and_glare
from pipeline.sim.shade_kernels import poly_radiance, poly_surface_coords, sensor_digitise, sensor_linear
from pipeline.sim.terrain import Terrain
from pipeline.sim.textures import SoilTextures, make_foliage, make_soil, make_trees
from pipeline.sim.trace_kernels import (
    LABEL_CANOPY,
    LABEL_LEAF,
    LABEL_SKY,
    LABEL_SOIL,
    LABEL_TREES,
    project_polygons,
    raster_polygons,
    trace_surfaces,
)
from pipeline.sim.world import (
    MAT_CANOPY,
    MAT_LEAF,
    PRISM1_RANGE_M,
    SHADOW_NONE,
    SHADOW_TEXEL_M,
    SHADOW_TILE_M,
    Field,
    PolySet,
)

LABEL_NAMES = {LABEL_SKY: "sky", LABEL_SOIL: "soil", LABEL_LEAF: "leaf", LABEL_CANOPY: "canopy",
               LABEL_TREES: "trees"}
T_MAX_M = 4000.0
NEAR_M = 0.05
_F32 = np.float32
_NO_ATLAS = np.zeros((1, 1), np.float32)  # the shadow-map argument of a frame without one
_NO_GLARE = np.zeros(1, np.float32)  # the glare argument of an image without glare


@dataclass
class RayBundle:
    """A fixed set of camera rays laid out as an image.

    Attributes:
        rays: (H, W, 3) float32 directions in the rectified camera frame, scaled to z = 1 (so a ray parameter is
            the rectified depth Z).
        ray_norm: (H, W) float32 length of each ray (metres of path per metre of depth).
        raster_x, raster_y: (H, W) int32 nearest pixel of the camera's polygon raster.
        pixel_angle: angular size of a pixel, rad.
    """

    rays: np.ndarray
    ray_norm: np.ndarray
    raster_x: np.ndarray
    raster_y: np.ndarray
    pixel_angle: float


@dataclass
class CameraView:
    """Fixed geometry of one camera.

    Attributes:
        name: ``"left"`` or ``"right"``.
        raw: the raw camera model.
        R_rect: (3, 3) rectification rotation, ``p_rect = R_rect · p_raw_cam``.
        fx, fy, cx, cy: intrinsics of the polygon raster (rectified focal length, principal point shifted by the
            margin), px.
        width, height: raster size, px (covers every raw ray plus a margin).
        margin: (mx, my) integer offset of the rectified image inside the raster.
        raw_bundle: one ray per raw (distorted) image pixel: the image is shaded from these.
        rect_bundle: one ray per rectified image pixel centre: the ground-truth depth is traced from these.
        vignette: (H_raw, W_raw) float32 brightness factor.
    """

    name: str
    raw: PinholeRadtan
    R_rect: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    margin: tuple[int, int]
    raw_bundle: RayBundle
    rect_bundle: RayBundle
    vignette: np.ndarray


def make_view(name: str, cam: PinholeRadtan, R_rect: np.ndarray, P_rect: np.ndarray, margin_px: int,
              vignetting: float) -> CameraView:
    """Ray bundles, raster geometry and vignetting of one camera (computed once)."""
    w, h = cam.width, cam.height
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = cam.undistort_points(np.stack([uu.ravel(), vv.ravel()], 1))
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ np.asarray(R_rect).T
    rays = rays / rays[:, 2:3]
    fx, fy = float(P_rect[0, 0]), float(P_rect[1, 1])
    cx, cy = float(P_rect[0, 2]), float(P_rect[1, 2])
    u_i = fx * rays[:, 0] + cx
    v_i = fy * rays[:, 1] + cy
    mx = int(np.ceil(-(min(u_i.min(), 0.0) - margin_px)))
    my = int(np.ceil(-(min(v_i.min(), 0.0) - margin_px)))
    width = int(np.ceil(max(u_i.max(), w - 1.0) + margin_px)) + mx + 1
    height = int(np.ceil(max(v_i.max(), h - 1.0) + margin_px)) + my + 1

    def bundle(r: np.ndarray, ux: np.ndarray, vy: np.ndarray) -> RayBundle:
        r = r.reshape(h, w, 3).astype(np.float32)
        return RayBundle(r, np.linalg.norm(r, axis=-1).astype(np.float32),
                         np.clip(np.rint(ux), 0, width - 1).astype(np.int32).reshape(h, w),
                         np.clip(np.rint(vy), 0, height - 1).astype(np.int32).reshape(h, w), 1.0 / fx)

    raw_bundle = bundle(rays, u_i + mx, v_i + my)
    rect_rays = np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones_like(uu)], -1).reshape(-1, 3)
    rect_bundle = bundle(rect_rays, uu.ravel() + mx, vv.ravel() + my)
    r2 = ((uu - cam.cx) / cam.fx) ** 2 + ((vv - cam.cy) / cam.fy) ** 2
    fall = 1.0 / (1.0 + r2) ** 2
    vig = 1.0 - vignetting * (1.0 - fall) / max(1.0 - fall.min(), 1e-6)
    return CameraView(name, cam, np.asarray(R_rect, np.float64), fx, fy, cx + mx, cy + my, width, height, (mx, my),
                      raw_bundle, rect_bundle, vig.astype(np.float32))


@dataclass
class Trace:
    """Surfaces hit by a ray bundle.

    Attributes:
        dirs: (H, W, 3) float32 field-frame ray directions (rectified z = 1).
        t: (H, W) float32 ray parameter = rectified depth Z, metres (``inf``: sky).
        label: (H, W) uint8 ``LABEL_*``.
        hgx, hgy: (H, W) float32 terrain slopes at the terrain hit.
        canopy: (H, W) bool, far canopy plane visible.
        poly_px, poly_k: flat pixel indices where a polygon is visible, and its index in the polygon set.
        trees: per tree line ``(flat pixel indices, arc length along the line, hit height, line index)``.
    """

    dirs: np.ndarray
    t: np.ndarray
    label: np.ndarray
    hgx: np.ndarray
    hgy: np.ndarray
    canopy: np.ndarray
    poly_px: np.ndarray
    poly_k: np.ndarray
    trees: list


@dataclass
class StereoRender:
    """One rendered stereo frame.

    Attributes:
        left_bgr, right_bgr: (376, 672, 3) uint8 raw (distorted) BGR images.
        depth: (376, 672) float32 depth Z in the rectified left camera frame, metres (``inf``: sky).
        label: (376, 672) uint8 ``LABEL_*`` of the rectified left pixels.
        glare: (376, 672) float32 sensor level of sun glare (veil + flare) at the rectified left pixels (0..).
        right_depth, right_label: the same for the rectified right camera (only when requested).
        mean_level: mean sensor level of the left image before noise, 0..1 (auto-exposure input).
    """

    left_bgr: np.ndarray
    right_bgr: np.ndarray
    depth: np.ndarray
    label: np.ndarray
    glare: np.ndarray
    right_depth: np.ndarray | None
    right_label: np.ndarray | None
    mean_level: float


# columns of the per-frame polygon attribute table (float32): e1 0-2, e2 3-5, normal 6-8, albedo 9-11, size, extra,
# ground height, radius (the kernels read it by these positions)
_EXTRA, _GROUND = 13, 14


def poly_table(polys: PolySet) -> np.ndarray:
    """(N, 16) float32 attributes of a polygon set: e1, e2, normal, albedo, size, extra, ground height, radius."""
    return np.concatenate([polys.e1, polys.e2, polys.normal, polys.albedo, polys.size[:, None],
                           polys.extra[:, None], polys.ground[:, None], polys.radius[:, None]], 1).astype(np.float32)


@lru_cache(maxsize=4)
def _cached_soil(field_cfg: FieldConfig, seed: int) -> SoilTextures:
    return make_soil(field_cfg, seed)


@lru_cache(maxsize=4)
def _cached_foliage(seed: int) -> MipTexture:
    return make_foliage(seed)


@lru_cache(maxsize=4)
def _cached_trees(seed: int) -> MipTexture:
    return make_trees(seed)


class FieldRenderer:
    """Renders the field for a stereo rig.

    Args:
        rig: the calibration (raw intrinsics/distortion, rectification) the images must obey.
        field_cfg, lighting, camera, render: configuration sections.
        seed: world seed (geometry and textures).
        threads: 2 renders the right camera in a second thread (numpy and OpenCV release the GIL); the result
            does not depend on it.
    """

    def __init__(self, rig: StereoRig, field_cfg: FieldConfig, lighting: LightingConfig, camera: CameraConfig,
                 render: RenderConfig, seed: int, threads: int = 2) -> None:
        self.rig = rig
        self.cfg_field = field_cfg
        self.cfg_light = lighting
        self.cfg_cam = camera
        self.cfg_render = render
        self.seed = int(seed)
        centre = ((field_cfg.n_rows - 1) * field_cfg.row_spacing_m / 2, field_cfg.row_length_m / 2)
        self.terrain = Terrain(field_cfg, seed, centre)
        self.field = Field(field_cfg, seed, self.terrain)
        self.sky = Sky(lighting, field_cfg.azimuth_deg, seed)
        self.field.sun_dir = self.sky.sun_dir
        self.soil: SoilTextures = _cached_soil(field_cfg, int(seed))
        self.foliage: MipTexture = _cached_foliage(int(seed))
        self.trees_tex: MipTexture = _cached_trees(int(seed))
        #: extra polygons drawn in every frame (e.g. a calibration marker in tests)
        self.extra_polys: PolySet | None = None
        rng = np.random.default_rng([seed, 401])
        self.leaf_noise = MipTexture.from_image((1.0 + 0.09 * fbm(rng, 128, ((0.7, 0.6), (2.5, 0.8)))).astype(
            np.float32), 0.0015)
        self.left = make_view("left", rig.left, rig.R_left, rig.P_left, render.margin_px, camera.vignetting)
        self.right = make_view("right", rig.right, rig.R_right, rig.P_right, render.margin_px, camera.vignetting)
        n = 8192
        tree_profiles = []
        for base, amp, gap in ((11.0, 5.0, -0.9), (9.0, 4.0, -1.6)):
            lo = smooth_noise_1d(rng, n, 40.0)
            hgt = base + amp * lo + 1.6 * smooth_noise_1d(rng, n, 6.0) + 0.6 * smooth_noise_1d(rng, n, 1.2)
            hgt[lo < gap] = 0.0
            tree_profiles.append(np.maximum(hgt, 0.0).astype(np.float32))
        self.tree_profiles = np.stack(tree_profiles)  # (2, n) tree-top heights along each tree line, m
        self.tree_top = self.tree_profiles.max(axis=1).astype(np.float64)  # (2,) highest tree of each line, m
        self.centre = np.array(centre)
        self.tree_radii = (render.treeline_radius_m, render.treeline_radius_m * 3.2)
        hc = self.field.canopy_height()
        #: far canopy plane ``(height, x0, x1, y0, y1, min_range)`` (trace_kernels.trace_surfaces)
        self._canopy_box = np.array([hc, *self.field.row_extent, PRISM1_RANGE_M], np.float64)
        #: rows for the soil's row shadow ``(spacing, canopy height, half width, x0, x1, y0, y1)`` (ground_kernels)
        self._row_params = np.array([field_cfg.row_spacing_m, hc, float(self.field.canopy_half_width(np.array(hc))),
                                     *self.field.row_extent], np.float64)
        self._pool: ThreadPoolExecutor | None = ThreadPoolExecutor(1) if threads > 1 else None

    # ---- per-frame helpers -----------------------------------------------------------------------------------------
    def select_polys(self, cam_xy: np.ndarray, fwd_xy: np.ndarray) -> PolySet:
        """Leaves and canopy prisms around a camera position (one set for both cameras of a frame)."""
        n = float(np.hypot(*fwd_xy))
        fwd = np.asarray(fwd_xy, np.float64) / n if n > 1e-6 else np.array([0.0, 1.0])
        leaves, prisms = self.field.select(np.asarray(cam_xy, np.float64), fwd, self.cfg_render.leaf_range_m,
                                           np.radians(64))
        extra = [self.extra_polys] if self.extra_polys is not None else []
        return PolySet.concat([leaves, prisms, *extra])

    def shadow_atlas(self, cam_xy: np.ndarray, fwd_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Leaf shadow-height atlas around the camera: (map, (x0, y0) of its corner), or None away from rows."""
        rng_m = self.cfg_render.shadow_range_m
        x0, x1, y0, y1 = self.field.row_extent
        disp = np.abs(self.sky.sun_dir[:2]) / max(self.sky.sun_dir[2], 0.05) * (1.7 * self.cfg_field.plant_height_m)
        lo = np.maximum(cam_xy - rng_m, np.array([x0, y0]) - disp - 0.4)
        hi = np.minimum(cam_xy + rng_m, np.array([x1, y1]) + disp + 0.4)
        if np.any(hi <= lo):
            return None
        t_lo = np.floor(lo / SHADOW_TILE_M).astype(int)
        t_hi = np.floor(hi / SHADOW_TILE_M).astype(int)
        n = int(round(SHADOW_TILE_M / SHADOW_TEXEL_M))
        atlas = np.full(((t_hi[1] - t_lo[1] + 1) * n, (t_hi[0] - t_lo[0] + 1) * n), SHADOW_NONE, np.float32)
        for tx in range(t_lo[0], t_hi[0] + 1):
            for ty in range(t_lo[1], t_hi[1] + 1):
                c = (np.array([tx, ty]) + 0.5) * SHADOW_TILE_M - cam_xy
                dist = float(np.hypot(*c))
                if dist > rng_m + 1.5 * SHADOW_TILE_M:
                    continue
                if dist > 2 * SHADOW_TILE_M and float(np.dot(c, fwd_xy)) < -0.3 * dist:
                    continue  # well behind the camera
                ix, iy = tx - t_lo[0], ty - t_lo[1]
                atlas[iy * n:(iy + 1) * n, ix * n:(ix + 1) * n] = self.field.shadow_tile(tx, ty)
        return atlas, t_lo * SHADOW_TILE_M

    def _shadow(self, atlas: tuple[np.ndarray, np.ndarray] | None, px: np.ndarray, py: np.ndarray, pz: np.ndarray,
                hz: np.ndarray, tol: float) -> np.ndarray:
        """Fraction (0..1) of sun blocked by leaves at points (N,) with height above ground ``hz``."""
        out = np.zeros(px.shape, np.float32)
        if atlas is None or not px.size:
            return out
        amap, corner = atlas
        disp = -self.sky.sun_dir[:2] / max(self.sky.sun_dir[2], 0.05)
        atlas_occlusion(amap, np.asarray(corner, np.float64), np.asarray(disp, np.float64), SHADOW_TEXEL_M, px, py,
                        pz, hz, float(tol), out)
        return out

    # ---- main entry --------------------------------------------------------------------------------------------------
    def render_frame(self, T_F_imu: np.ndarray, t_s: float, exposure: float, sun_e: float, noise_left: np.ndarray,
                     noise_right: np.ndarray, right_depth: bool = False) -> StereoRender:
        """Render a stereo frame.

        Args:
            T_F_imu: (4, 4) IMU pose in the field frame (maps IMU points into F) at the exposure time.
            t_s: time since the sequence start (clouds drift), seconds.
            exposure: multiplier from radiance to sensor level (1 = full scale), shared by both cameras.
            sun_e: direct sun irradiance (relative units; see :mod:`pipeline.sim.lighting`).
            noise_left, noise_right: (376, 672, 3) float32 standard-normal samples for the sensor noise.
            right_depth: also trace the rectified right camera's depth and labels (for occlusion analysis).
        """
        from pipeline.sim.mount import camera_poses

        T_L, T_R = camera_poses(T_F_imu, self.rig)
        mid = 0.5 * (T_L[:3, 3] + T_R[:3, 3])
        fwd = T_L[:3, 2][:2]
        polys = self.select_polys(mid[:2], fwd)
        polys.table = poly_table(polys)
        atlas = self.shadow_atlas(mid[:2], fwd)
        cam = self.cfg_cam

        def left_job() -> tuple:
            ids = self._raster(self.left, T_L, polys)
            tr = self._trace(self.left.raw_bundle, T_L, polys, ids, mid[:2])
            rad, _ = self._shade(self.left.raw_bundle, tr, T_L, polys, t_s, sun_e, atlas)
            img, level = self._camera(self.left, rad, exposure, noise_left, 1.0, 0.0)
            rect = self._trace(self.left.rect_bundle, T_L, polys, ids, mid[:2])
            g = self._glare(self.left.rect_bundle, rect.dirs, T_L[:3, :3], sun_e)
            glare = np.zeros(rect.t.shape, np.float32) if g is None else g * _F32(exposure)
            return img, level, rect, glare

        def right_job() -> tuple:
            ids = self._raster(self.right, T_R, polys)
            tr = self._trace(self.right.raw_bundle, T_R, polys, ids, mid[:2])
            rad, _ = self._shade(self.right.raw_bundle, tr, T_R, polys, t_s, sun_e, atlas)
            img, _ = self._camera(self.right, rad, exposure, noise_right, cam.right_gain, cam.right_offset_dn)
            rect = self._trace(self.right.rect_bundle, T_R, polys, ids, mid[:2]) if right_depth else None
            return img, rect

        if self._pool is not None:
            fut = self._pool.submit(right_job)
            left, mean_level, rect_l, glare = left_job()
            right, rect_r = fut.result()
        else:
            left, mean_level, rect_l, glare = left_job()
            right, rect_r = right_job()
        rd = rl = None
        if rect_r is not None:
            rd, rl = rect_r.t, rect_r.label
        return StereoRender(left, right, rect_l.t, rect_l.label, glare, rd, rl, mean_level)

    def _trace(self, bundle: RayBundle, T_F_rect: np.ndarray, polys: PolySet, ids: np.ndarray,
               ref_xy: np.ndarray) -> Trace:
        """Nearest surface along every ray of ``bundle`` (camera pose ``T_F_rect``; polygon raster ``ids``;
        ``ref_xy`` the frame's level-of-detail reference point, shared by both cameras)."""
        R = np.asarray(T_F_rect[:3, :3], np.float64)
        o = np.asarray(T_F_rect[:3, 3], np.float64)
        dirs = cv2.transform(bundle.rays, R.astype(np.float32))  # (H, W, 3), rectified z = 1
        H, W = dirs.shape[:2]
        t, _, hgx, hgy = self.terrain.intersect_image(o, dirs, T_MAX_M, ref_xy=ref_xy)
        n = H * W
        label = np.empty((H, W), np.uint8)
        canopy = np.empty((H, W), bool)
        tree_k = np.empty(n, np.int8)
        tree_arc = np.zeros(n, np.float32)
        tree_z = np.zeros(n, np.float32)
        pk = np.empty(n, np.int32)
        tab = polys.table if polys.table is not None else poly_table(polys)
        trace_surfaces(dirs.reshape(-1, 3), bundle.ray_norm.reshape(-1), o, t.reshape(-1), label.reshape(-1),
                       canopy.reshape(-1),
                       self._canopy_box,
                       self.centre, np.asarray(self.tree_radii, np.float64), self.tree_profiles,
                       self.tree_top, tree_k, tree_arc,
                       tree_z, ids, bundle.raster_x.reshape(-1), bundle.raster_y.reshape(-1), tab,
                       (polys.origin - o).astype(np.float32), polys.material == MAT_CANOPY,
                       float(bundle.pixel_angle), NEAR_M, pk)
        trees = []
        for k in range(len(self.tree_radii)):
            sel = np.flatnonzero(tree_k == k)
            trees.append((sel, tree_arc[sel], tree_z[sel], k))
        poly_px = np.flatnonzero(pk >= 0)
        poly_k = pk[poly_px].astype(np.int64)
        return Trace(dirs, t, label, hgx, hgy, canopy, poly_px, poly_k, trees)

    def _shade(self, bundle: RayBundle, tr: Trace, T_F_rect: np.ndarray, polys: PolySet, t_s: float, sun_e: float,
               atlas) -> tuple[np.ndarray, np.ndarray]:
        """Linear radiance (H, W, 3) and glare radiance (H, W) of a traced bundle."""
        o = np.asarray(T_F_rect[:3, 3], np.float64)
        H, W = tr.t.shape
        rad = np.zeros((H, W, 3), np.float32)
        glare_rad = np.zeros(H * W, np.float32)
        flat = rad.reshape(-1, 3)
        fd = tr.dirs.reshape(-1, 3)
        flat_t = tr.t.reshape(-1)
        norm_d = bundle.ray_norm.reshape(-1)
        soil = tr.label == LABEL_SOIL
        if soil.any():
            self._shade_soil(bundle, o, tr, soil, sun_e, atlas, rad)
        cpl = np.flatnonzero(tr.canopy.reshape(-1))
        if cpl.size:
            px = _F32(o[0]) + flat_t[cpl] * fd[cpl, 0]
            py = _F32(o[1]) + flat_t[cpl] * fd[cpl, 1]
            fp = flat_t[cpl] * norm_d[cpl] * _F32(bundle.pixel_angle) / \
                np.sqrt(np.maximum(-fd[cpl, 2] / norm_d[cpl], 0.03))
            flat[cpl] = self.foliage.sample(px * 7.3, py, fp) * _F32(0.75 + sun_e * 0.6 * self.sky.sun_dir[2])
        if tr.poly_px.size:
            self._shade_polys(bundle, o, tr, polys, sun_e, atlas, flat, glare_rad)
        for sel, arc, zt, k in tr.trees:
            if sel.size:
                fp = flat_t[sel] * norm_d[sel] * bundle.pixel_angle
                shade = (0.75 + 0.25 * np.clip(zt / 12.0, 0, 1)).astype(np.float32)
                flat[sel] = self.trees_tex.sample(arc, zt + 50.0 * k, fp) * _F32(0.9 + 0.14 * sun_e) * shade[:, None]
        sky = tr.label == LABEL_SKY
        if sky.any():
            self._shade_sky(bundle, tr.dirs, sky, o, t_s, sun_e, rad)
        g = self._glare(bundle, tr.dirs, T_F_rect[:3, :3], sun_e)
        haze_and_glare(sky.reshape(-1), flat_t, norm_d, float(self.cfg_light.haze / 3000.0), self.sky.horizon,
                       _NO_GLARE if g is None else g.reshape(-1), g is not None, flat, glare_rad)
        return rad, glare_rad.reshape(H, W)

    def _camera(self, view: CameraView, rad: np.ndarray, exposure: float, noise: np.ndarray, gain: float,
                offset_dn: float) -> tuple[np.ndarray, float]:
        """Sensor model: exposure, optics blur, vignetting and gain, gamma, noise → (uint8 BGR, mean level)."""
        lin = rad * _F32(exposure)
        if self.cfg_cam.blur_sigma_px > 0:
            lin = cv2.GaussianBlur(lin, (0, 0), self.cfg_cam.blur_sigma_px)
        val = np.empty_like(lin)
        sensor_linear(lin, view.vignette, float(gain), val)
        val **= _F32(1 / 2.2)  # numpy's vectorised power (a compiled loop calling powf per value is slower)
        bgr = np.empty(val.shape, np.uint8)
        mean_level = sensor_digitise(val, float(offset_dn), float(self.cfg_cam.read_noise_dn),
                                     float(self.cfg_cam.shot_noise), noise, bgr)
        return bgr, mean_level

    # ---- pieces -----------------------------------------------------------------------------------------------
    def _raster(self, view: CameraView, T_F_rect: np.ndarray, polys: PolySet) -> np.ndarray:
        """Polygon id raster (H_r, W_r) int32 of the nearest polygon in painter's order (-1 = none)."""
        R = np.asarray(T_F_rect[:3, :3], np.float64)
        o = np.asarray(T_F_rect[:3, 3], np.float64)
        buf = np.zeros((view.height, view.width), np.int32)
        if not len(polys):
            return buf - 1
        n, nv = polys.verts.shape[:2]
        uv = np.empty((n, nv, 2), np.float64)
        visible = np.empty(n, bool)
        dist2 = np.empty(n, np.float64)
        project_polygons(np.ascontiguousarray(polys.verts, np.float64), np.ascontiguousarray(polys.origin, np.float64),
                         np.ascontiguousarray(polys.normal, np.float64), polys.material != MAT_CANOPY, R, o,
                         view.fx, view.fy, view.cx, view.cy, view.width, view.height, NEAR_M, uv, visible, dist2)
        idx = np.flatnonzero(visible)
        if not idx.size:
            return buf - 1
        order = idx[np.argsort(-dist2[idx], kind="stable")]
        raster_polygons(uv, order, buf)
        return buf - 1

    def _shade_sky(self, bundle: RayBundle, dirs: np.ndarray, sky: np.ndarray, o: np.ndarray, t_s: float,
                   sun_e: float, out: np.ndarray) -> None:
        """Sky radiance into ``out`` at ``sky`` pixels: computed on a 3× coarser grid (the sky is smooth) and
        upsampled, plus the sun disk at full resolution."""
        H, W = sky.shape
        step = 3
        rows = np.any(sky, axis=1)
        r0 = int(np.argmax(rows))
        r1 = int(H - np.argmax(rows[::-1]))
        ys = np.arange(r0, r1 + step, step).clip(0, H - 1)
        xs = np.arange(0, W + step, step).clip(0, W - 1)
        cd = dirs[np.ix_(ys, xs)]
        cd = cd / np.linalg.norm(cd, axis=-1, keepdims=True)
        coarse = self.sky.radiance(cd.reshape(-1, 3), o, t_s, sun_e, bundle.pixel_angle * step,
                                   sun_disk=False).reshape(len(ys), len(xs), 3)
        gy = ((np.arange(r0, r1) - ys[0]) / step).astype(np.float32)
        gx = (np.arange(W) / step).astype(np.float32)
        mxg, myg = np.meshgrid(gx, gy)
        fine = cv2.remap(coarse, mxg, myg, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        np.copyto(out[r0:r1], fine, where=sky[r0:r1, :, None])
        # the sun disk (and its area-weighted brightness when smaller than a pixel)
        sd = self.sky.sun_dir.astype(np.float32)
        cosang = (dirs[..., 0] * sd[0] + dirs[..., 1] * sd[1] + dirs[..., 2] * sd[2]) / bundle.ray_norm
        disk_r = max(SUN_RADIUS_RAD, 0.5 * bundle.pixel_angle)
        disk = sky & (cosang > np.cos(disk_r))
        if disk.any():
            frac = (SUN_RADIUS_RAD / disk_r) ** 2
            out[disk] += _F32(400.0 * sun_e * frac)

    def _shade_soil(self, bundle: RayBundle, o: np.ndarray, tr: Trace, soil: np.ndarray, sun_e: float, atlas,
                    out: np.ndarray) -> None:
        """Shade the soil pixels of ``out`` (H, W, 3) in place (per-pixel trilinear textures; the lighting model
        in :func:`pipeline.sim.ground_kernels.soil_radiance`)."""
        idx = np.flatnonzero(soil)
        n = idx.size
        px = np.empty(n, np.float64)
        py = np.empty(n, np.float64)
        dist = np.empty(n, np.float32)
        lod_m = np.empty(n, np.float32)
        soil_footprints(tr.dirs.reshape(-1, 3), tr.t.reshape(-1), bundle.ray_norm.reshape(-1), idx, float(o[0]),
                        float(o[1]), float(bundle.pixel_angle), px, py, dist, lod_m)
        st = self.soil
        surf = st.surface.sample_lod(px, py, lod_m - _F32(np.log2(st.surface.texel_m)))
        grain = st.grain.sample_lod(px, py, lod_m - _F32(np.log2(st.grain.texel_m)), max_level=4)
        large = st.large.sample_lod(px, py, 1.0)  # one mip level (bilinear)
        amap, corner = atlas if atlas is not None else (_NO_ATLAS, np.zeros(2))
        soil_radiance(idx, px, py, dist, tr.hgx.reshape(-1)[idx], tr.hgy.reshape(-1)[idx], surf, grain, large, amap,
                      np.asarray(corner, np.float64), SHADOW_TEXEL_M, float(self.cfg_render.shadow_range_m),
                      self._row_params, np.asarray(self.sky.sun_dir, np.float64), float(sun_e), out.reshape(-1, 3))

    def _shade_polys(self, bundle: RayBundle, o: np.ndarray, tr: Trace, polys: PolySet, sun_e: float, atlas,
                     rad: np.ndarray, glare_rad: np.ndarray) -> None:
        """Radiance of the polygon pixels of a trace into ``rad`` (H·W, 3), their glare radiance added to
        ``glare_rad`` (H·W,) (lighting model in :mod:`pipeline.sim.shade_kernels`)."""
        tab = polys.table if polys.table is not None else poly_table(polys)
        k = tr.poly_k
        n = k.size
        fd, ft, fn = tr.dirs.reshape(-1, 3), tr.t.reshape(-1), bundle.ray_norm.reshape(-1)
        coords = np.empty((n, 6), np.float32)
        poly_surface_coords(fd, ft, fn, tr.poly_px, k, tab, (polys.origin - o).astype(np.float32),
                            np.asarray(o, np.float64), float(bundle.pixel_angle), coords)
        a, b, fp = coords[:, 0], coords[:, 1], coords[:, 2]
        canopy_poly = polys.material == MAT_CANOPY
        leaf = ~canopy_poly[k]
        tex = np.ones((n, 3), np.float32)
        shadow = np.zeros(n, np.float32)
        if leaf.any():
            li = np.flatnonzero(leaf)
            ex = tab[k[li], _EXTRA]
            # one leaf-noise level for the frame's leaves (their median footprint)
            lvl = int(np.clip(np.round(np.log2(max(float(np.median(fp[li])), 1e-6) / self.leaf_noise.texel_m)), 0, 6))
            tex[li, 0] = sample_level(self.leaf_noise, a[li] + 7.1 * ex, b[li] + 3.3 * ex, lvl)
            pz = coords[li, 5]
            shadow[li] = self._shadow(atlas, coords[li, 3], coords[li, 4], pz, pz - tab[k[li], _GROUND], 0.03)
        if not leaf.all():
            ci = np.flatnonzero(~leaf)
            var = tab[k[ci], _EXTRA]
            tex[ci] = self.foliage.sample(a[ci] + 13.7 * var, b[ci] + 5.1 * var, fp[ci])
        poly_radiance(fd, ft, fn, tr.poly_px, k, tab, polys.material == MAT_LEAF, canopy_poly, coords, tex, shadow,
                      float(o[2]), np.asarray(self.sky.sun_dir, np.float64), float(sun_e),
                      float(self.cfg_field.plant_height_m), float(self.cfg_light.leaf_gloss), rad, glare_rad)

    def _glare(self, bundle: RayBundle, dirs: np.ndarray, R: np.ndarray, sun_e: float) -> np.ndarray | None:
        """Veiling glare + flare ghosts (H, W) radiance, or None when negligible (sun well behind the camera);
        the model is :func:`pipeline.sim.optics_kernels.glare_field`."""
        strength = self.cfg_light.glare * sun_e / 3.0
        s_cam = np.asarray(R, np.float64).T @ self.sky.sun_dir
        if strength <= 0 or s_cam[2] < -0.3:
            return None
        ghosts = np.zeros((0, 4))
        if s_cam[2] > 0.3:  # sun within ≈70° of the optical axis: ghosts on the line through the image centre
            # ghost positions in rectified-normalised coordinates, so both bundles of a camera agree
            sx, sy = s_cam[0] / s_cam[2], s_cam[1] / s_cam[2]
            axis_w = float(np.clip((s_cam[2] - 0.3) / 0.5, 0, 1))
            ghosts = np.array([[sx * f, sy * f, rad, amp * strength * axis_w]
                               for f, rad, amp in ((-0.4, 0.063, 0.05), (-0.85, 0.108, 0.03), (-1.3, 0.04, 0.07))])
        H, W = dirs.shape[:2]
        g = np.empty((H, W), np.float32)
        glare_field(dirs.reshape(-1, 3), bundle.ray_norm.reshape(-1), bundle.rays.reshape(-1, 3),
                    np.asarray(self.sky.sun_dir, np.float64), float(strength), ghosts, g.reshape(-1))
        return g
