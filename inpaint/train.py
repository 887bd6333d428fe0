"""Self-supervised training of the fusion network (paper step 7).

Data: depth maps with exact ground truth (simulated). Known regions are hidden with realistic masks (stereo
occlusion/border-band masks made from the depth itself, plus random blobs, stripes and specks at 5–40 %), the
paper's fill runs with ``fusion="mean"``, and every block it fuses is recorded with its candidates, target,
quality and the ground truth of the block. The network learns to reconstruct the hidden pixels from those
inputs. Loss: smooth-L1 on hidden pixels with valid ground truth, in the per-block normalised units of
``fusion_net.normalise``. CPU, seeded (numpy and torch), deterministic for a fixed thread count.

``TrainConfig.formulation`` chooses whose blocks are recorded: ``"greedy"`` (``paper-greedy``, as above) or ``"c2f"``
(``paper``: the blocks of its refinement passes at levels ``c2f_levels``, recorded while fusing with the best block;
there the target channel is the current estimate on every pixel and ``known`` marks the measured pixels, and the
ground truth of a level is the masked pyramid of the exact depth). ``noise_fraction`` of the c2f masks see known
pixels with stereo-matching noise (``inpaint.synthetic.stereo_noise``) while the ground truth stays exact, so that
the network does not learn to copy noise as structure (real stereo depth is noisy; the simulator benchmark's known
pixels are exact).

The library returns the trained weights as bytes and the record as a dict; ``pipeline`` writes the files.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from inpaint.fusion_net import FusionNet, normalise
from inpaint.masks import occlusion_mask, random_mask
from inpaint.method import INVERSE_REF_M, inpaint_paper
from inpaint.synthetic import stereo_noise


@dataclass(frozen=True)
class TrainingFrame:
    """One ground-truth frame: ``depth`` float32 H×W metres, ``valid`` bool H×W (False: no ground truth, e.g. sky;
    never scored; NaN depth there is a hole the fill must cross, finite depth is known context)."""

    depth: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class TrainConfig:
    """Training settings. ``focal_baseline``: f·B (px·m) for the stereo occlusion masks (Rosario ZED:
    351.06 px × 0.1187 m). ``max_seconds``: wall-clock cap of the optimisation loop."""

    seed: int = 0
    masks_per_frame: int = 2
    ratio_range: tuple[float, float] = (0.05, 0.40)
    focal_baseline: float = 351.06 * 0.1187
    batch: int = 256
    lr: float = 2e-3
    epochs: int = 40
    max_seconds: float = 300.0
    val_fraction: float = 0.1
    max_examples: int = 60000
    method_options: dict = field(default_factory=dict)
    net: dict = field(default_factory=dict)
    threads: int = 1
    formulation: str = "greedy"  # whose candidates: "greedy" (paper-greedy) or "c2f" (paper, coarse-to-fine)
    c2f_levels: tuple[int, ...] = (0, 1)  # levels of the c2f passes whose blocks are recorded
    clamp: bool = False  # train through the per-pixel candidate-range clamp (the c2f method applies it)
    noise_fraction: float = 0.0  # c2f: share of masks whose known pixels carry stereo noise (ground truth exact)
    noise_px: float = 0.15  # σ of that disparity noise (pixels; ``inpaint.synthetic.stereo_noise``)


@dataclass
class Examples:
    """Recorded blocks (N of them): cands N×S×b×b, target N×b×b, known N×b×b (bool), q N×S, valid N×S (bool),
    gt N×b×b, gt_valid N×b×b (bool); all in the method's working domain (inverse depth by default)."""

    cands: np.ndarray
    target: np.ndarray
    known: np.ndarray
    q: np.ndarray
    valid: np.ndarray
    gt: np.ndarray
    gt_valid: np.ndarray
    target_all: bool = False  # c2f: ``target`` is the current estimate on every pixel, ``known`` the measured ones

    def __len__(self) -> int:
        return len(self.gt)


def training_mask(frame: TrainingFrame, rng: np.random.Generator, cfg: TrainConfig) -> np.ndarray:
    """A realistic hole mask: half the time stereo occlusions + border band topped up with blobs, otherwise a
    random blobs/stripes/specks mix; ratio drawn uniformly from ``cfg.ratio_range``."""
    ratio = float(rng.uniform(*cfg.ratio_range))
    seed = int(rng.integers(0, 2**31 - 1))
    if rng.random() < 0.5:
        band = int(rng.choice([0, 32, 64]))
        m = occlusion_mask(np.nan_to_num(frame.depth, nan=1e3), cfg.focal_baseline, band)
        if m.mean() < ratio:
            m |= random_mask(m.shape, max(0.0, ratio - float(m.mean())), "blobs", seed)
        return m
    return random_mask(frame.depth.shape, ratio, str(rng.choice(["blobs", "stripes", "specks", "mixed"])), seed)


