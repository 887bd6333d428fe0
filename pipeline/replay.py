"""Visual replay of runs as a rerun recording (``.rrd``; open it with ``rerun FILE.rrd``).

What a recording holds, on the ``frame`` (sequence) and ``time`` (bag clock) timelines:

* ``camera/left``: the left image, and per run ``camera/left/features/<run>``: tracked features coloured by track
  length (blue = new, yellow = long) with a ring colour by depth source (grey mono, green stereo, orange depth map);
* ``camera/depth_raw``, ``camera/depth_inpainted``: depth maps (metres), ``camera/holes``: the hole mask;
* ``world/gt``: the ground truth (one strip), ``world/<run>/trajectory``: the estimate aligned to the ground truth,
  ``world/<run>/camera``: the camera frustum (pinhole) at the current estimated pose;
* ``metrics/<run>/{ate_m,features,frame_ms}`` and ``metrics/hole_ratio``: scalar timelines.

Several runs (variants) can be replayed side by side in one recording. The module works on plain arrays; the
caller gathers them from run folders and caches.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pipeline.atomic import atomic_path

_SOURCE_COLOURS = np.array([[160, 160, 160], [40, 200, 40], [255, 140, 0]], dtype=np.uint8)  # DepthSource order


@dataclass
class ReplayRun:
    """One run's estimate and per-frame log.

    Attributes:
        name: label shown in the viewer (e.g. ``depth-inpainted seed 0``); entity-path safe characters preferred.
        stamps_s: (N,) estimate stamps, seconds.
        positions: (N, 3) estimated IMU positions, already aligned to the ground-truth frame, metres.
        quats_xyzw: (N, 4) estimated IMU orientations in the ground-truth frame.
        T_imu_cam: (4, 4) maps left-camera points into the IMU frame (for the frustum).
        ate_m: (N,) translational error of each aligned pose against the ground truth, metres (NaN if unknown).
        frame_stamps_s: (F,) stamps of the per-frame log.
        n_features: (F,) features tracked per frame. frame_ms: (F,) processing time per frame, milliseconds.
        features: per logged frame index, ``(uv (K, 2) raw left pixels, track_length (K,), source (K,))``.
    """

    name: str
    stamps_s: np.ndarray
    positions: np.ndarray
    quats_xyzw: np.ndarray
    T_imu_cam: np.ndarray
    ate_m: np.ndarray
    frame_stamps_s: np.ndarray
    n_features: np.ndarray
    frame_ms: np.ndarray
    features: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass
class ReplayFrame:
    """Images of one frame. ``left``: (H, W) or (H, W, 3) BGR uint8; depth maps float32 metres (NaN = hole)."""

    index: int
    stamp_s: float
    left: np.ndarray
    depth_raw: np.ndarray | None = None
    depth_inpainted: np.ndarray | None = None
    hole_mask: np.ndarray | None = None


def _entity(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def _track_colours(track_length: np.ndarray) -> np.ndarray:
    t = np.clip((np.asarray(track_length, dtype=np.float64) - 1.0) / 20.0, 0.0, 1.0)[:, None]
    return (np.array([40, 90, 255]) * (1 - t) + np.array([255, 230, 0]) * t).astype(np.uint8)


def _blueprint(run_names: list[str], has_depth: bool) -> rrb.Blueprint:
    images = [rrb.Spatial2DView(name="left + features", origin="camera/left")]
    if has_depth:
        images += [rrb.Spatial2DView(name="raw depth", origin="camera/depth_raw"),
                   rrb.Spatial2DView(name="inpainted depth", origin="camera/depth_inpainted"),
                   rrb.Spatial2DView(name="holes", origin="camera/holes")]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial3DView(name="trajectories", origin="world"),
                         rrb.TimeSeriesView(name="metrics", origin="metrics"), row_shares=[3, 2]),
            rrb.Grid(*images),
            column_shares=[1, 1],
        ),
        collapse_panels=True,
    )


def write_replay(out_path: Path | str, runs: list[ReplayRun], frames: Iterable[ReplayFrame],
                 gt_positions: np.ndarray | None, K_left: np.ndarray, image_size: tuple[int, int],
                 application: str = "agrivio") -> Path:
    """Write a rerun recording of ``runs`` over ``frames`` to ``out_path`` (atomically) and return the path.

    Args:
        gt_positions: (M, 3) ground-truth positions in the world frame (drawn once), or None.
        K_left: (3, 3) intrinsics of the left image shown (raw camera).
        image_size: ``(width, height)`` of the left image.
    """
    out_path = Path(out_path)
    frames_iter: Iterator[ReplayFrame] = iter(frames)
    first = next(frames_iter, None)
    has_depth = first is not None and first.depth_raw is not None
    with atomic_path(out_path, suffix=".rrd") as tmp:
        rec = rr.RecordingStream(application, recording_id=out_path.stem)
        rec.save(str(tmp), default_blueprint=_blueprint([r.name for r in runs], has_depth))
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if gt_positions is not None and len(gt_positions):
            rec.log("world/gt", rr.LineStrips3D([np.asarray(gt_positions, dtype=np.float32)], colors=[[0, 0, 0]],
                                                radii=0.02, labels=["ground truth"]), static=True)
        rec.log("camera/left/features", rr.AnnotationContext(
            [(i, name, tuple(int(c) for c in _SOURCE_COLOURS[i]))
             for i, name in enumerate(("mono", "stereo match", "depth map"))]), static=True)
        width, height = image_size
        for run in runs:
            ent = _entity(run.name)
            rec.log(f"world/{ent}/camera/image", rr.Pinhole(image_from_camera=np.asarray(K_left), width=width,
                                                             height=height, camera_xyz=rr.ViewCoordinates.RDF,
                                                             image_plane_distance=0.3), static=True)
            for metric, label in (("ate_m", "ATE so far [m]"), ("features", "features tracked"),
                                  ("frame_ms", "time per frame [ms]")):
                rec.log(f"metrics/{ent}/{metric}", rr.SeriesLines(names=f"{run.name}: {label}"), static=True)
            _log_run_columns(rec, run, ent)
        if first is not None:
            for frame in _chain(first, frames_iter):
                _log_frame(rec, frame, runs)
        rec.flush()
        rec.disconnect()
    return out_path


def _chain(first: ReplayFrame, rest: Iterator[ReplayFrame]) -> Iterator[ReplayFrame]:
    yield first
    yield from rest


def _log_run_columns(rec: rr.RecordingStream, run: ReplayRun, ent: str) -> None:
    """Per-pose data in one go with the columnar API (no O(N²) re-logging of growing strips)."""
    times = rr.TimeColumn("time", timestamp=np.asarray(run.stamps_s, dtype=np.float64))
    pos = np.asarray(run.positions, dtype=np.float64)
    rec.send_columns(f"world/{ent}/trajectory", indexes=[times],
                     columns=rr.Points3D.columns(positions=pos.astype(np.float32)))
    T_imu_cam = np.asarray(run.T_imu_cam, dtype=np.float64)
    from scipy.spatial.transform import Rotation

    R_world_imu = Rotation.from_quat(np.asarray(run.quats_xyzw, dtype=np.float64))
    R_world_cam = R_world_imu * Rotation.from_matrix(T_imu_cam[:3, :3])
    p_world_cam = pos + R_world_imu.apply(T_imu_cam[:3, 3])
    rec.send_columns(f"world/{ent}/camera", indexes=[times],
                     columns=rr.Transform3D.columns(translation=p_world_cam, quaternion=R_world_cam.as_quat()))
    rec.send_columns(f"metrics/{ent}/ate_m", indexes=[times],
                     columns=rr.Scalars.columns(scalars=np.asarray(run.ate_m, dtype=np.float64)))
    ftimes = rr.TimeColumn("time", timestamp=np.asarray(run.frame_stamps_s, dtype=np.float64))
    rec.send_columns(f"metrics/{ent}/features", indexes=[ftimes],
                     columns=rr.Scalars.columns(scalars=np.asarray(run.n_features, dtype=np.float64)))
    rec.send_columns(f"metrics/{ent}/frame_ms", indexes=[ftimes],
                     columns=rr.Scalars.columns(scalars=np.asarray(run.frame_ms, dtype=np.float64)))
    rec.log(f"world/{ent}/path", rr.LineStrips3D([pos.astype(np.float32)], radii=0.015, labels=[run.name]),
            static=True)


def _log_frame(rec: rr.RecordingStream, frame: ReplayFrame, runs: list[ReplayRun]) -> None:
    rec.set_time("frame", sequence=int(frame.index))
    rec.set_time("time", timestamp=float(frame.stamp_s))
    left = frame.left
    image = rr.Image(left, color_model="BGR") if left.ndim == 3 else rr.Image(left, color_model="L")
    rec.log("camera/left", image.compress(jpeg_quality=85))
    for run in runs:
        feats = run.features.get(int(frame.index))
        if feats is None:
            continue
        uv, track_len, source = feats
        rec.log(f"camera/left/features/{_entity(run.name)}",
                rr.Points2D(np.asarray(uv, dtype=np.float32), colors=_track_colours(track_len), radii=2.5,
                            class_ids=np.asarray(source, dtype=np.uint16)))
    for entity, depth in (("camera/depth_raw", frame.depth_raw), ("camera/depth_inpainted", frame.depth_inpainted)):
        if depth is not None:
            rec.log(entity, rr.DepthImage(_depth_mm(depth), meter=1000.0, colormap="turbo"))
    if frame.hole_mask is not None:
        mask = np.asarray(frame.hole_mask, dtype=bool)
        rec.log("camera/holes", rr.Image((mask * 255).astype(np.uint8), color_model="L"))
        rec.log("metrics/hole_ratio", rr.Scalars(float(mask.mean())))


def _depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """float metres (NaN = hole) → uint16 millimetres (0 = hole): half the bytes of float32, exact to 1 mm."""
    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0)
    return np.clip(np.round(d * 1000.0), 0, 65535).astype(np.uint16)


def recorded_entities(path: Path | str) -> dict[str, int]:
    """Rows per entity path in an ``.rrd`` file, read back with rerun's own reader (for tests and checks)."""
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows
