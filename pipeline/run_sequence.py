"""The whole chain for one or more sequences: read → depth (cached) → inpaint (cached) → runs → records → report.

``prepare_sequence`` resolves a source (a Rosario bag with its GT file, or a simulator preset) and fills the depth
and inpainted-depth caches once; ``plan_jobs`` expands variants × seeds into batch jobs whose run folders live under
``OUT/<sequence>/<variant>/seed<k>/``; ``run_matrix`` runs them with :mod:`pipeline.batch` and writes the
comparison report with :mod:`eval`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pipeline.bag_reader import RosarioSequence
from pipeline.batch import Job, run_jobs
from pipeline.depth import DepthParams
from pipeline.depth_cache import depth_stream
from pipeline.errors import AgrivioError
from pipeline.inpaint_stage import InpaintParams, inpainted_stream
from pipeline.run_job import VARIANTS, RunInputs, lever_arms_from_tf, run_job
from pipeline.sources import ResolvedSource, resolve_source

DEFAULT_VARIANTS = ("stereo", "depth-raw", "depth-inpainted", "odometry")


@dataclass(frozen=True)
class SequenceSpec:
    """A sequence to run: ``source`` is a bag path or a simulator preset; ``gt`` a TUM file (bags only)."""

    source: str
    name: str | None = None
    gt: str | None = None
    camchain: str | None = None
    duration_s: float | None = None
    sim_seed: int = 0


@dataclass
class PreparedSequence:
    """A sequence whose depth (and inpainted depth) caches are complete."""

    name: str
    source: ResolvedSource
    inputs: RunInputs
    n_frames: int
    stage_timings: dict[str, float] = field(default_factory=dict)
    depth_stats: dict[str, Any] = field(default_factory=dict)


def prepare_sequence(spec: SequenceSpec, variants: Sequence[str], cache_root: Path, inpaint_method: str = "paper",
                     msckf_config: str | None = None, max_frames: int | None = None,
                     progress: bool = True) -> PreparedSequence:
    """Resolve the source and fill the caches the variants need (depth for depth-*, inpainting for depth-inpainted)."""
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise AgrivioError(f"unknown variant(s) {', '.join(bad)}; choose from {', '.join(VARIANTS)}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    src = resolve_source(spec.source, gt=spec.gt, camchain=spec.camchain, duration_s=spec.duration_s,
                         seed=spec.sim_seed, cache_root=cache_root, progress=progress)
    timings["source_s"] = time.perf_counter() - t0
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    n_frames = seq.count("/stereo/left/image_raw")
    if max_frames is not None:
        n_frames = min(n_frames, max_frames)
    depth_stats: dict[str, Any] = {}
    if any(v.startswith("depth") for v in variants):
        t0 = time.perf_counter()
        holes = []
        for frame in depth_stream(seq, DepthParams(), cache=True, progress=progress, cache_root=cache_root):
            holes.append(frame.hole_ratio)
        timings["depth_s"] = time.perf_counter() - t0
        if holes:
            import numpy as np

            h = np.asarray(holes)
            depth_stats = {"hole_ratio_median": float(np.median(h)), "hole_ratio_p10": float(np.percentile(h, 10)),
                           "hole_ratio_p90": float(np.percentile(h, 90)), "frames": int(h.size)}
    if "depth-inpainted" in variants:
        t0 = time.perf_counter()
        stats: dict[str, Any] = {}
        for _ in inpainted_stream(seq, InpaintParams(method=inpaint_method), cache_root, progress=progress,
                                  stats=stats):
            pass
        timings["inpaint_s"] = time.perf_counter() - t0
        if stats.get("computed"):
            timings["inpaint_ms_per_frame"] = 1e3 * stats["compute_s"] / stats["computed"]
    levers = src.lever_arms if src.lever_arms is not None else lever_arms_from_tf(seq)
    inputs = RunInputs(bag=str(src.bag), gt=str(src.gt) if src.gt else None,
                       camchain=str(src.camchain) if src.camchain else None, cache_root=str(cache_root),
                       inpaint_method=inpaint_method, msckf_config=msckf_config, max_frames=max_frames, **levers)
    return PreparedSequence(spec.name or src.name, src, inputs, n_frames, timings, depth_stats)


def plan_jobs(prepared: PreparedSequence, variants: Sequence[str], seeds: Sequence[int], out_dir: Path) -> list[Job]:
    jobs = []
    for variant in variants:
        for seed in seeds:
            folder = out_dir / prepared.name / variant / f"seed{seed}"
            jobs.append(Job(prepared.name, prepared.source.source, variant, int(seed), str(folder),
                            prepared.inputs.to_options()))
    return jobs


def write_sequence_manifest(prepared: PreparedSequence, out_dir: Path) -> None:
    """``OUT/<sequence>/sequence.json``: where the data came from and what the stages measured."""
    from pipeline.atomic import write_json_atomic

    write_json_atomic(out_dir / prepared.name / "sequence.json", {
        "name": prepared.name, "source": prepared.source.source, "bag": str(prepared.source.bag),
        "gt": str(prepared.source.gt) if prepared.source.gt else None, "simulated": prepared.source.simulated,
        "n_frames": prepared.n_frames, "stage_timings": prepared.stage_timings, "depth": prepared.depth_stats,
        "inputs": prepared.inputs.to_options(),
    })


def run_matrix(specs: Sequence[SequenceSpec], variants: Sequence[str], seeds: Sequence[int], out_dir: Path,
               cache_root: Path, inpaint_method: str = "paper", msckf_config: str | None = None,
               executor: str = "local", workers: int | None = None, ray_address: str | None = None,
               max_frames: int | None = None, progress: bool = True) -> list[dict[str, Any]]:
    """Prepare every sequence, then run every (sequence, variant, seed) job; return the records."""
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs: list[Job] = []
    for spec in tqdm(specs, desc="sequences", unit="seq", disable=not progress or len(specs) < 2):
        prepared = prepare_sequence(spec, variants, cache_root, inpaint_method, msckf_config, max_frames, progress)
        write_sequence_manifest(prepared, out_dir)
        jobs += plan_jobs(prepared, variants, seeds, out_dir)
    return run_jobs(jobs, run_job, executor=executor, workers=workers, ray_address=ray_address, progress=progress)


def load_manifest(out_dir: Path, name: str) -> dict[str, Any]:
    return json.loads((out_dir / name / "sequence.json").read_text())