def collect_examples(frames: Sequence[TrainingFrame], cfg: TrainConfig,
                     progress: Callable[[int, int], None] | None = None) -> Examples:
    """Run the paper's fill (``fusion="mean"``) on masked frames and record every fused block with its ground truth."""
    if cfg.formulation == "c2f":
        return _collect_c2f(frames, cfg, progress)
    rng = np.random.default_rng(cfg.seed)
    rec: dict[str, list[np.ndarray]] = {k: [] for k in ("cands", "target", "known", "q", "valid", "gt", "gt_valid")}
    opts = dict(cfg.method_options)
    opts["fusion"] = "mean"
    domain = opts.get("domain", "inverse")
    total = len(frames) * cfg.masks_per_frame
    done = 0
    for frame in frames:
        with np.errstate(invalid="ignore"):
            gt_work = INVERSE_REF_M / np.maximum(frame.depth, 1e-6) if domain == "inverse" else frame.depth
        for _ in range(cfg.masks_per_frame):
            mask = training_mask(frame, rng, cfg)
            if mask.all() or not mask.any():
                continue

            def observer(centres: np.ndarray, cands: np.ndarray, target: np.ndarray, known: np.ndarray,
                         q: np.ndarray, valid: np.ndarray, _gt: np.ndarray = gt_work,
                         _ok: np.ndarray = frame.valid) -> None:
                hb = target.shape[1] // 2
                off = np.arange(-hb, hb + 1)
                ys = centres[:, 0, None, None] + off[None, :, None]
                xs = centres[:, 1, None, None] + off[None, None, :]
                ys, xs = np.broadcast_arrays(ys, xs)
                gt_blk, ok_blk = _gt[ys, xs].astype(np.float32), _ok[ys, xs] & np.isfinite(_gt[ys, xs])
                use = (ok_blk & ~known).any(axis=(1, 2))  # blocks with something to learn from
                for k, v in (("cands", cands), ("target", target), ("known", known), ("q", q), ("valid", valid),
                             ("gt", gt_blk), ("gt_valid", ok_blk)):
                    rec[k].append(np.array(v[use]))

            inpaint_paper(np.where(mask, np.nan, frame.depth).astype(np.float32), mask, observer=observer, **opts)
            done += 1
            if progress is not None:
                progress(done, total)
    ex = Examples(**{k: np.concatenate(v) for k, v in rec.items()})
    if len(ex) > cfg.max_examples:
        keep = np.sort(rng.choice(len(ex), cfg.max_examples, replace=False))
        ex = Examples(**{k: getattr(ex, k)[keep] for k in rec})
    return ex


