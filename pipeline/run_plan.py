"""The resolved settings of a sequence's runs, built once before any stage runs and passed down as one object.

A :class:`RunPlan` holds everything a run of a sequence needs besides its variant and seed: where the sequence
came from (bag, GT, camchain, content identity), the depth and inpainting parameters, the MSCKF configuration as a
resolved :class:`msckf.config.MsckfConfig` (the ``--config`` YAML is parsed exactly once, by
:func:`pipeline.validate.resolve_msckf_config`), the evaluation options, the cache root and the sequence-level parts
of every run's input key (:mod:`pipeline.run_key`). It is a frozen, picklable dataclass: the batch runner ships it
to worker processes (or Ray tasks) inside each :class:`pipeline.batch.Job`, so no worker re-reads a settings file.

Data path (each arrow: what crosses the boundary)::

    CLI args ──(paths, names)──▶ run_matrix ──(MsckfConfig)──▶ prepare_sequence
      ──(RunPlan: DepthParams, InpaintParams, MsckfConfig, key parts)──▶ depth / inpaint stages, plan_jobs
      ──(Job: variant, seed, out_dir, JSON description, RunPlan)──▶ run_job (worker)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from eval.evaluate import EvalOptions
from eval.variants import DEPTH_INPAINTED, DEPTH_RAW, ODOMETRY
from msckf.config import MsckfConfig
from pipeline.depth import DepthParams
from pipeline.errors import AgrivioError
from pipeline.inpaint_stage import InpaintParams
from pipeline.run_key import job_key_parts
from pipeline.validate import resolve_msckf_config

#: Nearest-stamp association window of an evaluation, s (the dataset authors' ``evo`` protocol: 20 ms).
EVAL_MAX_DIFF_S = 0.02

Vec3 = tuple[float, float, float]
Mat3 = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class RunPlan:
    """Resolved settings shared by every run of one sequence (and one inpainting method).

    Attributes:
        name: sequence name (reports, run folders).
        source: the source as the user gave it (a bag path or a simulator preset).
        bag: the sequence's bag (or the first byte-split part), absolute path.
        gt: ground-truth TUM file (Rosario: GPS antenna positions), or None (then no metrics).
        camchain: Kalibr camchain YAML, or None (the shipped Rosario one).
        simulated: the sequence comes from the simulator.
        bag_identity: :meth:`RosarioSequence.identity` (content identity; selects the depth caches).
        cache_root: the cache root holding the depth and inpainted-depth caches.
        max_frames: stop every stage after this many stereo frames (None: whole sequence).
        depth: parameters of the depth stage (raw depth cache of ``depth-*`` runs).
        inpaint: parameters of the inpainting stage, or None when ``depth-inpainted`` is not run.
        msckf: the resolved MSCKF configuration (defaults + ``--config``).
        msckf_config_path: the ``--config`` file it was read from (provenance only; never read again), or None.
        lever_arm_imu: (3,) GPS antenna position in the IMU frame, m (None: compare IMU positions directly).
        lever_arm_base: (3,) antenna in base_link (``odometry`` variant), m, or None.
        R_base_imu: (3, 3) rotation IMU → base_link as nested tuples, or None.
        key_parts: the sequence-level parts of every run's input key (:func:`pipeline.run_key.sequence_key_parts`).
        quality: the bag's data-quality summary (:mod:`pipeline.data_quality`).
    """

    name: str
    source: str
    bag: str
    gt: str | None
    camchain: str | None
    simulated: bool
    bag_identity: str
    cache_root: str
    max_frames: int | None
    depth: DepthParams
    inpaint: InpaintParams | None
    msckf: MsckfConfig
    msckf_config_path: str | None = None
    lever_arm_imu: Vec3 | None = None
    lever_arm_base: Vec3 | None = None
    R_base_imu: Mat3 | None = None
    key_parts: dict[str, Any] | None = None
    quality: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        for name in ("lever_arm_imu", "lever_arm_base"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(float(x) for x in value))
        if self.R_base_imu is not None:
            object.__setattr__(self, "R_base_imu", tuple(tuple(float(x) for x in row) for row in self.R_base_imu))

    @property
    def inpaint_method(self) -> str | None:
        """The ``depth-inpainted`` method, or None when that variant is not run."""
        return self.inpaint.method if self.inpaint is not None else None

    def inputs(self) -> dict[str, Any]:
        """The run inputs as JSON-able options (the sequence manifest's ``inputs``, the records' ``job``)."""
        return {"bag": self.bag, "gt": self.gt, "camchain": self.camchain, "cache_root": self.cache_root,
                "inpaint_method": self.inpaint_method, "msckf_config": self.msckf_config_path,
                "lever_arm_imu": self.lever_arm_imu, "lever_arm_base": self.lever_arm_base,
                "R_base_imu": self.R_base_imu, "max_frames": self.max_frames}

    def variant_inputs(self, variant: str) -> dict[str, Any]:
        """:meth:`inputs` with only the options that apply to ``variant`` (no inpainting method unless
        ``depth-inpainted``)."""
        out = self.inputs()
        if variant != DEPTH_INPAINTED:
            out.pop("inpaint_method")
        return out

    def eval_options(self, variant: str) -> EvalOptions:
        """How a run of ``variant`` is evaluated against the GT.

        The VIO's 15 Hz poses always fall within 20 ms of a 5 Hz GPS fix: nearest-stamp association, the dataset
        authors' protocol. Wheel odometry runs at 10 Hz on its own clock phase, so its poses may all sit > 20 ms
        from every fix: there the GPS reference is interpolated (linearly, gaps ≤ 0.5 s) at the estimate's stamps.
        The lever arm is the antenna in the estimate's frame (base_link for odometry, the IMU otherwise).
        """
        odometry = variant == ODOMETRY
        return EvalOptions(align="se3", max_diff_s=EVAL_MAX_DIFF_S,
                           lever_arm_m=self.lever_arm_base if odometry else self.lever_arm_imu,
                           interpolate=odometry)

    def depth_params(self, variant: str) -> DepthParams | InpaintParams | None:
        """The parameters selecting the depth cache a run of ``variant`` reads (None: it reads no depth)."""
        if variant == DEPTH_RAW:
            return self.depth
        if variant == DEPTH_INPAINTED:
            if self.inpaint is None:
                raise AgrivioError(f"{self.name}: a depth-inpainted run needs an inpainting method in its plan")
            return self.inpaint
        return None

    def job_key_parts(self, variant: str, seed: int) -> dict[str, Any]:
        """The input-key parts of the run of ``variant`` with ``seed`` (:func:`pipeline.run_key.job_key_parts`)."""
        return job_key_parts(self.key_parts or {}, variant, seed)


__all__ = ["EVAL_MAX_DIFF_S", "RunPlan", "resolve_msckf_config"]
