"""The whole chain for one or more sequences: read → depth (cached) → inpaint (cached) → runs → records → report.

``run_matrix`` checks the options and resolves the MSCKF ``--config`` once; ``prepare_sequence`` resolves a source
(a Rosario bag with its GT file, or a simulator preset), builds its :class:`pipeline.run_plan.RunPlan` (every setting
of its runs, resolved, with the input-key parts) before any stage runs, then fills the depth and inpainted-depth
caches from that plan; ``plan_jobs`` expands variants × seeds into batch jobs carrying the plan, whose run folders
live under ``OUT/<sequence>/<variant>/seed<k>/``; ``run_matrix`` runs them with :mod:`pipeline.batch` and writes
the comparison report with :mod:`eval`.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from eval.variants import DEPTH_INPAINTED, ODOMETRY, VARIANTS
from msckf.config import MsckfConfig
from pipeline.bag_reader import RosarioSequence
from pipeline.batch import INPUT_KEY, Job, failed_record, run_jobs
from pipeline.data_quality import check_stereo_pairing, sequence_quality
from pipeline.depth import DepthParams
from pipeline.depth_cache import DepthCache, depth_stream
from pipeline.errors import AgrivioError
from pipeline.inpaint_stage import InpaintParams, check_method, ensure_inpainted
from pipeline.paths import ROSARIO_CAMCHAIN
from pipeline.prep_stage import prepare_depth_caches
from pipeline.run_job import lever_arms_from_tf, run_job
from pipeline.run_key import code_fingerprint, input_key, sequence_key_parts
from pipeline.run_plan import RunPlan
from pipeline.sources import ResolvedSource, resolve_source
from pipeline.validate import check_ground_truth, check_output_dir, check_positive_int, resolve_msckf_config

DEFAULT_VARIANTS = VARIANTS


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
    """A sequence whose depth (and inpainted depth) caches are complete (up to ``max_frames``).

    ``plan`` holds every resolved setting of its runs (:class:`pipeline.run_plan.RunPlan`), the sequence-level
    input-key parts and the data-quality summary among them; the stage measurements are kept beside it.
    """

    name: str
    source: ResolvedSource
    plan: RunPlan
    n_frames: int
    stage_timings: dict[str, float] = field(default_factory=dict)
    depth_stats: dict[str, Any] = field(default_factory=dict)

    @property
    def key_parts(self) -> dict[str, Any]:
        """The sequence-level parts of every run's input key (:mod:`pipeline.run_key`)."""
        return self.plan.key_parts or {}

    @property
    def quality(self) -> dict[str, Any]:
        """The bag's data-quality summary (:mod:`pipeline.data_quality`)."""
        return self.plan.quality or {}


@dataclass
class CheckedSequence:
    """A sequence whose inputs passed every up-front check (bag, calibration, stereo pairing, IMU, GT)."""

    spec: SequenceSpec
    source: ResolvedSource
    quality: dict[str, Any]
    source_s: float


def user_error_types() -> tuple[type[BaseException], ...]:
    """The exception types that mean "bad input" (one line, exit 2), not a bug."""
    from eval.errors import EvalInputError
    from msckf.errors import MsckfInputError

    return (AgrivioError, EvalInputError, MsckfInputError, FileNotFoundError)


def check_variants(variants: Sequence[str]) -> None:
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise AgrivioError(f"unknown variant(s) {', '.join(bad)}; choose from {', '.join(VARIANTS)}")


def check_sequence(spec: SequenceSpec, variants: Sequence[str], cache_root: Path, progress: bool = True
                   ) -> CheckedSequence:
    """Resolve the source and check its inputs before any depth, inpainting or VIO work.

    Opens the bag (container, topics, camera_info, calibration), measures its data quality (stereo pairing, IMU
    NaN / gaps / repeated stamps, dropped frames) and checks the GT file against the bag's time span.
    """
    check_variants(variants)
    t0 = time.perf_counter()
    src = resolve_source(spec.source, gt=spec.gt, camchain=spec.camchain, duration_s=spec.duration_s,
                         seed=spec.sim_seed, cache_root=cache_root, progress=progress)
    source_s = time.perf_counter() - t0
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    _ = seq.calibration  # camera_info × camchain, checked now rather than in every worker
    quality = sequence_quality(seq, cache_root)
    if any(v != ODOMETRY for v in variants):
        check_stereo_pairing(src.bag, quality)
    if src.gt is not None:
        check_ground_truth(src.gt, seq.start_ns / 1e9, seq.end_ns / 1e9)
    return CheckedSequence(spec, src, quality, source_s)


