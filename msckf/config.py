"""The one typed configuration of the MSCKF VIO (filter + front end): a composition of option groups.

:class:`MsckfConfig` holds one frozen, validated group per component (:mod:`msckf.options`, plus
:class:`~msckf.frontend_config.FrontendConfig`), as OpenVINS' ``VioManagerOptions`` does; each group documents its
fields with units and defaults (CIFASIS' ``launch/msckf_vio_rosario.launch`` values, references/rosario.md §7,
msckf.md §1.14, and the constants msckf_vio hard-codes; "[port]" marks this port's own choices).

Override from YAML/dicts with :func:`load_config`: flat keys (``feature_noise: 0.01``, as before the grouping) are
mapped to their group by the one table :data:`FLAT_KEYS`; a group may also be given as a nested mapping
(``update: {feature_noise: 0.01}``); ``frontend`` is always a nested mapping.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from msckf.errors import MsckfInputError
from msckf.frontend_config import FrontendConfig
from msckf.options import (
    DepthOptions,
    HealthOptions,
    ImuNoise,
    InitOptions,
    PropagationOptions,
    TriangulationParams,
    UpdateOptions,
    WindowOptions,
)

__all__ = ["FLAT_KEYS", "GROUPS", "MsckfConfig", "load_config"]


#: The one name → group table: every flat parameter key (today's YAML / dict / ``--config`` names) and the
#: :class:`MsckfConfig` group holding it, in the order of the flat mapping (:meth:`MsckfConfig.to_flat_dict`).
#: The field of the group has the same name as the key. ``frontend`` is a group of its own (a nested mapping).
FLAT_KEYS: dict[str, str] = {
    "max_cam_state_size": "window",
    "rotation_threshold": "window",
    "translation_threshold": "window",
    "tracking_rate_threshold": "window",
    "feature_translation_threshold": "triangulation",
    "mono_translation_threshold": "triangulation",
    "position_std_threshold": "health",
    "gyro_noise": "imu_noise",
    "acc_noise": "imu_noise",
    "gyro_bias_noise": "imu_noise",
    "acc_bias_noise": "imu_noise",
    "initial_velocity": "init",
    "velocity_cov": "init",
    "gyro_bias_cov": "init",
    "acc_bias_cov": "init",
    "extrinsic_rotation_cov": "init",
    "extrinsic_translation_cov": "init",
    "feature_noise": "update",
    "gate_noise": "update",
    "stereo_gate_noise": "update",
    "stereo_feature_noise": "update",
    "stereo_track_drift_psd": "update",
    "chi2_quantile": "update",
    "chi2_dof": "update",
    "robust_k": "update",
    "track_drift_psd": "update",
    "max_update_rows": "update",
    "update_method": "update",
    "retriangulate": "update",
    "zupt_max_flow": "update",
    "zupt_velocity_sigma": "update",
    "zupt_only_at_start": "update",
    "extrinsics_after_motion": "update",
    "depth_fallback": "update",
    "depth_fallback_measured": "update",
    "gate_depth_scale": "update",
    "observability_constrained": "propagation",
    "propagate_to_image_time": "propagation",
    "depth_seed": "depth",
    "depth_row": "depth",
    "depth_inv_sigma": "depth",
    "depth_rel_sigma": "depth",
    "depth_gate_sigma": "depth",
    "depth_motion_rel_sigma": "depth",
    "depth_track_bias": "depth",
    "depth_keep_mono": "depth",
    "depth_sigma_at_prediction": "depth",
    "depth_shared_rel_sigma": "depth",
    "depth_fills_only_unmeasured": "depth",
    "depth_sigma_scale": "depth",
    "depth_min_rel_sigma": "depth",
    "huber_epsilon": "triangulation",
    "estimation_precision": "triangulation",
    "initial_damping": "triangulation",
    "outer_loop_max_iteration": "triangulation",
    "inner_loop_max_iteration": "triangulation",
    "init_imu_samples": "init",
    "init_max_gyro_std": "init",
    "init_max_gyro_mean": "init",
    "init_max_acc_std": "init",
    "init_max_acc_drift": "init",
    "init_max_gyro_drift": "init",
    "static_bias_from_window": "init",
    "static_velocity_cov": "init",
    "static_tilt_from_acc_bias": "init",
    "max_speed": "health",
    "frame_rate": "health",
}


#: The group types of :class:`MsckfConfig`, by attribute name.
GROUPS: dict[str, type] = {"window": WindowOptions, "imu_noise": ImuNoise, "propagation": PropagationOptions,
                           "init": InitOptions, "update": UpdateOptions, "depth": DepthOptions,
                           "triangulation": TriangulationParams, "health": HealthOptions,
                           "frontend": FrontendConfig}


@dataclass(frozen=True)
class MsckfConfig:
    """Every parameter of the VIO, one option group per component (field docs and units in each group).

    Attributes:
        window: :class:`~msckf.options.WindowOptions`, sliding window and pruning.
        imu_noise: :class:`~msckf.options.ImuNoise`, continuous-time IMU noise σ's.
        propagation: :class:`~msckf.options.PropagationOptions`, OC-EKF and propagation to the image time.
        init: :class:`~msckf.options.InitOptions`, initial state / covariance and the static initialisation.
        update: :class:`~msckf.options.UpdateOptions`, feature noise, χ² gate, robust weights, update solver.
        depth: :class:`~msckf.options.DepthOptions`, depth-map observations (variants ``depth-*``).
        triangulation: :class:`~msckf.options.TriangulationParams`, motion check and LM triangulation.
        health: :class:`~msckf.options.HealthOptions`, online reset, divergence, time budget.
        frontend: :class:`~msckf.frontend_config.FrontendConfig`, the image front end.

    Build one from flat or nested keys with :func:`load_config`; :meth:`to_flat_dict` gives the flat mapping that
    run records and run keys use.
    """

    window: WindowOptions = field(default_factory=WindowOptions)
    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    propagation: PropagationOptions = field(default_factory=PropagationOptions)
    init: InitOptions = field(default_factory=InitOptions)
    update: UpdateOptions = field(default_factory=UpdateOptions)
    depth: DepthOptions = field(default_factory=DepthOptions)
    triangulation: TriangulationParams = field(default_factory=TriangulationParams)
    health: HealthOptions = field(default_factory=HealthOptions)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            cls = GROUPS[f.name]
            if not isinstance(getattr(self, f.name), cls):
                raise MsckfInputError(f"msckf config: {f.name} must be a {cls.__name__}, "
                                      f"got {type(getattr(self, f.name)).__name__}")

    def to_flat_dict(self) -> dict[str, Any]:
        """The flat mapping of every parameter, ``{key: value}`` in :data:`FLAT_KEYS` order plus ``frontend`` (a
        plain dict). It is exactly the mapping of the former flat ``MsckfConfig.to_dict()``, so run records and run
        keys (pipeline/run_key.py) of an unchanged config stay byte-identical; round-trips through
        :func:`load_config`."""
        d: dict[str, Any] = {name: getattr(getattr(self, group), name) for name, group in FLAT_KEYS.items()}
        d["initial_velocity"] = list(self.init.initial_velocity)
        d["frontend"] = self.frontend.to_dict()
        return d

    def to_dict(self) -> dict[str, Any]:
        """Same as :meth:`to_flat_dict` (the form run records store)."""
        return self.to_flat_dict()

    def to_grouped_dict(self) -> dict[str, dict[str, Any]]:
        """``{group: {key: value}}`` (for printing); round-trips through :func:`load_config` too."""
        flat = self.to_flat_dict()
        out: dict[str, dict[str, Any]] = {g: {} for g in GROUPS}
        for name, group in FLAT_KEYS.items():
            out[group][name] = flat[name]
        out["frontend"] = flat["frontend"]
        return out


def _read(source: str | Path | Mapping[str, Any]) -> tuple[dict[str, Any], str]:
    """The mapping of a YAML file or a mapping, and where it came from (the file, or "config mapping")."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        where = str(path)
        try:
            values = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise MsckfInputError(f"{where}: cannot read msckf config ({exc.strerror or exc})") from None
        except yaml.YAMLError as exc:
            raise MsckfInputError(f"{where}: not valid YAML ({exc})") from None
        if values is None:
            values = {}
    else:
        where = "config mapping"
        values = source
    if not isinstance(values, Mapping):
        raise MsckfInputError(f"{where}: msckf config must be a mapping of parameter names to values, "
                              f"got {type(values).__name__}")
    return dict(values), where