def _collect_c2f(frames: Sequence[TrainingFrame], cfg: TrainConfig,
                 progress: Callable[[int, int], None] | None) -> Examples:
    """Blocks of the coarse-to-fine method's refinement passes (levels ``cfg.c2f_levels``), fused there with
    ``fusion="best"`` while recording; ground truth of a level = the masked pyramid of the exact depth."""
    from inpaint.c2f import inpaint_paper_c2f
    from inpaint.pyramid import masked_pyrdown

    rng = np.random.default_rng(cfg.seed)
    keys = ("cands", "target", "known", "q", "valid", "gt", "gt_valid")
    rec: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    opts = dict(cfg.method_options)
    opts.setdefault("fusion", "best")
    domain = opts.get("domain", "inverse")
    total = len(frames) * cfg.masks_per_frame
    done = 0
    for frame in frames:
        ok0 = frame.valid & np.isfinite(frame.depth)
        with np.errstate(invalid="ignore", divide="ignore"):
            g0 = np.where(ok0, INVERSE_REF_M / np.maximum(frame.depth, 1e-6) if domain == "inverse" else frame.depth,
                          0.0).astype(np.float32)
        gts, oks = [g0], [ok0]
        wgt = ok0.astype(np.float32)
        for _ in range(max(cfg.c2f_levels)):
            g, wgt = masked_pyrdown(gts[-1], wgt)
            gts.append(g)
            oks.append(wgt > 0.99)
        for _ in range(cfg.masks_per_frame):
            mask = training_mask(frame, rng, cfg)
            if mask.all() or not mask.any():
                continue

            def observer(lv: int, centres: np.ndarray, cands: np.ndarray, target: np.ndarray, known: np.ndarray,
                         q: np.ndarray, valid: np.ndarray, gts: list[np.ndarray] = gts,
                         oks: list[np.ndarray] = oks) -> None:
                if lv not in cfg.c2f_levels:
                    return
                hb = target.shape[1] // 2
                off = np.arange(-hb, hb + 1)
                ys, xs = np.broadcast_arrays(centres[:, 0, None, None] + off[None, :, None],
                                             centres[:, 1, None, None] + off[None, None, :])
                gt_blk, ok_blk = gts[lv][ys, xs], oks[lv][ys, xs]
                use = (ok_blk & ~known).any(axis=(1, 2))
                for k, v in (("cands", cands), ("target", target), ("known", known), ("q", q), ("valid", valid),
                             ("gt", gt_blk), ("gt_valid", ok_blk)):
                    rec[k].append(np.array(v[use]))

            measured = frame.depth
            if cfg.noise_fraction > 0 and rng.random() < cfg.noise_fraction:
                # known pixels as a stereo matcher measures them; the net learns to fill towards the exact depth
                with np.errstate(invalid="ignore"):
                    measured = stereo_noise(np.nan_to_num(frame.depth, nan=1e3), int(rng.integers(0, 2**31 - 1)),
                                            cfg.focal_baseline, cfg.noise_px)
            depth = np.where(mask | ~np.isfinite(frame.depth), np.nan, measured).astype(np.float32)
            inpaint_paper_c2f(depth, mask | ~np.isfinite(frame.depth), observer=observer, **opts)
            done += 1
            if progress is not None:
                progress(done, total)
    # levels differ in block size and scale count: pad every record to the largest (edge-replicated values,
    # padded pixels known and without ground truth; missing scales invalid), which the network ignores
    b0 = max(a.shape[-1] for a in rec["target"])
    s0 = max(a.shape[1] for a in rec["cands"])
    for i in range(len(rec["target"])):
        p = (b0 - rec["target"][i].shape[-1]) // 2
        ds = s0 - rec["cands"][i].shape[1]
        if p == 0 and ds == 0:
            continue
        sp = ((0, 0), (p, p), (p, p))
        rec["cands"][i] = np.pad(np.pad(rec["cands"][i], ((0, 0), (0, 0), (p, p), (p, p)), mode="edge"),
                                 ((0, 0), (0, ds), (0, 0), (0, 0)))
        rec["q"][i] = np.pad(rec["q"][i], ((0, 0), (0, ds)), constant_values=-10.0)
        rec["valid"][i] = np.pad(rec["valid"][i], ((0, 0), (0, ds)), constant_values=False)
        rec["target"][i] = np.pad(rec["target"][i], sp, mode="edge")
        rec["gt"][i] = np.pad(rec["gt"][i], sp, mode="edge")
        rec["known"][i] = np.pad(rec["known"][i], sp, constant_values=True)
        rec["gt_valid"][i] = np.pad(rec["gt_valid"][i], sp, constant_values=False)
    ex = Examples(**{k: np.concatenate(v) for k, v in rec.items()}, target_all=True)
    if len(ex) > cfg.max_examples:
        keep = np.sort(rng.choice(len(ex), cfg.max_examples, replace=False))
        ex = Examples(**{k: getattr(ex, k)[keep] for k in keys}, target_all=True)
    return ex


@dataclass
class TrainResult:
    """Trained weights and the record that ships beside them (JSON-serialisable ``meta``)."""

    state_dict: dict
    meta: dict

    def weights_bytes(self) -> bytes:
        buf = io.BytesIO()
        torch.save(self.state_dict, buf)
        return buf.getvalue()


def _tensors(ex: Examples, idx: np.ndarray) -> tuple[torch.Tensor, ...]:
    trusted = np.ones(ex.known[idx].shape, bool) if ex.target_all else ex.known[idx]
    cn, tn, mu, sigma = normalise(ex.cands[idx], ex.target[idx], trusted, ex.valid[idx])
    w = (~ex.known[idx]) & ex.gt_valid[idx] & np.isfinite(ex.gt[idx])
    gtn = np.where(w, (ex.gt[idx] - mu[:, None, None]) / sigma[:, None, None], 0.0)
    return (torch.from_numpy(cn), torch.from_numpy(tn), torch.from_numpy((~ex.known[idx]).astype(np.float32)),
            torch.from_numpy(ex.q[idx].astype(np.float32)), torch.from_numpy(ex.valid[idx]),
            torch.from_numpy(gtn.astype(np.float32)), torch.from_numpy(w.astype(np.float32)))