def build_plan(checked: CheckedSequence, variants: Sequence[str], cache_root: Path, inpaint_method: str,
               msckf: MsckfConfig, msckf_config: str | Path | None = None, max_frames: int | None = None,
               depth: DepthParams | None = None) -> RunPlan:
    """The :class:`RunPlan` of a checked sequence: its identity, stage parameters, the resolved MSCKF config,
    lever arms and input-key parts. Reads only the bag's index and ``tf_static`` (and hashes the small GT and
    camchain files); no depth, inpainting or VIO work."""
    src = checked.source
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    depth = depth or DepthParams()
    inpaint = InpaintParams(depth=depth, method=inpaint_method) if DEPTH_INPAINTED in variants else None
    levers = dict(src.lever_arms if src.lever_arms is not None else lever_arms_from_tf(seq))
    identity = seq.identity()
    key_parts = sequence_key_parts(identity, src.gt, src.camchain or ROSARIO_CAMCHAIN, max_frames, levers,
                                   msckf.to_flat_dict(), depth.key(), inpaint.key() if inpaint else None,
                                   code_fingerprint())
    return RunPlan(name=checked.spec.name or src.name, source=src.source, bag=str(src.bag),
                   gt=str(src.gt) if src.gt else None, camchain=str(src.camchain) if src.camchain else None,
                   simulated=src.simulated, bag_identity=identity, cache_root=str(cache_root), max_frames=max_frames,
                   depth=depth, inpaint=inpaint, msckf=msckf,
                   msckf_config_path=str(msckf_config) if msckf_config is not None else None,
                   key_parts=key_parts, quality=checked.quality, **levers)


def prepare_depth(checked: CheckedSequence, variants: Sequence[str], methods: Sequence[str], cache_root: Path,
                  max_frames: int | None = None, workers: int | None = None, progress: bool = True
                  ) -> dict[str, Any] | None:
    """Fill the depth cache and the inpainted caches of ``methods`` that the ``depth-*`` variants of a checked
    sequence read, in one pass on one process pool (:func:`pipeline.prep_stage.prepare_depth_caches`); the
    statistics, or None when no variant reads depth. :func:`prepare_sequence` then finds them cached."""
    if not any(v.startswith("depth") for v in variants):
        return None
    src = checked.source
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    depth = DepthParams()
    inpaints = [InpaintParams(depth=depth, method=m) for m in methods] if DEPTH_INPAINTED in variants else []
    return prepare_depth_caches(seq, depth, inpaints, cache_root, stop_index=max_frames, workers=workers,
                                progress=progress)


def prepare_sequence(spec: SequenceSpec, variants: Sequence[str], cache_root: Path, inpaint_method: str = "paper",
                     msckf_config: str | Path | None = None, max_frames: int | None = None,
                     progress: bool = True, checked: CheckedSequence | None = None,
                     msckf: MsckfConfig | None = None) -> PreparedSequence:
    """Plan the runs of a sequence, then fill the caches the variants need (depth for depth-*, inpainting for
    depth-inpainted), frames ``0 .. max_frames-1`` only when ``max_frames`` is given.

    The MSCKF config is resolved first (``msckf``: already resolved from ``msckf_config`` by the caller; else the
    file is read here), before any check or stage: a bad ``--config`` fails before any depth work. ``checked``: the
    result of :func:`check_sequence` (run now when None).
    """
    if msckf is None:
        msckf = resolve_msckf_config(msckf_config)
    checked = checked or check_sequence(spec, variants, cache_root, progress)
    plan = build_plan(checked, variants, cache_root, inpaint_method, msckf, msckf_config, max_frames)
    src = checked.source
    timings: dict[str, float] = {"source_s": checked.source_s}
    seq = RosarioSequence(src.bag, camchain=src.camchain)
    n_frames = seq.count("/stereo/left/image_raw")
    if max_frames is not None:
        n_frames = min(n_frames, max_frames)
    depth_stats: dict[str, Any] = {}
    if any(v.startswith("depth") for v in variants):
        t0 = time.perf_counter()
        # every frame present and intact: the hole ratios come from the chunk index, no image is decoded
        cached_holes = DepthCache(cache_root, plan.bag_identity, plan.depth).hole_ratios(n_frames)
        if cached_holes is not None:  # a warm cache: no image is decoded here (the runs read what they need)
            holes = cached_holes.tolist()
        else:
            holes = [frame.hole_ratio for frame in depth_stream(seq, plan.depth, cache=True, progress=progress,
                                                               cache_root=cache_root, stop_index=max_frames)]
        timings["depth_s"] = time.perf_counter() - t0
        if holes:
            import numpy as np

            h = np.asarray(holes)
            depth_stats = {"hole_ratio_median": float(np.median(h)), "hole_ratio_p10": float(np.percentile(h, 10)),
                           "hole_ratio_p90": float(np.percentile(h, 90)), "frames": int(h.size)}
    if plan.inpaint is not None:
        t0 = time.perf_counter()
        stats: dict[str, Any] = {}
        ensure_inpainted(seq, plan.inpaint, cache_root, progress=progress, stats=stats, stop_index=max_frames)
        timings["inpaint_s"] = time.perf_counter() - t0
        depth_stats["inpainted_frames"] = {"computed": int(stats.get("computed", 0)),
                                           "cached": int(stats.get("cached", 0))}
        if stats.get("computed"):
            timings["inpaint_ms_per_frame"] = 1e3 * stats["compute_s"] / stats["computed"]
    return PreparedSequence(plan.name, src, plan, n_frames, timings, depth_stats)


