"""The run record: one JSON-able dict per VIO run (or odometry baseline run), ok or failed.

Schema (``record_type: "run"``, ``schema_version: 1``)::

    sequence        str   e.g. "rosario-01" or a simulator preset
    variant         str   stereo | depth-raw | depth-inpainted | odometry | an ablation name
    inpaint_method  str | None   e.g. "paper", "telea" (depth-inpainted only)
    seed            int
    status          "ok" | "failed"
    failure_reason  str | None   (required when failed)
    config_hash     str   :func:`config_hash` of the run's configuration
    code_version    str   git describe or package version (computed by the pipeline)
    metrics         dict  flat metrics (``eval.evaluate.Evaluation.metrics()``: ate_rmse_m, ate_mean_m, rpe, ...)
    timings         dict  seconds per stage, e.g. {"total_s": 812.4, "vio_s": 640.0}
    estimate_path   str | None   TUM file of the estimate, relative to the record's folder (or absolute)
    gt_path         str | None   TUM ground truth, relative to the record's folder (or absolute)
    label           str | None   display name of the variant (default: see :meth:`RunRecord.display_variant`)
    extra           dict  any other keys found in the JSON (kept on round trip)

Writing the file (atomically) is the pipeline's job; this module only converts.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from eval.errors import EvalInputError

__all__ = ["RunRecord", "variant_display_name", "config_hash",
           "RECORD_TYPE", "SCHEMA_VERSION", "DEFAULT_INPAINT_METHOD", "is_run_record"]

RECORD_TYPE = "run"
SCHEMA_VERSION = 1
#: The inpainting method whose runs form the "after" column (the paper's method); others are labelled ablations.
DEFAULT_INPAINT_METHOD = "paper"


def variant_display_name(variant: str, inpaint_method: str | None) -> str:
    """A variant as tables show it: ``depth-inpainted`` for the paper's method, ``depth-inpainted[<method>]`` for
    another inpainting method, else ``variant``."""
    if inpaint_method and inpaint_method != DEFAULT_INPAINT_METHOD:
        return f"{variant}[{inpaint_method}]"
    return variant
STATUSES = ("ok", "failed")


def _canonical(obj: Any) -> Any:
    """JSON-able canonical form: tuples → lists, floats finite, keys as strings."""
    if isinstance(obj, Mapping):
        return {str(k): _canonical(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else repr(obj)
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalar
        return _canonical(obj.item())
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    return str(obj)


def config_hash(config: Mapping[str, Any]) -> str:
    """A short, stable hash (16 hex digits of SHA-256) of a configuration mapping.

    Key order does not matter; tuples and lists hash alike; numpy scalars hash as Python numbers.
    """
    text = json.dumps(_canonical(config), sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def is_run_record(obj: Any) -> bool:
    """True for a dict that claims to be a run record (``record_type == "run"``)."""
    return isinstance(obj, Mapping) and obj.get("record_type") == RECORD_TYPE


@dataclass(frozen=True)
class RunRecord:
    """One run's outcome (see the module docstring for the fields and units)."""

    sequence: str
    variant: str
    seed: int
    status: str = "ok"
    failure_reason: str | None = None
    inpaint_method: str | None = None
    config_hash: str = ""
    code_version: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    estimate_path: str | None = None
    gt_path: str | None = None
    label: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.sequence, str) or not self.sequence:
            raise EvalInputError(f"run record: 'sequence' must be a non-empty string, got {self.sequence!r}")
        if not isinstance(self.variant, str) or not self.variant:
            raise EvalInputError(f"run record: 'variant' must be a non-empty string, got {self.variant!r}")
        if self.status not in STATUSES:
            raise EvalInputError(f"run record: 'status' must be one of {STATUSES}, got {self.status!r}")
        if self.status == "failed" and not self.failure_reason:
            object.__setattr__(self, "failure_reason", "unknown (no reason recorded)")
        try:
            object.__setattr__(self, "seed", int(self.seed))
        except (TypeError, ValueError):
            raise EvalInputError(f"run record: 'seed' must be an integer, got {self.seed!r}") from None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def display_variant(self) -> str:
        """The variant as shown in tables: ``label`` if set; ``depth-inpainted`` for the paper's method;
        ``depth-inpainted[<method>]`` for another inpainting method; else ``variant``."""
        return self.label or variant_display_name(self.variant, self.inpaint_method)

    def metric(self, name: str) -> float | None:
        """A numeric metric or None (missing, null or not finite). ``ate_rmse_pct_distance`` is derived: ATE RMSE
        as a percentage of the reference path length (``100 · ate_rmse_m / ref_path_length_m``)."""
        if name == "ate_rmse_pct_distance":
            rmse, length = self.metric("ate_rmse_m"), self.metric("ref_path_length_m")
            return 100.0 * rmse / length if rmse is not None and length is not None and length > 0 else None
        v = self.metrics.get(name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            return None
        return float(v)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (``extra`` keys are merged at the top level, the record's own keys win)."""
        out: dict[str, Any] = dict(_canonical(self.extra))
        for f in fields(self):
            if f.name != "extra":
                out[f.name] = _canonical(getattr(self, f.name))
        out["record_type"] = RECORD_TYPE
        out["schema_version"] = SCHEMA_VERSION
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "<record>") -> RunRecord:
        """Parse a record dict; unknown keys go to ``extra``. Missing optional keys take defaults.

        Ok and failed records share one layout (the batch runner's failed records carry the inpainting method at
        the top level too).

        Raises:
            EvalInputError: naming ``source`` when a required key is missing or has a wrong type.
        """
        if not isinstance(data, Mapping):
            raise EvalInputError(f"{source}: a run record must be a JSON object")
        missing = [k for k in ("sequence", "variant") if k not in data]
        if missing:
            raise EvalInputError(f"{source}: run record lacks {', '.join(missing)}")
        known = {f.name for f in fields(cls)} - {"extra"}
        kwargs: dict[str, Any] = {k: data[k] for k in known if k in data}
        reserved = known | {"record_type", "schema_version", "extra"}
        extra = {k: v for k, v in data.items() if k not in reserved}
        if "extra" in data and isinstance(data["extra"], Mapping):  # a record written with a nested extra
            extra.update(data["extra"])
        kwargs.setdefault("seed", -1 if data.get("seed") is None else data["seed"])
        if kwargs.get("seed") is None:
            kwargs["seed"] = -1
        for key in ("metrics", "timings"):
            if kwargs.get(key) is None:
                kwargs[key] = {}
            elif not isinstance(kwargs[key], Mapping):
                raise EvalInputError(f"{source}: run record field {key!r} must be an object")
            kwargs[key] = dict(kwargs[key])
        try:
            return cls(extra=extra, **kwargs)
        except EvalInputError as exc:
            raise EvalInputError(f"{source}: {exc}") from None
