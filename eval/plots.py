"""Report figures (matplotlib, Agg, no global pyplot state) returned as PNG or SVG bytes.

Each function takes plain arrays / trajectories and returns the encoded image; nothing is written to disk.
PNG output carries no timestamp or version metadata, so the same inputs give the same bytes.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from eval.trajectory import Trajectory

__all__ = ["LOG_SCALE_RATIO", "wants_log_scale", "figure_bytes", "plot_top_view", "plot_error_over_time",
           "plot_ate_boxplot", "plot_rpe_vs_distance"]

_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


def _new_figure(width_in: float = 6.4, height_in: float = 4.8) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_bytes(fig: Figure, fmt: str = "png") -> bytes:
    """Encode a figure as ``png`` or ``svg`` bytes, without date/software metadata (deterministic)."""
    buf = io.BytesIO()
    if fmt == "png":
        fig.savefig(buf, format="png", metadata={"Software": None})
    elif fmt == "svg":
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    else:
        raise ValueError(f"unknown figure format {fmt!r}")
    return buf.getvalue()


#: Series whose typical values (medians of the positive ones) differ by more than this factor are drawn on a
#: logarithmic axis, so a 10 m wheel-odometry error does not flatten 0.1 m VIO errors into the x axis.
LOG_SCALE_RATIO = 20.0


def _positive(v: np.ndarray) -> np.ndarray:
    """The finite, positive values of ``v``, flattened."""
    v = np.asarray(v, dtype=np.float64).ravel()
    return v[np.isfinite(v) & (v > 0)]


def _positive_series(series: Sequence[np.ndarray]) -> list[np.ndarray]:
    """:func:`_positive` of each series, the empty ones left out."""
    return [p for p in map(_positive, series) if p.size]


def _medians_differ(positive: Sequence[np.ndarray], ratio: float) -> bool:
    medians = [float(np.median(v)) for v in positive]
    return len(medians) >= 2 and max(medians) > ratio * min(medians)


def wants_log_scale(series: Sequence[np.ndarray], ratio: float = LOG_SCALE_RATIO) -> bool:
    """True when the medians of the positive, finite values of the series differ by more than ``ratio``."""
    return _medians_differ(_positive_series(series), ratio)


def _log_y(ax, series: Sequence[np.ndarray], label: str) -> None:
    """A logarithmic y axis (labelled so) when :func:`wants_log_scale`; its bottom at the smallest series' 5th
    percentile of positive values (errors near 0 at an alignment point would otherwise stretch it)."""
    positive = _positive_series(series)
    if not _medians_differ(positive, LOG_SCALE_RATIO):
        return
    floor = min(float(np.percentile(v, 5)) for v in positive)
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor * 0.8)
    ax.set_ylabel(f"{label} (log scale)")


def _color(i: int) -> str:
    return _COLORS[i % len(_COLORS)]


#: Labels starting with this mark estimates from other systems (``agrivio compare --external``): drawn dashed.
EXTERNAL_LABEL_PREFIX = "external:"


def _linestyle(label: str) -> str:
    return "--" if label.startswith(EXTERNAL_LABEL_PREFIX) else "-"


def plot_top_view(reference: Trajectory | None, estimates: Mapping[str, Trajectory], title: str = "",
                  fmt: str = "png") -> bytes:
    """Top view (x east, y north, metres) of the reference and of each aligned estimate (label → trajectory);
    external estimates (labels ``external: …``) dashed."""
    fig = _new_figure(6.4, 5.6)
    ax = fig.add_subplot()
    if reference is not None and len(reference):
        ax.plot(reference.positions[:, 0], reference.positions[:, 1], color="black", lw=2.0, ls="--",
                label="ground truth")
        ax.plot(reference.positions[0, 0], reference.positions[0, 1], "ko", ms=5)
    for i, (label, traj) in enumerate(estimates.items()):
        if len(traj):
            ax.plot(traj.positions[:, 0], traj.positions[:, 1], color=_color(i), lw=1.2, ls=_linestyle(label),
                    label=label)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    ax.set_title(title or "top view (aligned)")
    return figure_bytes(fig, fmt)


def plot_error_over_time(series: Mapping[str, tuple[np.ndarray, np.ndarray]], title: str = "",
                         fmt: str = "png", spans: Sequence[tuple[float, float]] = (),
                         t0_s: float | None = None, span_label: str = "turn") -> bytes:
    """Translational error (m) over time; ``label → (stamps_s, errors_m)``.

    Time is in seconds from ``t0_s`` (default: the earliest first stamp of the series); ``spans`` (start, end)
    stamps in seconds, e.g. the reference's turns, are shaded and labelled ``span_label`` once in the legend.
    """
    fig = _new_figure(6.4 if not spans else 8.0, 3.6)
    ax = fig.add_subplot()
    firsts = [float(np.asarray(t)[0]) for t, _ in series.values() if np.asarray(t).size]
    origin = t0_s if t0_s is not None else (min(firsts) if firsts else 0.0)
    for k, (a, b) in enumerate(spans):
        ax.axvspan(a - origin, b - origin, color="0.85", zorder=0, label=span_label if k == 0 else None)
    for i, (label, (t, e)) in enumerate(series.items()):
        t = np.asarray(t, dtype=np.float64)
        if t.size:
            ax.plot(t - origin, np.asarray(e), color=_color(i), lw=1.0, ls=_linestyle(label), label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("translational error (m)")
    _log_y(ax, [np.asarray(e) for _, e in series.values()], "translational error (m)")
    ax.grid(True, alpha=0.3)
    if series:
        ax.legend(loc="best", fontsize="small")
    ax.set_title(title or "ATE over time")
    return figure_bytes(fig, fmt)


def plot_ate_boxplot(values: Mapping[str, Sequence[float]], failed: Mapping[str, int] | None = None,
                     title: str = "", ylabel: str = "ATE RMSE (m)", fmt: str = "png") -> bytes:
    """Box plot of a per-run metric for each variant (label → values of successful runs), runs as dots.

    ``failed`` (label → count) is written under each box, so failed runs stay visible.
    """
    failed = failed or {}
    labels = list(values.keys())
    fig = _new_figure(max(4.0, 1.3 * len(labels) + 2.0), 3.8)
    ax = fig.add_subplot()
    data = [np.asarray(values[k], dtype=np.float64) for k in labels]
    positions = np.arange(1, len(labels) + 1)
    nonempty = [i for i, d in enumerate(data) if d.size]
    if nonempty:
        ax.boxplot([data[i] for i in nonempty], positions=positions[nonempty], widths=0.5, showfliers=False)
    for i, d in enumerate(data):
        if d.size:
            jitter = np.linspace(-0.12, 0.12, d.size) if d.size > 1 else np.zeros(1)
            ax.plot(positions[i] + jitter, d, "o", color=_color(i), ms=4, alpha=0.8)
    ticks = []
    for k, d in zip(labels, data):
        f = int(failed.get(k, 0))
        ticks.append(f"{k}\n{d.size} ok" + (f", {f} failed" if f else ""))
    ax.set_xticks(positions, ticks, fontsize="small")
    ax.set_xlim(0.4, len(labels) + 0.6)
    ax.set_ylabel(ylabel)
    _log_y(ax, data, ylabel)
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(title or "ATE over runs")
    return figure_bytes(fig, fmt)


def plot_rpe_vs_distance(series: Mapping[str, tuple[Sequence[float], Sequence[float], Sequence[float]]],
                         title: str = "", ylabel: str = "RPE translation RMSE (m)", fmt: str = "png") -> bytes:
    """RPE vs segment length: ``label → (distances_m, means, stds)`` (std may hold NaN for a single run)."""
    fig = _new_figure(6.4, 3.6)
    ax = fig.add_subplot()
    n = max(1, len(series))
    for i, (label, (dist, mean, std)) in enumerate(series.items()):
        d = np.asarray(dist, dtype=np.float64)
        if not d.size:
            continue
        offset = (i - (n - 1) / 2) * 0.01 * d.max()
        s = np.nan_to_num(np.asarray(std, dtype=np.float64), nan=0.0)
        ax.errorbar(d + offset, np.asarray(mean), yerr=s, color=_color(i), marker="o", ms=4, capsize=3, lw=1.0,
                    label=label)
    ax.set_xlabel("travelled distance (m)")
    ax.set_ylabel(ylabel)
    _log_y(ax, [np.asarray(mean) for _, mean, _ in series.values()], ylabel)
    ax.grid(True, alpha=0.3)
    if series:
        ax.legend(loc="best", fontsize="small")
    ax.set_title(title or "RPE vs distance")
    return figure_bytes(fig, fmt)
