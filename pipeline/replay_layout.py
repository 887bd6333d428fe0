"""How a replay looks: colours, entity paths and the default blueprint of the rerun viewer (rerun-sdk 0.41).

One home for every visual convention of :mod:`pipeline.replay`:

* a run has **one colour everywhere** (path, current position, frustum, label, every time series):
  :func:`run_colour` by the run's position in the replay;
* the ground truth is drawn in :data:`GT_COLOUR`, a saturated magenta that reads on the viewer's dark and light
  themes alike and is in no run's palette;
* feature markers are coloured by **depth source** (:data:`FEATURE_CLASSES`), the one thing that differs between
  depth-raw and depth-inpainted runs;
* depth maps share one pinned colour range (:data:`DEPTH_RANGE_M`, the front end's ``max_depth_m``), holes are
  painted :data:`HOLE_RGBA` on top.

The blueprint: trajectories (3-D, eye fitted to the paths) above one time-series view per quantity on the left;
per-run left images with their features, then raw | inpainted | error depth side by side on the right.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import rerun.blueprint as rrb

from msckf.frontend_config import FrontendConfig

#: Run palette (RGB): Tableau-10 without its pink/purple/grey, readable on dark and light backgrounds.
RUN_PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (23, 190, 207), (140, 86, 75),
    (188, 189, 34), (127, 127, 255))
#: Ground truth (RGB): magenta, visible on the dark (default) and the light viewer theme, unlike black or white.
GT_COLOUR: tuple[int, int, int] = (230, 40, 230)
#: Feature classes (class id, label, RGB) of ``camera/left/features/<run>``; ids are the replay's, not msckf's.
FEATURE_CLASSES: tuple[tuple[int, str, tuple[int, int, int]], ...] = (
    (0, "mono (no depth)", (170, 170, 170)),
    (1, "measured depth (valid raw SGBM pixel)", (40, 210, 40)),
    (2, "inpainted depth (raw pixel was a hole)", (255, 150, 0)),
    (3, "stereo match (KLT left→right)", (60, 150, 255)),
)
MONO, MEASURED_DEPTH, INPAINTED_DEPTH, STEREO = 0, 1, 2, 3
#: Colour range of every depth map, metres: 0 to the depth the front end still uses (features farther are dropped).
DEPTH_RANGE_M: tuple[float, float] = (0.0, float(FrontendConfig().max_depth_m))
#: Colour range of the |inpainted − exact| error map, metres.
ERROR_RANGE_M: tuple[float, float] = (0.0, 2.0)
#: Holes of the raw depth (RGBA): opaque magenta over the depth colours (turbo has no magenta).
HOLE_RGBA: tuple[int, int, int, int] = (255, 0, 255, 255)
#: Default timeline of the viewer: seconds from the first frame.
SECONDS = "seconds"
#: Time-series views: (entity under ``metrics/``, title).
PLOTS: tuple[tuple[str, str], ...] = (
    ("ate", "ATE: error at GT fixes (thin) and running RMSE (thick) [m]"),
    ("features", "features: tracked (thick) / with depth (thin)"),
    ("frame_ms", "VIO time per frame [ms]"),
    ("hole_ratio", "raw depth hole ratio [0–1]"),
)


def run_colour(i: int) -> tuple[int, int, int]:
    """RGB of the ``i``-th run of a replay (cycles after :data:`RUN_PALETTE`)."""
    return RUN_PALETTE[i % len(RUN_PALETTE)]


def entity_name(name: str) -> str:
    """``name`` as one entity-path part (letters, digits, ``-`` and ``_``; anything else becomes ``_``)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


@dataclass(frozen=True)
class Eye:
    """A 3-D view's initial camera: ``position`` and ``look_target`` (world frame, metres), ``up`` axis."""

    position: tuple[float, float, float]
    look_target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


def fit_eye(points: np.ndarray) -> Eye | None:
    """An oblique view from south-west-above framing (N, 3) world points (z up), or None for no points.

    The target is the bounding-box centre; the eye sits 0.9 bounding-box diagonals away (at least 3 m), 35° above
    the horizon, looking across the longer horizontal side so that the paths fill the view.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        return None
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2.0
    span = hi - lo
    dist = max(3.0, 0.9 * float(np.linalg.norm(span)))
    # look perpendicular to the longer horizontal extent, from the side of negative coordinates
    horiz = np.array([0.3, -1.0, 0.0]) if span[0] >= span[1] else np.array([-1.0, 0.3, 0.0])
    horiz /= np.linalg.norm(horiz)
    elev = np.deg2rad(35.0)
    eye = centre + dist * (np.cos(elev) * horiz + np.array([0.0, 0.0, np.sin(elev)]))
    return Eye(tuple(float(x) for x in eye), tuple(float(x) for x in centre))


def blueprint(feature_runs: Sequence[str], has_depth: bool, has_error: bool, eye: Eye | None) -> rrb.Blueprint:
    """The default layout.

    Args:
        feature_runs: entity names of the runs with feature logs (one left-image view each, side by side).
        has_depth: whether raw/inpainted depth maps are logged.
        has_error: whether the |inpainted − exact| error map is logged.
        eye: initial 3-D camera (None: the viewer's default).
    """
    eye_controls = None if eye is None else rrb.EyeControls3D(position=eye.position, look_target=eye.look_target,
                                                              eye_up=eye.up)
    view3d = rrb.Spatial3DView(name="trajectories (GT magenta)", origin="world", eye_controls=eye_controls)
    # Plot legends would cover the curves; runs are told apart by their colour (legend panel, 3-D labels) and the
    # titles say which line is which. The one-series hole-ratio plot keeps its legend.
    plots = [rrb.TimeSeriesView(name=title, origin=f"metrics/{key}",
                                plot_legend=rrb.PlotLegend(visible=key == "hole_ratio")) for key, title in PLOTS]
    left_col = rrb.Vertical(view3d, rrb.Grid(*plots, grid_columns=2), row_shares=[5, 4])
    right_rows: list[rrb.Container] = []
    if feature_runs:
        right_rows.append(rrb.Horizontal(*[
            rrb.Spatial2DView(name=f"left + features: {run}", origin="camera/left",
                              contents=["$origin", f"$origin/features/{run}"]) for run in feature_runs]))
    else:
        right_rows.append(rrb.Horizontal(rrb.Spatial2DView(name="left image", origin="camera/left")))
    if has_depth:
        depth_views = [rrb.Spatial2DView(name=f"raw depth 0–{DEPTH_RANGE_M[1]:g} m (holes magenta)",
                                         origin="camera/depth_raw"),
                       rrb.Spatial2DView(name=f"inpainted depth 0–{DEPTH_RANGE_M[1]:g} m",
                                         origin="camera/depth_inpainted")]
        if has_error:
            depth_views.append(rrb.Spatial2DView(name=f"|inpainted − exact| 0–{ERROR_RANGE_M[1]:g} m",
                                                 origin="camera/depth_error"))
        right_rows.append(rrb.Horizontal(*depth_views))
    right_rows.append(rrb.TextDocumentView(name="legend", origin="legend"))
    right_col = rrb.Vertical(*right_rows, row_shares=[3] * (len(right_rows) - 1) + [2])
    return rrb.Blueprint(
        rrb.Horizontal(left_col, right_col, column_shares=[1, 1]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=SECONDS),
    )