def load_config(source: str | Path | Mapping[str, Any] | MsckfConfig | None = None) -> MsckfConfig:
    """Build an :class:`MsckfConfig` from defaults overridden by a YAML file or a mapping.

    Args:
        source: ``None`` (defaults), a path to a YAML file holding a mapping, a mapping, or a config (returned
            as is). Keys are flat parameter names (:data:`FLAT_KEYS`) or group names (:data:`GROUPS`) holding a
            mapping of that group's parameters (or a ready group object). A ``frontend`` key holds a mapping of
            :class:`FrontendConfig` overrides (or a :class:`FrontendConfig`).
    Raises:
        MsckfInputError: unreadable file, not a mapping, unknown key, a key given twice (flat and nested) or a bad
            value; the message names the file (or "config mapping") and the key.
    """
    if source is None:
        return MsckfConfig()
    if isinstance(source, MsckfConfig):
        return source
    values, where = _read(source)
    overrides: dict[str, dict[str, Any]] = {g: {} for g in GROUPS if g != "frontend"}
    ready: dict[str, Any] = {}
    unknown: list[str] = []

    def put(group: str, name: str, value: Any) -> None:
        if name in overrides[group]:
            raise MsckfInputError(f"{where}: msckf parameter {name} given twice (flat and as {group}.{name})")
        overrides[group][name] = value

    for key, value in values.items():
        if key in FLAT_KEYS:
            put(FLAT_KEYS[key], key, value)
        elif key in overrides:
            if isinstance(value, GROUPS[key]):
                ready[key] = value
            elif isinstance(value, Mapping):
                for name, v in value.items():
                    if FLAT_KEYS.get(name) == key:
                        put(key, name, v)
                    else:
                        unknown.append(f"{key}.{name}")
            else:
                raise MsckfInputError(f"{where}: '{key}' must be a mapping, got {type(value).__name__}")
        elif key != "frontend":
            unknown.append(str(key))
    if unknown:
        known = sorted([*FLAT_KEYS, *GROUPS])
        raise MsckfInputError(f"{where}: unknown msckf parameter(s) {', '.join(sorted(unknown))}; "
                              f"known: {', '.join(known)}")
    fe = values.get("frontend")
    if isinstance(fe, FrontendConfig):
        frontend = fe
    else:
        if fe is not None and not isinstance(fe, Mapping):
            raise MsckfInputError(f"{where}: 'frontend' must be a mapping, got {type(fe).__name__}")
        frontend = FrontendConfig.from_mapping(fe, source=where)
    groups: dict[str, Any] = {}
    try:
        for group, vals in overrides.items():
            if group in ready:
                groups[group] = dataclasses.replace(ready[group], **vals) if vals else ready[group]
            else:
                groups[group] = GROUPS[group](**vals)
        return MsckfConfig(frontend=frontend, **groups)
    except MsckfInputError as exc:
        raise MsckfInputError(f"{where}: {exc}") from None
