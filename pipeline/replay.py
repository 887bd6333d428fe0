"""Visual replay of runs as a rerun recording (``.rrd``; open it with ``rerun FILE.rrd``).

Everything is logged on three timelines: ``seconds`` (duration from the first frame, the viewer's default),
``frame`` (stereo frame index) and ``time`` (bag clock, UTC timestamp). A recording holds:

* ``world/gt``: the ground truth (magenta strip); per run ``world/<run>/path`` (the estimate at the point the ground
  truth measures, e.g. the GPS antenna, aligned exactly as its ATE was computed), ``world/<run>/trajectory`` (the
  current position), ``world/<run>/camera`` (one small frustum at the current path point, oriented as the camera) and
  ``world/<run>/label`` (the run's name, once). A run has one colour everywhere (:mod:`pipeline.replay_layout`).
* ``camera/left`` (left image) with ``camera/left/features/<run>``: tracked features coloured by depth source
  (mono / measured depth / inpainted depth / stereo), one overlay per run;
* ``camera/depth_raw`` with ``camera/depth_raw/holes`` (holes painted magenta), ``camera/depth_inpainted`` and,
  when the simulator's exact depth exists, ``camera/depth_error`` = |inpainted − exact|; all depth colours on one
  pinned range (0–20 m, the front end's ``max_depth_m``);
* ``metrics/ate/<run>/{error_at_gt,rmse_so_far}``: the translational error at each pose associated with a GT fix and
  its running RMSE (its last value is the run's ATE RMSE); ``metrics/features/<run>/{tracked,with_depth}``;
  ``metrics/frame_ms/<run>``; ``metrics/hole_ratio/raw``;
* ``legend``: a Markdown table of the runs (colour, kind, ATE RMSE, depth-source shares) and of the colours.

The module works on plain arrays; the caller gathers them from run folders and caches.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from pipeline import replay_layout as lay
from pipeline.atomic import atomic_path
from pipeline.png_codec import PNG_COMPACT, encode_png_bytes


@dataclass
class ReplayRun:
    """One run's estimate and per-frame log.

    Attributes:
        name: label shown in the viewer (e.g. ``depth-inpainted seed0``).
        stamps_s: (N,) estimate stamps, seconds (bag clock).
        positions: (N, 3) estimated positions of the point the ground truth measures (e.g. the GPS antenna), in the
            ground-truth frame (aligned as the run's ATE was computed), metres.
        quats_xyzw: (N, 4) estimated body (IMU or base_link) orientations in the ground-truth frame.
        T_body_cam: (4, 4) maps left-camera points into the body frame; its rotation orients the frustum drawn at
            ``positions``. None: the body frame is drawn as a forward-looking (x forward, z up) frustum.
        gt_stamps_s: (M,) stamps of the poses associated with a ground-truth fix, seconds.
        gt_errors_m: (M,) translational error at those poses after alignment, metres.
        ate_rmse_m: the run's recorded ATE RMSE, metres (None: unknown).
        frame_stamps_s: (F,) stamps of the per-frame log (frame ``i`` of the sequence is row ``i``).
        n_features: (F,) features tracked per frame. n_with_depth: (F,) of which with depth (any source but mono).
        frame_ms: (F,) VIO processing time per frame, milliseconds.
        features: frame index → ``(uv (K, 2) raw left pixels, track_length (K,), feature class (K,))`` with classes
            of :data:`pipeline.replay_layout.FEATURE_CLASSES`.
        feature_sigma_rel: frame index → (K,) the depth σ_Z/Z stated to the filter for each of those features (NaN:
            no depth or no stated σ); it sets the marker size (:func:`feature_radii`).
        kind: what the run is, for the legend (``VIO``, ``odometry``, ``external``).
    """

    name: str
    stamps_s: np.ndarray
    positions: np.ndarray
    quats_xyzw: np.ndarray
    T_body_cam: np.ndarray | None = None
    gt_stamps_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gt_errors_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ate_rmse_m: float | None = None
    frame_stamps_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_features: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_with_depth: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    features: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    feature_sigma_rel: dict[int, np.ndarray] = field(default_factory=dict)
    kind: str = "VIO"


@dataclass
class ReplayFrame:
    """Images of one frame. ``left``: (H, W) or (H, W, 3) BGR uint8 raw left image; depth maps: (h, w) float32
    metres in the rectified left camera (NaN = hole / none); ``hole_mask``: (h, w) bool, True = raw hole;
    ``depth_exact``: the simulator's exact depth of the frame (None for real bags)."""

    index: int
    stamp_s: float
    left: np.ndarray
    depth_raw: np.ndarray | None = None
    depth_inpainted: np.ndarray | None = None
    hole_mask: np.ndarray | None = None
    depth_exact: np.ndarray | None = None


class _Clock:
    """Frame index ↔ stamp, and the three timelines of a stamp."""

    def __init__(self, t0_s: float) -> None:
        self.t0_s = float(t0_s)
        self.known: dict[int, float] = {}

    def add(self, index: int, stamp_s: float) -> None:
        self.known.setdefault(int(index), float(stamp_s))

    def indexes(self, stamps_s: np.ndarray) -> list[rr.TimeColumn]:
        """``frame`` (latest frame at or before each stamp, 1 ms tolerance), ``seconds`` and ``time`` columns."""
        stamps = np.asarray(stamps_s, dtype=np.float64)
        if self.known:
            idx = np.array(sorted(self.known))
            st = np.array([self.known[i] for i in idx])
            order = np.argsort(st, kind="stable")
            idx, st = idx[order], st[order]
            pos = np.clip(np.searchsorted(st, stamps + 1e-3, side="right") - 1, 0, len(st) - 1)
            frame = idx[pos]
        else:
            frame = np.zeros(len(stamps), dtype=np.int64)
        return [rr.TimeColumn("frame", sequence=frame.astype(np.int64)),
                rr.TimeColumn(lay.SECONDS, duration=stamps - self.t0_s),
                rr.TimeColumn("time", timestamp=stamps)]

    def set(self, rec: rr.RecordingStream, index: int, stamp_s: float) -> None:
        rec.set_time("frame", sequence=int(index))
        rec.set_time(lay.SECONDS, duration=float(stamp_s) - self.t0_s)
        rec.set_time("time", timestamp=float(stamp_s))


def write_replay(out_path: Path | str, runs: list[ReplayRun], frames: Iterable[ReplayFrame],
                 gt_positions: np.ndarray | None, K_left: np.ndarray, image_size: tuple[int, int],
                 application: str = "agrivio", notes: Sequence[str] = ()) -> Path:
    """Write a rerun recording of ``runs`` over ``frames`` to ``out_path`` (atomically) and return the path.

    Args:
        runs: the runs, in the order that gives them their colours.
        frames: images per frame (streamed; may be empty).
        gt_positions: (M, 3) ground-truth positions in the world frame (drawn once), or None.
        K_left: (3, 3) intrinsics of the left image shown (raw camera).
        image_size: ``(width, height)`` of the left image.
        notes: lines added to the legend (e.g. the image stride).
    """
    out_path = Path(out_path)
    frames_iter: Iterator[ReplayFrame] = iter(frames)
    first = next(frames_iter, None)
    has_depth = first is not None and first.depth_raw is not None
    has_error = has_depth and first.depth_exact is not None and first.depth_inpainted is not None
    ents = [lay.entity_name(r.name) for r in runs]
    if len(set(ents)) != len(ents):
        raise ValueError(f"replay: run names must differ as entity names, got {ents}")
    t0 = _start_stamp(first, runs)
    clock = _Clock(t0)
    for run in runs:
        for i, s in enumerate(np.asarray(run.frame_stamps_s, dtype=np.float64)):
            clock.add(i, s)
    fitted = [np.asarray(gt_positions, dtype=np.float64).reshape(-1, 3)] if gt_positions is not None else []
    fitted += [np.asarray(r.positions, dtype=np.float64).reshape(-1, 3) for r in runs]
    eye = lay.fit_eye(np.concatenate(fitted)) if fitted else None
    feature_runs = [e for r, e in zip(runs, ents) if r.features]
    with atomic_path(out_path, suffix=".rrd") as tmp:
        rec = rr.RecordingStream(application, recording_id=out_path.stem)
        rec.save(str(tmp), default_blueprint=lay.blueprint(feature_runs, has_depth, has_error, eye))
        _log_static(rec, runs, ents, gt_positions, K_left, image_size, notes)
        # Poses and metrics go first when the frame logs give the frame index of every stamp: the viewer then
        # shows every plot while the images are still loading. Otherwise the frames define the index first.
        columns_first = bool(clock.known)
        if columns_first:
            for i, (run, ent) in enumerate(zip(runs, ents)):
                _log_run_columns(rec, run, ent, lay.run_colour(i), clock)
        if first is not None:
            for frame in _chain(first, frames_iter):
                clock.add(frame.index, frame.stamp_s)
                clock.set(rec, frame.index, frame.stamp_s)
                _log_frame(rec, frame, runs, ents)
        if not columns_first:
            for i, (run, ent) in enumerate(zip(runs, ents)):
                _log_run_columns(rec, run, ent, lay.run_colour(i), clock)
        rec.flush()
        rec.disconnect()
    return out_path


def _start_stamp(first: ReplayFrame | None, runs: Sequence[ReplayRun]) -> float:
    """Stamp of ``seconds`` = 0: the first frame, else the first frame log, else the first estimate."""
    if first is not None:
        return float(first.stamp_s)
    logs = [float(r.frame_stamps_s[0]) for r in runs if len(r.frame_stamps_s)]
    if logs:
        return min(logs)
    ests = [float(r.stamps_s[0]) for r in runs if len(r.stamps_s)]
    return min(ests) if ests else 0.0


def _chain(first: ReplayFrame, rest: Iterator[ReplayFrame]) -> Iterator[ReplayFrame]:
    yield first
    yield from rest


def _log_static(rec: rr.RecordingStream, runs: Sequence[ReplayRun], ents: Sequence[str],
                gt_positions: np.ndarray | None, K_left: np.ndarray, image_size: tuple[int, int],
                notes: Sequence[str]) -> None:
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if gt_positions is not None and len(gt_positions):
        rec.log("world/gt", rr.LineStrips3D([np.asarray(gt_positions, dtype=np.float32)], colors=[lay.GT_COLOUR],
                                            radii=0.03), static=True)
    rec.log("camera/left/features", rr.AnnotationContext(list(lay.FEATURE_CLASSES)), static=True)
    # an RGBA PNG overlay would be smaller, but the web viewer draws its transparent pixels black
    rec.log("camera/depth_raw/holes", rr.AnnotationContext([(0, "valid", (0, 0, 0, 0)), (1, "hole", lay.HOLE_RGBA)]),
            static=True)
    width, height = image_size
    for i, (run, ent) in enumerate(zip(runs, ents)):
        colour = lay.run_colour(i)
        xyz = rr.ViewCoordinates.RDF if run.T_body_cam is not None else rr.ViewCoordinates.FLU
        rec.log(f"world/{ent}/camera/image", rr.Pinhole(image_from_camera=np.asarray(K_left), width=width,
                                                         height=height, camera_xyz=xyz, image_plane_distance=0.12,
                                                         color=colour, line_width=0.004), static=True)
        pos = np.asarray(run.positions, dtype=np.float32).reshape(-1, 3)
        if len(pos):
            rec.log(f"world/{ent}/path", rr.LineStrips3D([pos], colors=[colour], radii=0.015), static=True)
            end = pos[-1].astype(np.float64)
            tag = end + np.array([0.0, 0.0, 0.35 + 0.3 * i])
            rec.log(f"world/{ent}/label", rr.Points3D([tag], colors=[colour], radii=0.03, labels=[run.name],
                                                      show_labels=True), static=True)
            rec.log(f"world/{ent}/label/leader", rr.LineStrips3D([[end, tag]], colors=[colour], radii=0.005),
                    static=True)
        rec.log(f"world/{ent}/trajectory", rr.Points3D.from_fields(colors=[colour], radii=[0.05]), static=True)
        rec.log(f"metrics/ate/{ent}/error_at_gt", rr.SeriesLines(colors=[colour], widths=[1.0],
                                                                 names=[f"{run.name}: error at GT fix"]), static=True)
        rec.log(f"metrics/ate/{ent}/rmse_so_far", rr.SeriesLines(colors=[colour], widths=[3.0],
                                                                 names=[f"{run.name}: RMSE so far"]), static=True)
        if len(run.frame_stamps_s):
            rec.log(f"metrics/features/{ent}/tracked", rr.SeriesLines(colors=[colour], widths=[3.0],
                                                                      names=[f"{run.name}: tracked"]), static=True)
            rec.log(f"metrics/features/{ent}/with_depth", rr.SeriesLines(colors=[colour], widths=[1.0],
                                                                         names=[f"{run.name}: with depth"]),
                    static=True)
            rec.log(f"metrics/frame_ms/{ent}", rr.SeriesLines(colors=[colour], widths=[1.5], names=[run.name]),
                    static=True)
    rec.log("metrics/hole_ratio/raw", rr.SeriesLines(colors=[(150, 150, 150)], widths=[1.5],
                                                     names=["raw SGBM holes / pixels"]), static=True)
    rec.log("legend", rr.TextDocument(legend_markdown(runs, notes), media_type=rr.MediaType.MARKDOWN), static=True)


def _hex(rgb: Sequence[int]) -> str:
    return "#" + "".join(f"{int(c):02x}" for c in rgb[:3])


def feature_shares(run: ReplayRun) -> dict[int, float]:
    """Fraction of all logged feature observations of ``run`` in each feature class (empty without features)."""
    classes = [np.asarray(c) for _, _, c in run.features.values()]
    allc = np.concatenate(classes) if classes else np.zeros(0)
    if not allc.size:
        return {}
    return {cid: float(np.mean(allc == cid)) for cid, _, _ in lay.FEATURE_CLASSES}


def legend_markdown(runs: Sequence[ReplayRun], notes: Sequence[str] = ()) -> str:
    """The legend document: one row per run (colour, kind, ATE RMSE, feature depth sources), then the colours."""
    lines = ["### Runs", "", "| colour | run | kind | ATE RMSE (m) | features: mono / measured / inpainted / stereo |",
             "|---|---|---|---|---|"]
    for i, run in enumerate(runs):
        shares = feature_shares(run)
        share = " / ".join(f"{100 * shares[c]:.0f} %" for c, _, _ in lay.FEATURE_CLASSES) if shares else "–"
        ate = "–" if run.ate_rmse_m is None else f"{run.ate_rmse_m:.3f}"
        lines.append(f"| {_hex(lay.run_colour(i))} | {run.name} | {run.kind} | {ate} | {share} |")
    lines += ["", f"Ground truth: magenta ({_hex(lay.GT_COLOUR)}). Paths are drawn at the point the ground truth "
              "measures (the GPS antenna on Rosario), aligned as the ATE was computed.", "",
              "Features: " + ", ".join(f"{label} {_hex(rgb)}" for _, label, rgb in lay.FEATURE_CLASSES) + ".", "",
              f"Depth: turbo on {lay.DEPTH_RANGE_M[0]:g}–{lay.DEPTH_RANGE_M[1]:g} m for raw and inpainted alike; raw "
              f"holes magenta; error map |inpainted − exact| on {lay.ERROR_RANGE_M[0]:g}–{lay.ERROR_RANGE_M[1]:g} m "
              "(simulated sequences only)."]
    lines += [""] + [f"{n}" for n in notes] if notes else []
    return "\n".join(lines) + "\n"


def _log_run_columns(rec: rr.RecordingStream, run: ReplayRun, ent: str, colour: tuple[int, int, int],
                     clock: _Clock) -> None:
    """Per-pose and per-frame data in one go with the columnar API (no O(N²) re-logging of growing strips)."""
    stamps = np.asarray(run.stamps_s, dtype=np.float64)
    pos = np.asarray(run.positions, dtype=np.float64).reshape(-1, 3)
    if len(stamps):
        idx = clock.indexes(stamps)
        rec.send_columns(f"world/{ent}/trajectory", indexes=idx,
                         columns=rr.Points3D.columns(positions=pos.astype(np.float32)))
        # The frustum marks where the run is now and where its camera looks: at the path point (the GT point, e.g.
        # the antenna ≈ 0.6 m above the camera on Rosario) so that it sits on its path, oriented as the camera.
        R_world_body = Rotation.from_quat(np.asarray(run.quats_xyzw, dtype=np.float64))
        R_world_cam = R_world_body if run.T_body_cam is None else \
            R_world_body * Rotation.from_matrix(np.asarray(run.T_body_cam, dtype=np.float64)[:3, :3])
        rec.send_columns(f"world/{ent}/camera", indexes=idx,
                         columns=rr.Transform3D.columns(translation=pos, quaternion=R_world_cam.as_quat()))
    gt_t = np.asarray(run.gt_stamps_s, dtype=np.float64)
    if len(gt_t):
        err = np.asarray(run.gt_errors_m, dtype=np.float64)
        running = np.sqrt(np.cumsum(err ** 2) / np.arange(1, len(err) + 1))
        idx = clock.indexes(gt_t)
        rec.send_columns(f"metrics/ate/{ent}/error_at_gt", indexes=idx, columns=rr.Scalars.columns(scalars=err))
        rec.send_columns(f"metrics/ate/{ent}/rmse_so_far", indexes=idx, columns=rr.Scalars.columns(scalars=running))
    ft = np.asarray(run.frame_stamps_s, dtype=np.float64)
    if len(ft):
        idx = clock.indexes(ft)
        for path, values in ((f"metrics/features/{ent}/tracked", run.n_features),
                             (f"metrics/features/{ent}/with_depth", run.n_with_depth),
                             (f"metrics/frame_ms/{ent}", run.frame_ms)):
            rec.send_columns(path, indexes=idx,
                             columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))