def plan_jobs(prepared: PreparedSequence, variants: Sequence[str], seeds: Sequence[int], out_dir: Path,
              folder_suffix: str = "") -> list[Job]:
    """One job per variant × seed, each carrying the sequence's :class:`RunPlan` (what the worker runs from) and
    a JSON description for its record: the inputs that apply to the variant, its input key and parts.

    Run folders are ``OUT/<sequence>/<variant><folder_suffix>/seed<k>``; a suffix keeps the runs of a second
    inpainting method (e.g. ``-telea``) beside those of the first.
    """
    plan = prepared.plan
    jobs = []
    for variant in variants:
        for seed in seeds:
            folder = out_dir / prepared.name / f"{variant}{folder_suffix}" / f"seed{seed}"
            parts = plan.job_key_parts(variant, int(seed))
            options = plan.variant_inputs(variant)
            options.update({INPUT_KEY: input_key(parts), "input_key_parts": parts,
                            "data_quality": plan.quality, "simulated": plan.simulated})
            jobs.append(Job(prepared.name, plan.source, variant, int(seed), str(folder), options, plan=plan))
    return jobs


def write_sequence_manifest(prepared: PreparedSequence, out_dir: Path) -> None:
    """``OUT/<sequence>/sequence.json``: where the data came from and what the stages measured."""
    from pipeline.atomic import write_json_atomic

    write_json_atomic(out_dir / prepared.name / "sequence.json", {
        "name": prepared.name, "source": prepared.source.source, "bag": str(prepared.source.bag),
        "gt": str(prepared.source.gt) if prepared.source.gt else None, "simulated": prepared.source.simulated,
        "n_frames": prepared.n_frames, "stage_timings": prepared.stage_timings, "depth": prepared.depth_stats,
        "inputs": prepared.plan.inputs(), "input_key_parts": prepared.key_parts,
        "data_quality": prepared.quality,
    })


def _spec_name(spec: SequenceSpec) -> str:
    if spec.name:
        return spec.name
    name = Path(spec.source).name
    return name.split(".bag")[0] if ".bag" in name else name


def _failed_sequence_records(spec: SequenceSpec, reason: str, variants: Sequence[str], seeds: Sequence[int],
                             out_dir: Path) -> list[dict[str, Any]]:
    """Failed records (written) for every run of a sequence whose inputs were refused; retried next time."""
    from pipeline.atomic import write_json_atomic

    records = []
    for variant in variants:
        for seed in seeds:
            job = Job(_spec_name(spec), spec.source, variant, int(seed),
                      str(out_dir / _spec_name(spec) / variant / f"seed{seed}"))
            record = failed_record(job, reason)
            write_json_atomic(job.record_path, record)
            records.append(record)
    return records


def _note_preparation(prepared: PreparedSequence, prep: dict[str, Any], inpaint_method: str) -> None:
    """Put what the one-pass preparation did into the sequence manifest: its wall time and worker seconds, and
    per inpainting method the frames computed now and found cached (the stage counts of :func:`prepare_sequence`
    would only see the caches it filled)."""
    prepared.stage_timings["prepare_s"] = prep["wall_s"]
    prepared.stage_timings["depth_worker_s"] = prep["depth_s"]
    n = prepared.n_frames
    prepared.depth_stats["depth_frames"] = {"computed": prep["depth_computed"], "cached": n - prep["depth_computed"]}
    for method, computed in prep["inpainted"].items():
        key = "inpainted_frames" if method == inpaint_method else f"inpainted_frames[{method}]"
        prepared.depth_stats[key] = {"computed": computed, "cached": n - computed}
        prepared.stage_timings["inpaint_worker_s" if method == inpaint_method else f"inpaint_worker_s[{method}]"] = \
            prep["inpaint_s"][method]
        if computed:
            prepared.stage_timings[f"inpaint_ms_per_frame[{method}]"] = 1e3 * prep["inpaint_s"][method] / computed