def _clamped(pred: torch.Tensor, cands: torch.Tensor, valid: torch.Tensor, on: bool) -> torch.Tensor:
    """The prediction kept within the per-pixel range of the valid candidates (``C2FOptions.clamp_fusion``)."""
    if not on:
        return pred
    vm = valid[:, :, None, None]
    lo = torch.where(vm, cands, torch.full_like(cands, float("inf"))).amin(dim=1)
    hi = torch.where(vm, cands, torch.full_like(cands, float("-inf"))).amax(dim=1)
    return torch.minimum(torch.maximum(pred, lo), hi)


def _loss(pred: torch.Tensor, gt: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    per = torch.nn.functional.smooth_l1_loss(pred, gt, reduction="none", beta=0.1)
    return (per * w).sum() / w.sum().clamp(min=1.0)


def train_fusion(ex: Examples, cfg: TrainConfig, progress: Callable[[int, int, float], None] | None = None
                 ) -> TrainResult:
    """Train a ``FusionNet`` on recorded blocks; returns weights and a record (losses, timing, config)."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed + 1)
    order = rng.permutation(len(ex))
    n_val = max(1, int(len(ex) * cfg.val_fraction))
    val_idx, tr_idx = np.sort(order[:n_val]), order[n_val:]
    net = FusionNet(**cfg.net)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs)
    val = _tensors(ex, val_idx)
    with torch.no_grad():
        base_val = float(_loss((torch.softmax(torch.where(val[4], 4.0 * val[3], torch.full_like(val[3], -1e9)), 1)
                                [:, :, None, None] * val[0]).sum(1), val[5], val[6]))
        best_single = val[0][torch.arange(len(val_idx)),
                             torch.argmax(torch.where(val[4], val[3], torch.full_like(val[3], -1e9)), 1)]
        best_val = float(_loss(best_single, val[5], val[6]))
    history = []
    t0 = time.perf_counter()
    epochs_run = 0
    train_loss = float("nan")
    for epoch in range(cfg.epochs):
        net.train()
        perm = tr_idx[rng.permutation(len(tr_idx))]
        tot, cnt = 0.0, 0
        for i in range(0, len(perm), cfg.batch):
            cn, tn, hole, q, valid, gtn, w = _tensors(ex, np.sort(perm[i:i + cfg.batch]))
            loss = _loss(_clamped(net(cn, tn, hole, q, valid), cn, valid, cfg.clamp), gtn, w)
            opt.zero_grad()
            loss.backward()
            opt.step()
            tot += float(loss.detach()) * len(cn)
            cnt += len(cn)
        sched.step()
        net.eval()
        with torch.no_grad():
            vl = float(_loss(_clamped(net(*val[:5]), val[0], val[4], cfg.clamp), val[5], val[6]))
        train_loss = tot / max(cnt, 1)
        history.append({"epoch": epoch + 1, "train_loss": train_loss, "val_loss": vl,
                        "elapsed_s": time.perf_counter() - t0})
        epochs_run = epoch + 1
        if progress is not None:
            progress(epoch + 1, cfg.epochs, vl)
        if time.perf_counter() - t0 > cfg.max_seconds:
            break
    meta = {
        "config": net.config,
        "train_config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "seed": cfg.seed,
        "n_examples": len(ex), "n_train": int(len(tr_idx)), "n_val": int(n_val),
        "block": int(ex.gt.shape[1]), "scales": int(ex.cands.shape[1]),
        "epochs_run": epochs_run, "final_train_loss": train_loss,
        "final_val_loss": history[-1]["val_loss"] if history else None,
        "val_loss_softmax_mean_fusion": base_val, "val_loss_best_single_block": best_val,
        "optimisation_wall_s": time.perf_counter() - t0, "history": history,
        "n_parameters": int(sum(p.numel() for p in net.parameters())),
        "loss": "smooth-L1 (beta 0.1) on hidden pixels with valid ground truth, per-block normalised units",
    }
    return TrainResult({k: v.detach().clone() for k, v in net.state_dict().items()}, meta)