def _log_frame(rec: rr.RecordingStream, frame: ReplayFrame, runs: Sequence[ReplayRun], ents: Sequence[str]) -> None:
    left = frame.left
    image = rr.Image(left, color_model="BGR") if left.ndim == 3 else rr.Image(left, color_model="L")
    rec.log("camera/left", image.compress(jpeg_quality=85))
    for run, ent in zip(runs, ents):
        feats = run.features.get(int(frame.index))
        if feats is None:
            continue
        uv, _track_len, cls = feats
        radii = feature_radii(run.feature_sigma_rel.get(int(frame.index)), len(uv))
        rec.log(f"camera/left/features/{ent}",
                rr.Points2D(np.asarray(uv, dtype=np.float32), radii=radii, class_ids=np.asarray(cls, dtype=np.uint16)))
    mm_range = (1000.0 * lay.DEPTH_RANGE_M[0], 1000.0 * lay.DEPTH_RANGE_M[1])
    for entity, depth in (("camera/depth_raw", frame.depth_raw), ("camera/depth_inpainted", frame.depth_inpainted)):
        if depth is not None:
            rec.log(entity, _depth_png(depth_mm(depth), "turbo", mm_range))
    if frame.hole_mask is not None:
        mask = np.asarray(frame.hole_mask, dtype=bool)
        rec.log("camera/depth_raw/holes", rr.SegmentationImage(mask.astype(np.uint8), opacity=1.0, draw_order=10.0))
        rec.log("metrics/hole_ratio/raw", rr.Scalars(float(mask.mean())))
    if frame.depth_exact is not None and frame.depth_inpainted is not None:
        err = np.abs(np.asarray(frame.depth_inpainted, np.float64) - np.asarray(frame.depth_exact, np.float64))
        err_mm = np.where(np.isfinite(err), np.maximum(depth_mm(err), 1), 0).astype(np.uint16)
        rec.log("camera/depth_error", _depth_png(err_mm, "inferno", (1000.0 * lay.ERROR_RANGE_M[0],
                                                                   1000.0 * lay.ERROR_RANGE_M[1])))