def run_matrix(specs: Sequence[SequenceSpec], variants: Sequence[str], seeds: Sequence[int], out_dir: Path,
               cache_root: Path, inpaint_method: str = "paper", msckf_config: str | None = None,
               executor: str = "local", workers: int | None = None, ray_address: str | None = None,
               max_frames: int | None = None, progress: bool = True, keep_going: bool = False,
               keep_failed: bool = False, extra_inpaint_methods: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Check every input, prepare every sequence, then run every (sequence, variant, seed) job; return the records.

    Options, the MSCKF config and every sequence's inputs are checked first, before any depth, inpainting or VIO
    work. ``keep_going`` (batches): a sequence whose inputs are refused (or whose depth stage fails on bad data)
    is recorded as failed runs with the reason and the others go on; otherwise the error is raised. Failed records
    are retried unless ``keep_failed``. ``extra_inpaint_methods``: more methods of ``depth-inpainted`` (when that
    variant is asked for), run in ``OUT/<sequence>/depth-inpainted-<method>/``; all jobs run as one matrix.
    """
    check_variants(variants)
    check_positive_int("max_frames", max_frames)
    check_positive_int("workers", workers)
    extra = [m for m in dict.fromkeys(extra_inpaint_methods) if m != inpaint_method] \
        if DEPTH_INPAINTED in variants else []
    methods = ([inpaint_method] if DEPTH_INPAINTED in variants else []) + extra
    for method in methods:
        check_method(method)
    msckf = resolve_msckf_config(msckf_config)  # the one read of --config; every run gets this object
    check_output_dir(out_dir)
    user_errors = user_error_types()
    failed: list[dict[str, Any]] = []
    checked: list[CheckedSequence] = []
    for spec in specs:
        try:
            checked.append(check_sequence(spec, variants, cache_root, progress))
        except user_errors as exc:
            if not keep_going:
                raise
            print(f"agrivio: sequence {spec.source} refused: {exc}", file=sys.stderr)
            failed += _failed_sequence_records(spec, f"{type(exc).__name__}: {exc}", variants, seeds, out_dir)
    jobs: list[Job] = []
    for c in tqdm(checked, desc="sequences", unit="seq", disable=not progress or len(checked) < 2):
        try:
            prep = prepare_depth(c, variants, methods, cache_root, max_frames, workers, progress)
            prepared = prepare_sequence(c.spec, variants, cache_root, inpaint_method, msckf_config, max_frames,
                                        progress, checked=c, msckf=msckf)
        except user_errors as exc:
            if not keep_going:
                raise
            print(f"agrivio: sequence {c.spec.source} failed: {exc}", file=sys.stderr)
            failed += _failed_sequence_records(c.spec, f"{type(exc).__name__}: {exc}", variants, seeds, out_dir)
            continue
        jobs += plan_jobs(prepared, variants, seeds, out_dir)
        for method in extra:
            try:
                more = prepare_sequence(c.spec, [DEPTH_INPAINTED], cache_root, method, msckf_config, max_frames,
                                        progress, checked=c, msckf=msckf)
            except user_errors as exc:
                if not keep_going:
                    raise
                print(f"agrivio: sequence {c.spec.source} failed ({method}): {exc}", file=sys.stderr)
                continue
            prepared.depth_stats[f"inpainted_frames[{method}]"] = more.depth_stats.get("inpainted_frames")
            prepared.stage_timings[f"inpaint_s[{method}]"] = more.stage_timings.get("inpaint_s", 0.0)
            jobs += plan_jobs(more, [DEPTH_INPAINTED], seeds, out_dir, folder_suffix=f"-{method}")
        if prep is not None:
            _note_preparation(prepared, prep, inpaint_method)
        write_sequence_manifest(prepared, out_dir)
    records = run_jobs(jobs, run_job, executor=executor, workers=workers, ray_address=ray_address,
                       progress=progress, keep_failed=keep_failed) if jobs else []
    return records + failed


def load_manifest(out_dir: Path, name: str) -> dict[str, Any]:
    return json.loads((out_dir / name / "sequence.json").read_text())
