"""How realistic is a simulated sequence for stereo and tracking? Measured on its own bag with the project's
depth stage (``pipeline.depth.compute_depth``) against the simulator's exact depth.

Per analysed frame:

* **holes** of the SGBM depth (``valid == False``) and their causes, each hole pixel assigned to the first
  matching class, in this order (``HOLE_CLASSES``):

  1. ``sky`` — the ground truth shows sky;
  2. ``far`` — ground-truth disparity below the depth stage's smallest valid disparity (or depth beyond
     65.5 m: tree line, far canopy);
  3. ``border`` — the left border band where SGBM has no full disparity range (``u < num_disparities``), the
     match would fall outside the right image, or the match lies in the right image's own border band (where
     the right-reference pass of the LR check has no full range: ``u − d > W − num_disparities``);
  4. ``occlusion`` — the point is hidden in the right camera (the rectified right ground-truth depth in front
     of it by more than 2 %), or, without right depth, within 2 px of a ground-truth disparity jump > 1.5 px;
  5. ``glare`` — sun veil/flare above 8 % of full scale, or a saturated pixel;
  6. ``textureless`` — the rectified left image is flat around the pixel (7×7 standard deviation < 3 DN);
  7. ``leaves`` — on leaves or canopy (repetitive, self-similar texture, thin structures);
  8. ``other`` — the rest (mostly soil).

* **depth error** on valid pixels with ground truth: absolute (m), relative, and disparity error (px).
* **FAST corners** per frame (threshold 10, like the Rosario S-MSCKF config) on the raw left image.
* **KLT tracks** over consecutive frames: pyramidal Lucas-Kanade (15×15 window, 3 levels), forward-backward
  check (1 px), features replenished to 300 per frame on a 4×5 grid; a track's length is the number of frames
  it survived.

Everything is computed from the images in the bag; nothing here alters them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from msckf.camera import StereoRig
from pipeline.depth import DepthParams, compute_depth, to_grey
from pipeline.png_codec import encode_png_bytes
from pipeline.sim.render import LABEL_CANOPY, LABEL_LEAF, LABEL_SKY

HOLE_CLASSES = ("sky", "far", "border", "occlusion", "glare", "textureless", "leaves", "other")
_CLASS_COLOURS = {"sky": (235, 206, 135), "far": (180, 130, 70), "border": (128, 128, 128),
                  "occlusion": (0, 0, 255), "glare": (0, 255, 255), "textureless": (255, 0, 255),
                  "leaves": (0, 200, 0), "other": (0, 128, 255)}


@dataclass
class FrameRealism:
    """Per-frame measurements (ratios are fractions of all pixels)."""

    index: int
    hole_ratio: float
    hole_causes: dict[str, float]
    abs_err_m: np.ndarray
    rel_err: np.ndarray
    disp_err_px: np.ndarray
    fast_corners: int


def classify_holes(valid: np.ndarray, gt_depth: np.ndarray, label: np.ndarray, glare: np.ndarray,
                   left_rect_grey: np.ndarray, rig: StereoRig, params: DepthParams,
                   right_depth: np.ndarray | None = None) -> np.ndarray:
    """Index into ``HOLE_CLASSES`` for every pixel (int8, -1 where SGBM gave depth). See the module docstring."""
    h, w = valid.shape
    fb = rig.fx * rig.baseline
    with np.errstate(divide="ignore", invalid="ignore"):
        disp = np.where(np.isfinite(gt_depth), fb / gt_depth, 0.0)
    u = np.arange(w)[None, :].repeat(h, 0)
    holes = ~valid
    out = np.full((h, w), -1, np.int8)
    remaining = holes.copy()

    def assign(cls: str, mask: np.ndarray) -> None:
        m = remaining & mask
        out[m] = HOLE_CLASSES.index(cls)
        remaining[m] = False

    assign("sky", label == LABEL_SKY)
    assign("far", ~np.isfinite(gt_depth) | (disp < params.min_valid_disparity_px))
    # left band: no full disparity range; right band: the LR check's right-reference matching has none there
    band = params.min_disparity + params.num_disparities
    assign("border", (u < band) | (u - disp < 0) | (u - disp > w - band))
    if right_depth is not None:
        ur = np.clip(np.rint(u - disp).astype(np.int64), 0, w - 1)
        zr = np.take_along_axis(np.nan_to_num(right_depth, nan=np.inf), ur, axis=1)
        occluded = zr < gt_depth * 0.98
    else:
        jump = np.zeros_like(valid)
        dd = np.abs(np.diff(disp, axis=1)) > 1.5
        jump[:, 1:] |= dd
        jump[:, :-1] |= dd
        occluded = cv2.dilate(jump.astype(np.uint8), np.ones((1, 5), np.uint8)).astype(bool)
    assign("occlusion", occluded)
    assign("glare", (glare > 0.08) | (left_rect_grey >= 250))
    g = left_rect_grey.astype(np.float32)
    mean = cv2.blur(g, (7, 7))
    sd = np.sqrt(np.maximum(cv2.blur(g * g, (7, 7)) - mean * mean, 0))
    assign("textureless", sd < 3.0)
    assign("leaves", (label == LABEL_LEAF) | (label == LABEL_CANOPY))
    assign("other", np.ones_like(valid))
    return out


def analyse_frame(index: int, rig: StereoRig, left_bgr: np.ndarray, right_bgr: np.ndarray, gt_depth: np.ndarray,
                  label: np.ndarray, glare: np.ndarray, params: DepthParams,
                  right_depth: np.ndarray | None = None) -> tuple[FrameRealism, Any, np.ndarray]:
    """Measurements of one frame; also returns the depth frame and the hole-cause image (for the gallery)."""
    d = compute_depth(rig, left_bgr, right_bgr, params, index=index)
    causes = classify_holes(d.valid, gt_depth, label, glare, d.left_rect_grey, rig, params, right_depth)
    n = causes.size
    frac = {c: float(np.count_nonzero(causes == i)) / n for i, c in enumerate(HOLE_CLASSES)}
    m = d.valid & np.isfinite(gt_depth)
    est, gt = d.depth_m[m].astype(np.float64), gt_depth[m].astype(np.float64)
    fb = rig.fx * rig.baseline
    fast = cv2.FastFeatureDetector_create(threshold=10, nonmaxSuppression=True)
    corners = len(fast.detect(to_grey(left_bgr)))
    fr = FrameRealism(index, d.hole_ratio, frac, np.abs(est - gt), np.abs(est - gt) / gt,
                      np.abs(fb / est - fb / gt), corners)
    return fr, d, causes


def klt_track_lengths(frames_grey: list[np.ndarray], max_features: int = 300) -> dict[str, float]:
    """Track FAST corners with pyramidal LK through consecutive grey frames; statistics of track lengths (frames).

    Tracks still alive at the end are counted with their length so far (censored).
    """
    if len(frames_grey) < 2:
        return {"tracks": 0}
    fast = cv2.FastFeatureDetector_create(threshold=10, nonmaxSuppression=True)
    lk = dict(winSize=(15, 15), maxLevel=3, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))
    h, w = frames_grey[0].shape
    rows, cols = 4, 5
    per_cell = max(1, max_features // (rows * cols))

    def detect(img: np.ndarray, existing: np.ndarray) -> np.ndarray:
        mask = np.full((h, w), 255, np.uint8)
        for x, y in existing.reshape(-1, 2):
            cv2.circle(mask, (int(x), int(y)), 8, 0, -1)
        kps = fast.detect(img, mask)
        pts = []
        counts = np.zeros((rows, cols), int)
        for x, y in existing.reshape(-1, 2):
            counts[min(int(y * rows / h), rows - 1), min(int(x * cols / w), cols - 1)] += 1
        for kp in sorted(kps, key=lambda k: -k.response):
            r, c = min(int(kp.pt[1] * rows / h), rows - 1), min(int(kp.pt[0] * cols / w), cols - 1)
            if counts[r, c] < per_cell:
                counts[r, c] += 1
                pts.append(kp.pt)
        return np.array(pts, np.float32).reshape(-1, 1, 2)

    pts = detect(frames_grey[0], np.zeros((0, 1, 2), np.float32))
    ages = np.ones(len(pts), int)
    finished: list[int] = []
    for prev, cur in zip(frames_grey[:-1], frames_grey[1:]):
        if len(pts):
            nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts, None, **lk)
            back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, nxt, None, **lk)
            fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
            inside = (nxt[:, 0, 0] >= 0) & (nxt[:, 0, 0] < w) & (nxt[:, 0, 1] >= 0) & (nxt[:, 0, 1] < h)
            ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < 1.0) & inside
            finished.extend(ages[~ok].tolist())
            pts, ages = nxt[ok], ages[ok] + 1
        new = detect(cur, pts)
        pts = np.concatenate([pts, new]) if len(new) else pts
        ages = np.concatenate([ages, np.ones(len(new), int)])
    lengths = np.array(finished + ages.tolist())
    return {"tracks": int(lengths.size), "median": float(np.median(lengths)), "mean": float(lengths.mean()),
            "p90": float(np.percentile(lengths, 90)), "frac_ge_10": float(np.mean(lengths >= 10)),
            "frames": len(frames_grey)}


@dataclass
class SequenceRealism:
    """Summary of a sequence (see :func:`summarize`)."""

    name: str
    frames: list[FrameRealism] = field(default_factory=list)
    klt: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        hr = np.array([f.hole_ratio for f in self.frames])
        causes = {c: float(np.mean([f.hole_causes[c] for f in self.frames])) for c in HOLE_CLASSES}
        abs_err = np.concatenate([f.abs_err_m for f in self.frames])
        rel = np.concatenate([f.rel_err for f in self.frames])
        de = np.concatenate([f.disp_err_px for f in self.frames])
        corners = np.array([f.fast_corners for f in self.frames])
        return {
            "name": self.name, "frames": len(self.frames),
            "hole_ratio": {"median": float(np.median(hr)), "p10": float(np.percentile(hr, 10)),
                           "p90": float(np.percentile(hr, 90))},
            "hole_causes_mean_fraction_of_image": causes,
            "hole_causes_share_of_holes": {c: v / max(float(hr.mean()), 1e-9) for c, v in causes.items()},
            "depth_abs_error_m": {"median": float(np.median(abs_err)), "p90": float(np.percentile(abs_err, 90))},
            "depth_rel_error": {"median": float(np.median(rel)), "p90": float(np.percentile(rel, 90))},
            "disparity_error_px": {"median": float(np.median(de)), "p90": float(np.percentile(de, 90)),
                                   "bad_gt_1px": float(np.mean(de > 1.0))},
            "fast_corners": {"median": float(np.median(corners)), "p10": float(np.percentile(corners, 10)),
                             "p90": float(np.percentile(corners, 90))},
            "klt_track_length_frames": self.klt,
        }


def colour_depth(depth: np.ndarray, max_m: float = 20.0) -> np.ndarray:
    """BGR visualisation of a depth map (turbo, near = red; black where there is none)."""
    v = np.clip(1.0 - np.nan_to_num(depth, nan=np.inf) / max_m, 0, 1)
    img = cv2.applyColorMap((v * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~np.isfinite(depth)] = 0
    return img


def colour_causes(causes: np.ndarray) -> np.ndarray:
    img = np.zeros(causes.shape + (3,), np.uint8)
    for i, c in enumerate(HOLE_CLASSES):
        img[causes == i] = _CLASS_COLOURS[c]
    return img


def gallery_png(left: np.ndarray, right: np.ndarray, gt: np.ndarray, est: np.ndarray, causes: np.ndarray,
                title: str) -> bytes:
    """One PNG: raw left, raw right, hole causes / GT depth, SGBM depth, legend."""
    def tag(img: np.ndarray, text: str) -> np.ndarray:
        img = img.copy()
        cv2.rectangle(img, (0, 0), (len(text) * 9 + 8, 20), (0, 0, 0), -1)
        cv2.putText(img, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        return img

    h, w = left.shape[:2]
    legend = np.full((h, w, 3), 30, np.uint8)
    cv2.putText(legend, title, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    for i, c in enumerate(HOLE_CLASSES):
        y = 60 + 28 * i
        cv2.rectangle(legend, (14, y - 14), (34, y + 4), _CLASS_COLOURS[c], -1)
        cv2.putText(legend, f"hole: {c}", (44, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (230, 230, 230), 1, cv2.LINE_AA)
    cv2.putText(legend, "depth colour: 0 m (red) .. 20 m (blue), black = none", (10, 60 + 28 * 8 + 10),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (230, 230, 230), 1, cv2.LINE_AA)
    top = np.concatenate([tag(left, "left (raw)"), tag(right, "right (raw)"), legend], 1)
    bottom = np.concatenate([tag(colour_depth(gt), "exact depth (rectified left)"),
                             tag(colour_depth(est), "SGBM depth (depth stage)"), tag(colour_causes(causes),
                                                                                     "SGBM holes by cause")], 1)
    return encode_png_bytes(np.concatenate([top, bottom], 0), None)


def markdown(summaries: list[dict[str, Any]], note: str = "") -> str:
    """Markdown report of several sequences' summaries."""
    lines = ["# Simulator realism", "", note, "",
             "| preset | frames | holes median (p10–p90) | depth err median / p90 (m) | rel. err median / p90 | "
             "disp. err median / p90 (px) | FAST corners median (p10–p90) | KLT track length median / p90 "
             "(frames), ≥10 |", "|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        h, a, r, d, c, k = (s["hole_ratio"], s["depth_abs_error_m"], s["depth_rel_error"], s["disparity_error_px"],
                            s["fast_corners"], s["klt_track_length_frames"])
        klt = (f"{k['median']:.0f} / {k['p90']:.0f}, {100 * k['frac_ge_10']:.0f} %" if k.get("tracks") else "–")
        lines.append(f"| {s['name']} | {s['frames']} | {100 * h['median']:.1f} % ({100 * h['p10']:.1f}–"
                     f"{100 * h['p90']:.1f}) | {a['median']:.3f} / {a['p90']:.3f} | {100 * r['median']:.1f} % / "
                     f"{100 * r['p90']:.1f} % | {d['median']:.2f} / {d['p90']:.2f} | {c['median']:.0f} "
                     f"({c['p10']:.0f}–{c['p90']:.0f}) | {klt} |")
    lines += ["", "Hole causes (share of all hole pixels, mean over frames):", "",
              "| preset | " + " | ".join(HOLE_CLASSES) + " |", "|---" * (len(HOLE_CLASSES) + 1) + "|"]
    for s in summaries:
        sh = s["hole_causes_share_of_holes"]
        lines.append(f"| {s['name']} | " + " | ".join(f"{100 * sh[c]:.1f} %" for c in HOLE_CLASSES) + " |")
    return "\n".join(lines) + "\n"
