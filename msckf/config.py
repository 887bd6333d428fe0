"""The one typed configuration of the MSCKF VIO (filter + front end), with the Rosario defaults.

Defaults are CIFASIS' ``launch/msckf_vio_rosario.launch`` values (references/rosario.md §7, msckf.md §1.14)
and the constants msckf_vio hard-codes; choices of this port that differ from S-MSCKF are marked
"[port]" and explained in the field docs. Override from YAML/dicts with :func:`load_config`.

Units: noise values are continuous-time standard deviations (noise densities) exactly as S-MSCKF's launch
files give them (the code squares them): gyro rad/s/√Hz, acc m/s²/√Hz, gyro bias rad/s²/√Hz, acc bias
m/s³/√Hz. ``feature_noise`` is a standard deviation in *normalised* image coordinates (≈ pixels / fx).
Initial covariances are variances.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from msckf.errors import MsckfInputError
from msckf.frontend_config import FrontendConfig

__all__ = ["MsckfConfig", "load_config"]


@dataclass(frozen=True)
class MsckfConfig:
    """Every parameter of the VIO.

    Window and pruning (S-MSCKF, Rosario launch):
        max_cam_state_size: clones kept in the sliding window (prune 2 when reached). >= 4.
        rotation_threshold: rad; a recent clone closer than this in angle (and ``translation_threshold`` in
            distance, with tracking rate above ``tracking_rate_threshold``) to the 4th-newest is redundant.
        translation_threshold: metres (pruning).
        tracking_rate_threshold: fraction of the map tracked in the newest frame (pruning).
        feature_translation_threshold: metres; a lost feature is triangulated only if the camera moved more than
            this orthogonally to its first bearing (S-MSCKF ``checkMotion``); −1 (Rosario) disables it.
        mono_translation_threshold: [port] the same check, applied to features that have no right-camera
            observation at all (monocular tracks have no stereo baseline to fall back on), metres.
        position_std_threshold: metres; online reset when any position σ exceeds it (≤ 0 disables).

    IMU noise (σ, continuous time) and initial state / covariance (variances):
        gyro_noise, acc_noise, gyro_bias_noise, acc_bias_noise, initial_velocity (m/s, world),
        velocity_cov, gyro_bias_cov, acc_bias_cov, extrinsic_rotation_cov (rad²), extrinsic_translation_cov (m²).

    Visual measurement:
        feature_noise: [port] σ of a normalised image coordinate. Default 0.007 ≈ 2.5 px at the Rosario
            rectified fx of 351 px, paired with the 95 % gate below. The Rosario launch value 0.035 (≈ 12 px)
            only makes sense paired with S-MSCKF's 5 % gate (msckf.md §0.3: carry the pair over or re-tune
            both; this port re-tunes both). On the simulated feature world (benchmarks/bench_msckf.py) an
            under-stated σ costs far more than an over-stated one (the gate then rejects good features).
        chi2_quantile, chi2_dof: [port] χ² gate. Each feature is accepted when
            ``rᵀ(HPHᵀ + σ²I)⁻¹r < chi2.ppf(chi2_quantile, dof)``. Default: the 95 % quantile with
            ``dof = residual rows after null-space projection`` (a true 5 % false-rejection test).
            S-MSCKF uses the 5 % quantile with dof = #observations − 1 (issue #124: with an honest σ it rejects
            nearly every update — measured: all of them on the simulated world — hence its inflated σ);
            ``chi2_quantile=0.05, chi2_dof="observations", feature_noise=0.035`` reproduces that pairing.
        robust_k: Huber-style weight of a gated-in feature: when its χ² per degree of freedom γ/dof exceeds
            ``robust_k``, its σ is scaled by ``sqrt(γ / (dof · robust_k))`` (its whole residual — pixel and
            depth rows — counts with that weight). 0 (default) disables it.
        track_drift_psd: q of the tracking-drift model (normalised²/s; ``msckf.update.whiten_track_drift``): the
            pixel errors of one track are correlated as ``σ² δ_ij + q·min(t_i, t_j)`` from its first observation
            in the window. 0 (default) keeps them independent.
        max_update_rows: [port] S-MSCKF stops stacking lost-feature Jacobians after 1500 rows (and drops the
            rest) to bound its run time; this port's update cost does not grow with rows, so the default is
            0 = no cap. A positive value restores the S-MSCKF behaviour.
        update_method: ``"qr"`` (default; literal S-MSCKF: QR of each feature's H_f for its left null space,
            stacked QR compression, Joseph-form EKF update) or ``"schur"`` (1.3–1.7× faster: the feature is
            marginalised by a Schur complement, algebraically the same, with the symmetric covariance update).
            Measured on the simulated Rosario-like sequences: with depth-map observations the symmetric update
            lost positive definiteness within 5–9 s on 14 of 20 depth runs ("negative variance"), the Joseph
            form on none; hence ``qr`` by default.
        observability_constrained: OC-EKF modifications of Φ and H (S-MSCKF); False = standard EKF.
        propagate_to_image_time: [port] after the last IMU sample at or before the image, propagate the rest
            of the way to the image stamp holding that sample (S-MSCKF stops at the sample, up to one IMU
            period — 7 ms at Rosario's 142 Hz — early).

    Depth (variants ``depth-*``; msckf.md §5):
        depth_seed: seed the triangulation with the measured depth when the anchor observation has one.
        depth_row: [port, default True] a depth-map observation enters as an inverse-depth residual row with its
            own σ (rows u0, v0, 1/d) instead of a virtual cam1 pixel derived from the cam0 pixel and the depth
            (that pixel's error is fully correlated with cam0's and was treated as independent, σ = 1 px, with no
            knowledge of the depth's own σ). Measured (benchmarks/bench_depth_oracle.py, 10 s presets 02/03,
            3 seeds): depth-raw 0.0180 / 0.0463 m → 0.0189 / 0.0321 m, Telea-inpainted 0.0361 / 0.0359 m →
            0.0194 / 0.0331 m, exact tracked-point depth 0.0121 / 0.0144 m → 0.0099 / 0.0122 m (stereo front end
            0.0106 / 0.0229 m); NEES of depth runs 3.6 → 2.7 (bench_msckf.py --quick). False restores the
            virtual-stereo model.
        depth_inv_sigma: 1/m, σ of the inverse depth from disparity noise (σ_disp_px / (fx · baseline)).
        depth_rel_sigma: relative depth error σ_z / z (e.g. inpainting error); the row's σ is
            ``sqrt(depth_inv_sigma² + (depth_rel_sigma / z)²)`` in 1/m — depth dependent. An observation that
            states its own σ_Z (``FeatureObservations.depth_sigma_m``: the pipeline's per-pixel depth σ) uses
            ``σ_Z / Z²`` instead.
        depth_gate_sigma: a depth row whose residual at the triangulated feature exceeds this many σ is dropped
            (that observation counts as monocular); the χ² gate of the whole feature still follows. 0 disables.
        depth_motion_rel_sigma: with ``depth_row``, a depth-map observation exempts its track from the monocular
            motion check (``mono_translation_threshold``) only if its σ_Z / Z is at most this; with ``depth_row``
            the triangulation also weights each depth by its σ instead of using the virtual cam1 pixel.

    Triangulation (S-MSCKF hard-coded values):
        huber_epsilon (normalised units), estimation_precision, initial_damping, outer_loop_max_iteration,
        inner_loop_max_iteration.

    Initialisation and health:
        init_imu_samples: IMU samples averaged for the static initialisation (S-MSCKF: 200).
        init_max_gyro_std: rad/s, per-axis standard deviation above which the start is not static.
        init_max_gyro_mean: rad/s, |mean gyro| above which the start is rotating (bias must be smaller).
        init_max_acc_std: m/s², per-axis standard deviation above which the start is not static.
        init_max_acc_drift: m/s², change of the mean accelerometer vector between the first and last quarter
            of the window above which the start is accelerating or tilting.
        init_max_gyro_drift: rad/s, the same for the mean angular rate (turning during part of the window).
        max_speed: m/s; a faster velocity estimate is declared divergence (field robot).
        frame_rate: Hz, expected image rate (only for the budget warning in the stats).

    Front end:
        frontend: :class:`~msckf.frontend_config.FrontendConfig`.
    """

    max_cam_state_size: int = 20
    rotation_threshold: float = 0.2618
    translation_threshold: float = 0.4
    tracking_rate_threshold: float = 0.5
    feature_translation_threshold: float = -1.0
    mono_translation_threshold: float = 0.1
    position_std_threshold: float = 8.0

    gyro_noise: float = 0.005
    acc_noise: float = 0.05
    gyro_bias_noise: float = 0.001
    acc_bias_noise: float = 0.01
    initial_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity_cov: float = 0.25
    gyro_bias_cov: float = 0.01
    acc_bias_cov: float = 0.01
    extrinsic_rotation_cov: float = 3.0462e-4
    extrinsic_translation_cov: float = 2.5e-5

    feature_noise: float = 0.007
    chi2_quantile: float = 0.95
    chi2_dof: str = "residual"
    robust_k: float = 0.0
    track_drift_psd: float = 0.0
    max_update_rows: int = 0
    update_method: str = "qr"
    observability_constrained: bool = True
    propagate_to_image_time: bool = True

    depth_seed: bool = True
    depth_row: bool = True
    depth_inv_sigma: float = 0.01
    depth_rel_sigma: float = 0.05
    depth_gate_sigma: float = 0.0
    depth_motion_rel_sigma: float = 0.05

    huber_epsilon: float = 0.01
    estimation_precision: float = 5e-7
    initial_damping: float = 1e-3
    outer_loop_max_iteration: int = 10
    inner_loop_max_iteration: int = 10

    init_imu_samples: int = 200
    init_max_gyro_std: float = 0.1
    init_max_gyro_mean: float = 0.1
    init_max_acc_std: float = 0.5
    init_max_acc_drift: float = 0.3
    init_max_gyro_drift: float = 0.05
    max_speed: float = 20.0
    frame_rate: float = 15.0

    frontend: FrontendConfig = field(default_factory=FrontendConfig)

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> MsckfInputError:
            return MsckfInputError(f"msckf config: {name}={getattr(self, name)!r} {why}")

        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type == "float":
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise bad(f.name, "must be a finite number")
                object.__setattr__(self, f.name, float(value))
            elif f.type == "int":
                if isinstance(value, bool) or not isinstance(value, int):
                    raise bad(f.name, "must be an integer")
            elif f.type == "bool":
                if not isinstance(value, bool):
                    raise bad(f.name, "must be true or false")
        v = self.initial_velocity
        try:
            v = tuple(float(x) for x in v)
        except (TypeError, ValueError):
            raise bad("initial_velocity", "must be three numbers") from None
        if len(v) != 3 or not all(math.isfinite(x) for x in v):
            raise bad("initial_velocity", "must be three finite numbers")
        object.__setattr__(self, "initial_velocity", v)
        if not isinstance(self.frontend, FrontendConfig):
            raise bad("frontend", "must be a FrontendConfig")

        if self.max_cam_state_size < 4:
            raise bad("max_cam_state_size", "must be >= 4 (pruning compares with the 4th-newest clone)")
        for name in ("gyro_noise", "acc_noise", "gyro_bias_noise", "acc_bias_noise", "feature_noise",
                     "huber_epsilon", "estimation_precision", "initial_damping", "max_speed", "frame_rate",
                     "depth_inv_sigma", "init_max_gyro_std", "init_max_gyro_mean", "init_max_acc_std",
                     "init_max_acc_drift", "init_max_gyro_drift"):
            if getattr(self, name) <= 0:
                raise bad(name, "must be > 0")
        for name in ("velocity_cov", "gyro_bias_cov", "acc_bias_cov", "extrinsic_rotation_cov",
                     "extrinsic_translation_cov", "depth_rel_sigma", "depth_gate_sigma", "depth_motion_rel_sigma",
                     "rotation_threshold",
                     "translation_threshold", "tracking_rate_threshold", "max_update_rows", "robust_k",
                     "track_drift_psd"):
            if getattr(self, name) < 0:
                raise bad(name, "must be >= 0")
        for name in ("outer_loop_max_iteration", "inner_loop_max_iteration"):
            if getattr(self, name) < 1:
                raise bad(name, "must be >= 1")
        if self.init_imu_samples < 10:
            raise bad("init_imu_samples", "must be >= 10")
        if not 0.0 < self.chi2_quantile < 1.0:
            raise bad("chi2_quantile", "must be in (0, 1)")
        if self.chi2_dof not in ("residual", "observations"):
            raise bad("chi2_dof", "must be 'residual' or 'observations'")
        if self.update_method not in ("schur", "qr"):
            raise bad("update_method", "must be 'schur' or 'qr'")

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict of every parameter (for run records); round-trips through :func:`load_config`."""
        d = dataclasses.asdict(self)
        d["initial_velocity"] = list(self.initial_velocity)
        return d


def load_config(source: str | Path | Mapping[str, Any] | MsckfConfig | None = None) -> MsckfConfig:
    """Build an :class:`MsckfConfig` from defaults overridden by a YAML file or a mapping.

    Args:
        source: ``None`` (defaults), a path to a YAML file holding a mapping, a mapping, or a config (returned
            as is). A ``frontend`` key holds a mapping of :class:`FrontendConfig` overrides.
    Raises:
        MsckfInputError: unreadable file, not a mapping, unknown key or bad value; the message names the file
            (or "config mapping") and the key.
    """
    if source is None:
        return MsckfConfig()
    if isinstance(source, MsckfConfig):
        return source
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
    values = dict(values)
    known = {f.name for f in dataclasses.fields(MsckfConfig)}
    unknown = sorted(str(k) for k in values if k not in known)
    if unknown:
        raise MsckfInputError(f"{where}: unknown msckf parameter(s) {', '.join(unknown)}; "
                              f"known: {', '.join(sorted(known))}")
    fe = values.pop("frontend", None)
    if isinstance(fe, FrontendConfig):
        frontend = fe
    else:
        if fe is not None and not isinstance(fe, Mapping):
            raise MsckfInputError(f"{where}: 'frontend' must be a mapping, got {type(fe).__name__}")
        frontend = FrontendConfig.from_mapping(fe, source=where)
    try:
        return MsckfConfig(frontend=frontend, **values)
    except MsckfInputError as exc:
        raise MsckfInputError(f"{where}: {exc}") from None
    except TypeError as exc:  # pragma: no cover - guarded by the unknown-key check
        raise MsckfInputError(f"{where}: {exc}") from None