def feature_radii(sigma_rel: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) marker radii in pixels: 3 px, plus 20 px per unit of the stated depth σ_Z/Z (capped at 30 %), so a
    filled depth (σ ≈ 15 % of Z) is drawn about twice the size of a measured one (≈ 2 %)."""
    if sigma_rel is None or len(sigma_rel) != n:
        return np.full(n, 3.0, dtype=np.float32)
    s = np.nan_to_num(np.asarray(sigma_rel, dtype=np.float64), nan=0.0)
    return (3.0 + 20.0 * np.clip(s, 0.0, 0.3)).astype(np.float32)


def _depth_png(mm: np.ndarray, colormap: str, range_mm: tuple[float, float]) -> rr.EncodedDepthImage:
    """(h, w) uint16 millimetres (0 = none) as a 16-bit PNG depth image, rounded to whole centimetres (the
    viewer shows depth to 1 cm; millimetre noise would triple the file)."""
    cm = np.where(mm > 0, np.maximum(10, np.round(mm.astype(np.float64) / 10.0) * 10), 0).astype(np.uint16)
    return rr.EncodedDepthImage(encode_png_bytes(cm, PNG_COMPACT), media_type="image/png", meter=1000.0,
                                colormap=colormap, depth_range=range_mm)


def depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """float metres (NaN = hole) → uint16 millimetres (0 = hole): half the bytes of float32, exact to 1 mm."""
    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(d * 1000.0), 0, 65535).astype(np.uint16)


def recorded_entities(path: Path | str) -> dict[str, int]:
    """Rows per entity path in an ``.rrd`` file, read back with rerun's own reader (for tests and checks)."""
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows
