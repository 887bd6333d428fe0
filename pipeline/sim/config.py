"""Configuration of the Rosario-like simulator: small frozen dataclasses with documented defaults.

Frames used throughout the simulator:

* **field frame F**: x across the crop rows (row ``i`` has its centre line at ``x = i · row_spacing``), y along the
  rows (rows span ``0 <= y <= row_length``), z up, metres. Origin on the nominal ground plane at the start of row 0.
  Everything geometric (terrain, plants, the trajectory) lives here.
* **ENU frame E**: local east-north-up, used only for outputs (GPS, ground truth). ``p_E = Rz(field.azimuth) p_F``
  followed by a shift that puts the true antenna position of the first GPS fix at the origin.
* **base_link B**: x forward, y left, z up, origin on the ground between the rear wheels (a ``base_footprint``-like
  choice so that the camera head height above the ground is the IMU ``z`` lever arm).
* **IMU I**: Rosario IMU axes (x ≈ up, y ≈ right, z ≈ forward), rigidly fixed to the cameras through the Kalibr
  ``cam0/T_cam_imu``; the head's mounting rotation is chosen so that the left optical axis is pitched
  ``camera.tilt_deg`` below the base's horizontal plane.

``T_a_b`` maps frame-b points into frame a (project convention).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any

from pipeline.validate import check_unknown_keys


@dataclass(frozen=True)
class FieldConfig:
    """The soybean field.

    Attributes:
        row_spacing_m: distance between row centre lines (Rosario: 0.52 m).
        n_rows: number of rows (x from 0 to ``(n_rows - 1) · row_spacing_m``).
        row_length_m: rows span ``0 <= y <= row_length_m``; beyond are bare headlands with stubble.
        azimuth_deg: direction of the rows (field +y) measured from north towards east, degrees.
        plant_spacing_m: mean distance between plants along a row.
        plant_height_m: mean plant height (top leaf), metres.
        plant_height_rel_std: relative standard deviation of plant height.
        leaflet_length_m: mean leaflet length (soybean trifoliate leaflets), metres.
        trifoliates: (min, max) trifoliate leaves per plant (each has three leaflets).
        gap_probability: probability that a plant is missing.
        long_gap_probability: per-plant probability that a long gap (0.3-1.5 m without plants) starts.
        weeds_per_m2: density of small weeds between the rows.
        roughness_m: standard deviation of clod-scale soil relief (a few cm), metres.
        undulation_m: amplitude of the large-scale terrain undulation (tens of metres wavelength), metres.
        straw_cover: fraction of the soil covered by straw residue (no-till field), 0..1.
        soil_moisture: 0 (dry, light soil) .. 1 (moist, dark soil).
        world_seed: seed of the field geometry; ``None`` derives it from the simulation seed.
    """

    row_spacing_m: float = 0.52
    n_rows: int = 160
    row_length_m: float = 90.0
    azimuth_deg: float = 12.0
    plant_spacing_m: float = 0.07
    plant_height_m: float = 0.30
    plant_height_rel_std: float = 0.18
    leaflet_length_m: float = 0.065
    trifoliates: tuple[int, int] = (3, 6)
    gap_probability: float = 0.08
    long_gap_probability: float = 0.006
    weeds_per_m2: float = 0.6
    roughness_m: float = 0.02
    undulation_m: float = 0.08
    straw_cover: float = 0.35
    soil_moisture: float = 0.4
    world_seed: int | None = None


@dataclass(frozen=True)
class RouteConfig:
    """Where and how fast the robot drives (base_link path in the field frame).

    Attributes:
        kind: ``"rows"`` (along the rows with headland U-turns, boustrophedon) or ``"loop"`` (a rounded rectangle:
            across the rows, along them, back across, back along).
        start_row: the row the robot straddles at the start (its centre is above this row; wheels in the gaps).
        start_y_m: base_link y at the start, metres (negative: in the southern headland).
        speed_mps: cruise speed on straight legs, m/s.
        turn_speed_mps: speed in turns, m/s.
        accel_mps2: largest longitudinal acceleration, m/s².
        still_s: standing still at the start (true zero velocity), seconds (S-MSCKF needs ≥ 200 IMU samples).
        turn_rows: rows skipped by a headland U-turn (turn radius = ``turn_rows · spacing / 2``).
        leg_m: length of the across-row legs of a ``"loop"`` route, metres.
        corner_radius_m: corner radius of a ``"loop"`` route, metres.
        stop_every_s: stand still for ``stop_s`` every this many seconds of driving (``None``: never).
        stop_s: duration of each stop, seconds.
        lateral_wander_m: standard deviation of slow lateral steering wander, metres.
        yaw_wander_deg: standard deviation of slow heading wander, degrees.
        speed_changes: cruise-speed factors of the successive straight passes, cycled (pass ``k`` drives at
            ``speed_mps · speed_changes[k % len]``); empty: every pass at ``speed_mps``. The robot's operator
            changes speed between rows; the factor of the first pass should be 1.0 so that short clips of a
            preset do not depend on it.
    """

    kind: str = "rows"
    start_row: int = 20
    start_y_m: float = -2.0
    speed_mps: float = 0.8
    turn_speed_mps: float = 0.45
    accel_mps2: float = 0.25
    still_s: float = 3.0
    turn_rows: int = 10
    leg_m: float = 14.0
    corner_radius_m: float = 3.0
    stop_every_s: float | None = None
    stop_s: float = 3.0
    lateral_wander_m: float = 0.03
    yaw_wander_deg: float = 0.6
    speed_changes: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "speed_changes", tuple(float(f) for f in self.speed_changes))
        if any(not f > 0 for f in self.speed_changes):
            raise ValueError(f"route.speed_changes must be factors > 0, got {self.speed_changes}")

    def max_speed_factor(self) -> float:
        """The largest cruise-speed factor of any pass (1.0 without speed changes)."""
        return max(self.speed_changes, default=1.0)


@dataclass(frozen=True)
class MotionConfig:
    """Vibration of the robot on rough ground (part of the true trajectory, so the IMU sees it exactly).

    Amplitudes scale linearly with speed / 1 m/s and with ``field.roughness_m / 0.02``; zero when standing still.

    Attributes:
        heave_acc_rms: RMS vertical acceleration of base_link from vibration at 1 m/s, m/s².
        lateral_acc_rms: RMS horizontal acceleration from vibration at 1 m/s, m/s².
        rate_rms_deg_s: RMS roll/pitch/yaw rate from vibration at 1 m/s, deg/s (yaw gets half).
        knot_dt_s: knot spacing of the trajectory B-splines, seconds (bandwidth ≈ 1/(4·dt)).
        smooth_knots: Gaussian smoothing (in knots) of the translational vibration control points (twice that
            for the rotational ones: body modes are slower).
    """

    heave_acc_rms: float = 0.6
    lateral_acc_rms: float = 0.25
    rate_rms_deg_s: float = 1.5
    knot_dt_s: float = 0.02
    smooth_knots: float = 1.5


@dataclass(frozen=True)
class CameraConfig:
    """The camera/IMU head and image formation.

    Attributes:
        tilt_deg: pitch of the left optical axis below the base's horizontal plane, degrees (Rosario 6.4-19.2).
        imu_position_m: IMU position in base_link, metres (Rosario ``transformations.launch``: 1.96, -0.017, 1.02).
        gps_antenna_m: GPS antenna in base_link, metres (hand-measured lever arm of ``gps_aligment.py``).
        right_gain, right_offset_dn: per-camera response difference (right = left · gain + offset, DN).
        vignetting: relative brightness loss at the image corners (cos⁴-like).
        blur_sigma_px: optics blur (Gaussian σ) of the ideal image, pixels.
        read_noise_dn: sensor read noise, DN (8-bit).
        shot_noise: shot-noise scale: σ² = shot_noise · DN.
        ae_target: auto-exposure target for the mean of the tone-mapped image, 0..1.
        ae_tau_s: auto-exposure time constant, seconds (shared by both cameras, like the ZED).
        time_offset_s: camera stamps minus true exposure times (0: perfectly synchronised).
    """

    tilt_deg: float = 12.0
    imu_position_m: tuple[float, float, float] = (1.96, -0.017, 1.0)
    gps_antenna_m: tuple[float, float, float] = (1.80070337, -0.02982362, 1.59345719)
    right_gain: float = 1.045
    right_offset_dn: float = -2.0
    vignetting: float = 0.28
    blur_sigma_px: float = 0.7
    read_noise_dn: float = 1.4
    shot_noise: float = 0.06
    ae_target: float = 0.42
    ae_tau_s: float = 0.5
    time_offset_s: float = 0.0


@dataclass(frozen=True)
class LightingConfig:
    """Sun, sky, clouds and glare.

    Attributes:
        sun_elevation_deg: sun elevation, degrees.
        sun_azimuth_deg: sun azimuth from north towards east, degrees (southern hemisphere: noon sun in the north).
        sun_irradiance: direct sun irradiance relative to the sky's diffuse irradiance (clear sky ≈ 2.5-4).
        cloud_cover: fraction of the sky covered by clouds, 0..1.
        cloud_speed_mps: drift of the cloud layer (its shadows dim the sun; the sky texture moves), m/s.
        glare: strength of veiling glare / flare when the sun is near the field of view (0: none).
        leaf_gloss: strength of the specular highlights on the waxy leaves.
        haze: aerial perspective strength (distant things fade towards the horizon colour).
    """

    sun_elevation_deg: float = 40.0
    sun_azimuth_deg: float = 20.0
    sun_irradiance: float = 3.0
    cloud_cover: float = 0.3
    cloud_speed_mps: float = 6.0
    glare: float = 1.0
    leaf_gloss: float = 0.25
    haze: float = 0.6


@dataclass(frozen=True)
class ImuConfig:
    """IMU rate and noise (continuous-time densities, like Kalibr / S-MSCKF parameters).

    Defaults: the basalt ``rosario_calib.json`` set of rosario.md §4.5 (gyro 2.858e-3 rad/s/√Hz, acc
    6.367e-3 m/s²/√Hz, gyro walk 7.545e-4 rad/s²/√Hz, acc walk 2.643e-3 m/s³/√Hz): ten times the "tara" set the
    authors export with the ASL data, i.e. clearly worse than EuRoC's ADIS16448, as a low-cost MEMS board is.

    Attributes:
        rate_hz: sample rate (Rosario ≈ 142 Hz, equidistant stamps as in the regenerated bags).
        gyro_noise_density: white gyro noise, rad/s/√Hz (per-sample σ = density · √rate).
        acc_noise_density: white accelerometer noise, m/s²/√Hz.
        gyro_random_walk: gyro bias random walk, rad/s²/√Hz.
        acc_random_walk: accelerometer bias random walk, m/s³/√Hz.
        gyro_bias_std: standard deviation of the initial gyro bias, rad/s.
        acc_bias_std: standard deviation of the initial accelerometer bias, m/s².
        vibration_acc_rms: engine/structure vibration at 1 m/s (25-65 Hz, not part of the trajectory), m/s² RMS.
        vibration_gyro_rms: the same for the gyro, rad/s RMS.
        gravity_mps2: local gravity magnitude (normal gravity at Zavalla, 33° S), m/s².
    """

    rate_hz: float = 142.0
    gyro_noise_density: float = 2.8579943407611055e-3
    acc_noise_density: float = 6.367367080238862e-3
    gyro_random_walk: float = 7.544790215216806e-4
    acc_random_walk: float = 2.643259445927608e-3
    gyro_bias_std: float = 0.003
    acc_bias_std: float = 0.04
    vibration_acc_rms: float = 0.25
    vibration_gyro_rms: float = 0.01
    gravity_mps2: float = 9.7957

    def ideal(self) -> ImuConfig:
        """The same IMU without any noise, bias or vibration (for consistency checks)."""
        return dataclasses.replace(self, gyro_noise_density=0.0, acc_noise_density=0.0, gyro_random_walk=0.0,
                                   acc_random_walk=0.0, gyro_bias_std=0.0, acc_bias_std=0.0, vibration_acc_rms=0.0,
                                   vibration_gyro_rms=0.0)


@dataclass(frozen=True)
class GpsConfig:
    """GPS-RTK receiver.

    Attributes:
        rate_hz: fix and velocity rate (5 Hz, like Emlid Reach units).
        white_m: white horizontal noise σ per axis, metres.
        correlated_m: slowly varying (Gauss-Markov, ``tau_s``) horizontal error σ per axis, metres.
        vertical_factor: vertical noise = factor · horizontal.
        tau_s: correlation time of the slow error, seconds.
        vel_noise_mps: white noise on ``/gps/vel`` per axis, m/s.
        hdop: HDOP written into the fix covariance.
        origin_lat_deg, origin_lon_deg: geodetic position of the field frame origin (Zavalla, rosario.md §1).
        origin_alt_msl_m: mean-sea-level altitude of the origin, metres.
        geoid_separation_m: geoid height (ellipsoid - MSL); ``/gps/fix`` altitude is ellipsoidal like the bags.
    """

    rate_hz: float = 5.0
    white_m: float = 0.008
    correlated_m: float = 0.012
    vertical_factor: float = 2.0
    tau_s: float = 30.0
    vel_noise_mps: float = 0.02
    hdop: float = 0.8
    origin_lat_deg: float = -33.0337693
    origin_lon_deg: float = -60.8846327
    origin_alt_msl_m: float = 60.0
    geoid_separation_m: float = 14.5

    def ideal(self) -> GpsConfig:
        return dataclasses.replace(self, white_m=0.0, correlated_m=0.0, vel_noise_mps=0.0)


@dataclass(frozen=True)
class OdomConfig:
    """Wheel odometry (Ackermann, integrated like the authors' converter: Euler steps at the odometry rate).

    Attributes:
        rate_hz: odometry rate (10 Hz).
        speed_scale: systematic wheel-speed scale (wheel diameter error), 1 = exact.
        slip_std: relative speed noise from wheel slip on loose soil.
        turn_slip: extra relative speed error per rad/s of yaw rate (skidding in turns).
        yaw_rate_bias: steering-encoder bias as a yaw-rate bias, rad/s.
        yaw_rate_noise: white yaw-rate noise, rad/s.
    """

    rate_hz: float = 10.0
    speed_scale: float = 0.975
    slip_std: float = 0.04
    turn_slip: float = 0.08
    yaw_rate_bias: float = 0.006
    yaw_rate_noise: float = 0.01

    def ideal(self) -> OdomConfig:
        return dataclasses.replace(self, speed_scale=1.0, slip_std=0.0, turn_slip=0.0, yaw_rate_bias=0.0,
                                   yaw_rate_noise=0.0)


@dataclass(frozen=True)
class RenderConfig:
    """Level of detail of the renderer.

    Attributes:
        leaf_range_m: plants closer than this (horizontal distance to the camera) are drawn leaf by leaf;
            farther rows are drawn as canopy prisms (world-fixed segments of 0.25/1/4/16 m).
        shadow_range_m: leaf shadows from the shadow map within this distance; an analytic row shadow beyond.
        far_range_m: nothing but terrain, tree line and sky beyond this distance (rows end there).
        treeline_radius_m: radius of the tree line around the field centre, metres.
        margin_px: extra border of the ideal (undistorted) render around what the raw image needs.
    """

    leaf_range_m: float = 5.0
    shadow_range_m: float = 7.0
    far_range_m: float = 220.0
    treeline_radius_m: float = 260.0
    margin_px: int = 3


@dataclass(frozen=True)
class SimConfig:
    """A whole simulated sequence.

    Attributes:
        name: preset name (recorded in ``meta.json``).
        duration_s: sequence length, seconds.
        start_stamp_ns: stamp of the first IMU sample (host clock of the recording), ns.
    """

    name: str = "custom"
    duration_s: float = 60.0
    start_stamp_ns: int = 1_512_130_000_000_000_000
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    route: RouteConfig = dataclasses.field(default_factory=RouteConfig)
    motion: MotionConfig = dataclasses.field(default_factory=MotionConfig)
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    lighting: LightingConfig = dataclasses.field(default_factory=LightingConfig)
    imu: ImuConfig = dataclasses.field(default_factory=ImuConfig)
    gps: GpsConfig = dataclasses.field(default_factory=GpsConfig)
    odom: OdomConfig = dataclasses.field(default_factory=OdomConfig)
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dict of every parameter."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them."""
        kwargs: dict[str, Any] = {}
        sub_types = {f.name: f.type for f in fields(cls)}
        nested = {"field": FieldConfig, "route": RouteConfig, "motion": MotionConfig, "camera": CameraConfig,
                  "lighting": LightingConfig, "imu": ImuConfig, "gps": GpsConfig, "odom": OdomConfig,
                  "render": RenderConfig}
        check_unknown_keys(data, sub_types, "simulator config", error=ValueError)
        for key, value in data.items():
            if key in nested:
                kwargs[key] = _sub_from_dict(nested[key], value, key)
            else:
                kwargs[key] = value
        return cls(**kwargs)

    def replace(self, **changes: Any) -> SimConfig:
        """Copy with top-level fields replaced; nested ones by ``section={"key": value}`` dicts or dataclasses."""
        out: dict[str, Any] = {}
        for key, value in changes.items():
            current = getattr(self, key)
            if dataclasses.is_dataclass(current) and isinstance(value, dict):
                out[key] = dataclasses.replace(current, **value)
            else:
                out[key] = value
        return dataclasses.replace(self, **out)


def _sub_from_dict(kind: type, value: Any, name: str) -> Any:
    if dataclasses.is_dataclass(value):
        return value
    if not isinstance(value, dict):
        raise ValueError(f"simulator config section {name!r} must be a mapping")
    check_unknown_keys(value, (f.name for f in fields(kind)), f"simulator config section {name!r}", error=ValueError)
    conv = {k: (tuple(v) if isinstance(v, list) else v) for k, v in value.items()}
    return kind(**conv)
