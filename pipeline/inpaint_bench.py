"""The depth-inpainting benchmark (``agrivio inpaint-bench``): methods × frames × hole masks → Table-1 report.

Frames carry exact ground-truth depth. Hole masks:

- ``sgbm``: the real StereoSGBM invalid mask of a simulated stereo frame (``pipeline.depth``), transplanted onto a
  ground-truth depth map (its own frame's, or another frame's: ``transplant``) — stereo holes where ground truth
  is known;
- ``blobs`` / ``stripes`` / ``specks`` / ``mixed``: seeded random masks (``inpaint.masks``) at a hole ratio of
  5–40 %.

Metrics (``eval.depth_metrics``): RMSE, MAE (m), PSNR (fixed peak, default 20 m), SSIM (Gaussian 11×11, σ 1.5)
on hole pixels whose ground truth is valid and ≤ ``max_depth``; whole-image figures beside them. Per-method
median time per frame. Output: Markdown + JSON tables in the shape of the paper's Table 1 (images as rows,
methods as columns, one block per metric, an average row) and a PNG figure grid.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from eval.depth_metrics import DEFAULT_PEAK_M, DepthMetrics, depth_metrics
from inpaint import METHODS, inpaint
from pipeline.png_codec import encode_png_bytes
from pipeline.rosario_layout import RATE_CAMERA_HZ

DEFAULT_METHODS = ("paper", "paper-greedy", "ebm", "telea", "ns", "biharmonic", "ipbasic")


@dataclass(frozen=True)
class BenchFrame:
    """One benchmark case. ``depth_gt``: H×W float32 metres; ``valid``: bool H×W (ground truth exists);
    ``mask``: bool H×W holes to fill; ``guide``: H×W or H×W×3 uint8 image or None; ``source``: where the frame
    and mask come from (shown in the report)."""

    name: str
    depth_gt: np.ndarray
    valid: np.ndarray
    mask: np.ndarray
    guide: np.ndarray | None
    source: str


@dataclass
class BenchResult:
    """Per (frame, method): metrics and seconds; plus the outputs of every method (for the figure)."""

    frames: list[BenchFrame]
    methods: list[str]
    metrics: dict[tuple[str, str], DepthMetrics] = field(default_factory=dict)
    seconds: dict[tuple[str, str], float] = field(default_factory=dict)
    outputs: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    peak_m: float = DEFAULT_PEAK_M
    max_depth_m: float = DEFAULT_PEAK_M
    options: dict[str, dict] = field(default_factory=dict)

    def median_seconds(self, method: str) -> float:
        return float(np.median([self.seconds[(f.name, method)] for f in self.frames]))

    def mean_metric(self, method: str, key: str) -> float:
        vals = [getattr(self.metrics[(f.name, method)], key) for f in self.frames]
        return float(np.mean(vals))


ABLATIONS = ("paper:single_scale=true", "paper:gradient=sobel", "paper:fusion=best", "paper:fusion=mean")


def parse_method(spec: str) -> tuple[str, dict]:
    """``"name"`` or ``"name:key=value,key=value"`` (an ablation variant) → (name, options). Values: true/false,
    ints, floats, else strings."""
    name, _, rest = spec.partition(":")
    opts: dict = {}
    for item in filter(None, rest.split(",")):
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"bad option {item!r} in method spec {spec!r} (expected key=value)")
        low = val.lower()
        if low in ("true", "false"):
            opts[key] = low == "true"
        else:
            try:
                opts[key] = int(val)
            except ValueError:
                try:
                    opts[key] = float(val)
                except ValueError:
                    opts[key] = val
    return name, opts


def run_bench(frames: Sequence[BenchFrame], methods: Sequence[str] = DEFAULT_METHODS,
              options: dict[str, dict] | None = None, peak: float = DEFAULT_PEAK_M,
              max_depth: float = DEFAULT_PEAK_M,
              progress: Callable[[str, str], None] | None = None) -> BenchResult:
    """Run every method on every frame (holes = ``frame.mask``), timing each call; score on hole pixels.

    ``methods`` are names of ``inpaint.METHODS`` or variant specs ``name:key=value,…``; ``options[name]`` applies to
    every spec of that method (the spec's own options win)."""
    options = options or {}
    res = BenchResult(list(frames), list(methods), peak_m=peak, max_depth_m=max_depth, options=dict(options))
    for fr in frames:
        raw = np.where(fr.mask, np.nan, fr.depth_gt).astype(np.float32)
        ok = fr.valid & (fr.depth_gt <= max_depth)
        for m in methods:
            name, spec_opts = parse_method(m)
            if name not in METHODS:
                raise KeyError(m)
            t0 = time.perf_counter()
            out = inpaint(raw, fr.mask, fr.guide, method=name, **{**options.get(name, {}), **spec_opts})
            res.seconds[(fr.name, m)] = time.perf_counter() - t0
            res.metrics[(fr.name, m)] = depth_metrics(out, fr.depth_gt, fr.mask, valid=ok, peak=peak)
            res.outputs[(fr.name, m)] = out
            if progress is not None:
                progress(fr.name, m)
    return res


def _fmt(v: float, digits: int) -> str:
    return "inf" if np.isinf(v) else f"{v:.{digits}f}"


_TABLE_METRICS = (("psnr_hole", "PSNR (dB, holes)", 2), ("rmse_hole", "RMSE (m, holes)", 3),
                  ("ssim_hole", "SSIM (holes)", 4), ("mae_hole", "MAE (m, holes)", 3))
_WHOLE_METRICS = (("psnr_whole", "PSNR (dB, whole image)", 2), ("rmse_whole", "RMSE (m, whole image)", 3),
                  ("ssim_whole", "SSIM (whole image)", 4))


def to_markdown(res: BenchResult, title: str = "Depth inpainting benchmark") -> str:
    """Table-1-shaped Markdown: per metric a table with images as rows, methods as columns, and an average row;
    then whole-image figures, then median time per frame."""
    lines = [f"# {title}", "",
             f"{len(res.frames)} frames; hole metrics on hole pixels with valid ground truth ≤ {res.max_depth_m:g} m; "
             f"PSNR peak {res.peak_m:g} m; SSIM Gaussian 11×11, σ 1.5, averaged over hole pixels.", ""]
    lines += ["| image | source | hole % |", "|---|---|---|"]
    for f in res.frames:
        lines.append(f"| {f.name} | {f.source} | {100 * float(f.mask.mean()):.1f} |")
    lines.append("")
    for key, label, digits in _TABLE_METRICS + _WHOLE_METRICS:
        lines += [f"## {label}", "", "| image | " + " | ".join(res.methods) + " |",
                  "|---|" + "---|" * len(res.methods)]
        for f in res.frames:
            lines.append(f"| {f.name} | " + " | ".join(_fmt(getattr(res.metrics[(f.name, m)], key), digits)
                                                      for m in res.methods) + " |")
        lines.append("| **average** | " + " | ".join(f"**{_fmt(res.mean_metric(m, key), digits)}**"
                                                     for m in res.methods) + " |")
        lines.append("")
    lines += ["## Median time per frame (s)", "", "| " + " | ".join(res.methods) + " |",
              "|" + "---|" * len(res.methods),
              "| " + " | ".join(f"{res.median_seconds(m):.3f}" for m in res.methods) + " |", ""]
    if "paper" in res.methods:
        base = res.mean_metric("paper", "rmse_hole")
        rel = [f"{m}: {100 * (base / res.mean_metric(m, 'rmse_hole') - 1):+.1f} %" for m in res.methods if m != "paper"]
        lines += ["Average hole RMSE of `paper` relative to each method (negative = paper lower): " + "; ".join(rel),
                  ""]
    return "\n".join(lines)


def to_json(res: BenchResult) -> dict:
    """Everything in the Markdown, machine-readable."""
    return {
        "peak_m": res.peak_m, "max_depth_m": res.max_depth_m, "methods": res.methods,
        "options": {k: {kk: (list(vv) if isinstance(vv, tuple) else vv) for kk, vv in v.items()}
                    for k, v in res.options.items()},
        "frames": [{"name": f.name, "source": f.source, "hole_ratio": float(f.mask.mean()),
                    "shape": list(f.depth_gt.shape),
                    "methods": {m: dict(res.metrics[(f.name, m)].to_dict(), seconds=res.seconds[(f.name, m)])
                                for m in res.methods}} for f in res.frames],
        "average": {m: {key: res.mean_metric(m, key) for key, _, _ in _TABLE_METRICS + _WHOLE_METRICS}
                    for m in res.methods},
        "median_seconds": {m: res.median_seconds(m) for m in res.methods},
    }


def write_bench(res: BenchResult, out: Path, source: str, wall_s: float) -> str:
    """Write ``results.md``, ``results.json`` and ``grid.png`` of a benchmark into ``out`` (atomically); returns the
    Markdown table."""
    from pipeline.atomic import atomic_path, write_json_atomic, write_text_atomic

    md = to_markdown(res, f"Depth inpainting benchmark ({source} frames)")
    js = to_json(res)
    js["source"] = source
    js["wall_s"] = float(wall_s)
    write_text_atomic(out / "results.md", md)
    write_json_atomic(out / "results.json", js)
    with atomic_path(out / "grid.png", suffix=".png") as tmp:
        tmp.write_bytes(figure_png(res))
    return md


def _colour_depth(d: np.ndarray, vmax: float, holes: np.ndarray | None = None) -> np.ndarray:
    img = cv2.applyColorMap(np.clip(np.nan_to_num(d) / vmax * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    if holes is not None:
        img[holes] = 0
    return img


def figure_png(res: BenchResult, max_rows: int = 4, error_max_m: float = 1.0) -> bytes:
    """PNG grid: per frame one row of [guide (RGB), raw depth with holes black, each method's result] and one row
    of [ground truth, hole mask, each method's |error| on hole pixels (0–``error_max_m`` m, inferno)]."""
    rows = []
    vmax = res.max_depth_m
    for f in res.frames[:max_rows]:
        h, w = f.depth_gt.shape
        if f.guide is None:
            g = np.zeros((h, w, 3), np.uint8)
        elif f.guide.ndim == 2:
            g = cv2.cvtColor(f.guide if f.guide.dtype == np.uint8 else
                             np.clip(f.guide * 255, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        else:
            g = f.guide.astype(np.uint8)
        top = [g, _colour_depth(f.depth_gt, vmax, f.mask)]
        bot = [_colour_depth(f.depth_gt, vmax), cv2.cvtColor(f.mask.astype(np.uint8) * 255, cv2.COLOR_GRAY2BGR)]
        for m in res.methods:
            out = res.outputs[(f.name, m)]
            top.append(_colour_depth(out, vmax))
            err = np.where(f.mask & f.valid, np.abs(out - f.depth_gt), 0)
            bot.append(cv2.applyColorMap(np.clip(err / error_max_m * 255, 0, 255).astype(np.uint8),
                                         cv2.COLORMAP_INFERNO))
        rows += [np.hstack(top), np.hstack(bot)]
    grid = np.vstack(rows)
    # column titles
    h, w = res.frames[0].depth_gt.shape
    header = np.full((28, grid.shape[1], 3), 255, np.uint8)
    for i, t in enumerate(["image / GT", "raw / mask"] + res.methods):
        cv2.putText(header, t, (i * w + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    grid = np.vstack([header, grid])
    scale = min(1.0, 2400 / grid.shape[1])
    if scale < 1.0:
        grid = cv2.resize(grid, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return encode_png_bytes(grid, None)


# ------------------------------------------------------------------------------------------------ frame sources
def procedural_frames(n_frames: int, seed: int = 0, ratios: Sequence[float] = (0.05, 0.15, 0.25, 0.40),
                      kinds: Sequence[str] = ("blobs", "stripes", "specks", "mixed"), height: int = 376,
                      width: int = 672, occlusion: bool = True) -> list[BenchFrame]:
    """Frames from ``inpaint.synthetic`` (procedural field depth, NOT the simulator): random masks cycling through
    ``kinds`` × ``ratios``, and (``occlusion``) stereo-occlusion + border-band masks computed from the depth."""
    from inpaint.masks import occlusion_mask, random_mask
    from inpaint.synthetic import field_depth

    frames = []
    for i in range(n_frames):
        f = field_depth(height, width, seed=seed * 1000 + i)
        guide = np.clip(f.guide * 255, 0, 255).astype(np.uint8)
        if occlusion and i % 2 == 1:
            mask = occlusion_mask(f.depth, 351.06 * 0.1187, 64)
            src = "procedural depth, stereo-occlusion + 64-px band mask"
        else:
            kind, ratio = kinds[i % len(kinds)], ratios[(i // len(kinds)) % len(ratios)]
            mask = random_mask(f.depth.shape, ratio, kind, seed=seed * 1000 + i)
            src = f"procedural depth, {kind} {int(ratio * 100)} % mask"
        frames.append(BenchFrame(f"proc{i:02d}", f.depth, f.valid, mask, guide, src))
    return frames


SIM_PRESETS = ("rosario-like-01", "rosario-like-02", "rosario-like-03")
STILL_FRAMES = 48  # the presets stand still for 3 s (45 frames at 15 Hz) before driving


def _sim_sequence(preset: str, seed: int, max_frames: int, progress: bool = False):
    """A short simulated sequence of ``preset`` (cached under ``<cache>/inpaint_bench/sim``; rendered once)."""
    from pipeline.sim.sequence import SimulatedSequence, simulate_sequence

    root = cache_dir_for_sim() / f"{preset}-s{seed}-f{max_frames}"
    seq = SimulatedSequence(root)
    if (root / "meta.json").is_file() and seq.n_frames >= max_frames:
        return seq
    duration = max_frames / RATE_CAMERA_HZ + 0.5
    return simulate_sequence(preset, root, seed=seed, duration_s=duration, max_frames=max_frames, progress=progress)


def cache_dir_for_sim():
    from pipeline.paths import cache_dir

    return cache_dir() / "inpaint_bench" / "sim"


def _pick(n_total: int, k: int, start: int) -> list[int]:
    start = min(start, max(0, n_total - 1))
    return sorted({int(round(x)) for x in np.linspace(start, n_total - 1, k)})


def sim_frames(n_frames: int, seed: int = 0, presets: Sequence[str] = SIM_PRESETS,
               progress: bool = False) -> list[BenchFrame]:
    """Benchmark frames from the simulator: exact rendered depth as ground truth, holes = the real StereoSGBM
    invalid mask (``pipeline.depth``, LR-checked) of a simulated stereo frame. Even-numbered frames use their own
    frame's mask; odd-numbered ones get the mask of a frame of another preset (transplanted). ``n_frames`` ≤ 3
    uses one frame per preset from the standing start (fast); more frames spread over the first seconds of driving.
    Sky / beyond 65 m has no ground truth and is never scored."""
    from pipeline.bag_reader import RosarioSequence
    from pipeline.depth import compute_depth

    per = int(np.ceil(n_frames / len(presets)))
    max_frames = 1 if per == 1 else STILL_FRAMES + 15 * per
    raw = []
    for p in presets:
        seq = _sim_sequence(p, seed, max_frames, progress)
        rig = seq.rig()
        picks = [0] if per == 1 else _pick(seq.n_frames, per, STILL_FRAMES)
        bag = RosarioSequence(seq.bag_path, seq.camchain_path)
        for fr in bag.stereo_frames(0, max(picks) + 1):
            if fr.index in picks:
                d = compute_depth(rig, fr.left_bgr, fr.right_bgr)
                raw.append((f"{p} #{fr.index}", seq.depth(fr.index).astype(np.float32), ~d.valid,
                            d.left_rect_grey))
    frames = []
    for i, (name, gt, mask, grey) in enumerate(raw[:n_frames]):
        valid = np.isfinite(gt)
        if i % 2 == 0 or len(raw) < 2:
            m, src = mask, f"sim {name}, its own SGBM mask"
        else:
            j = (i + per) % len(raw) if per > 1 else (i + 1) % len(raw)
            m, src = raw[j][2], f"sim {name}, SGBM mask of {raw[j][0]} (transplanted)"
        gt_filled = np.where(valid, gt, np.nan).astype(np.float32)
        frames.append(BenchFrame(f"sim{i:02d}", gt_filled, valid, m, grey, src))
    return frames


def sim_training_frames(n_frames: int, seed: int = 0, presets: Sequence[str] = SIM_PRESETS,
                        progress: bool = False):
    """Ground-truth depth of simulated frames for ``agrivio train-fusion`` (world seeds 1000 + seed + k, so the
    fields differ from the benchmark's); returns (frames, description)."""
    from inpaint.train import TrainingFrame

    per = int(np.ceil(n_frames / len(presets)))
    max_frames = STILL_FRAMES + 8 * per
    frames = []
    for k, p in enumerate(presets):
        s = 1000 + seed + k
        seq = _sim_sequence(p, s, max_frames, progress)
        for idx in _pick(seq.n_frames, per, STILL_FRAMES):
            gt = seq.depth(idx).astype(np.float32)
            frames.append(TrainingFrame(gt, np.isfinite(gt)))
    frames = frames[:n_frames]
    desc = (f"{len(frames)} simulated frames (pipeline.sim presets {', '.join(presets)}, seeds "
            f"{1000 + seed}..{1000 + seed + len(presets) - 1}, frames spread over the first "
            f"{max_frames / RATE_CAMERA_HZ:.1f} s; exact rendered depth, sky without ground truth)")
    return frames, desc
