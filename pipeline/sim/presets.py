"""Named simulator presets that differ the way the Rosario v1 sequences do (rosario.md §4.3: camera pitch 19°,
12° and 7° for sequences 01, 02 and 03), plus speed, lighting, roughness, crop height and route.

Each Rosario-like preset has the real sequences' length by default (≈ 445 s: the regenerated Rosario bag of
sequence 01 is cut to 445.1 s; 02 and 03 have no published length, 450 s here) and drives what the real robot
does over that time: along the rows, headland U-turns onto the next rows (or a loop), stops and restarts, and a
different cruise speed on successive passes. The demo and the tests take short clips of them (``--duration``);
a clip's first pass is not affected by the later speed changes and stops.

* ``rosario-like-01``: camera pitched 19° down; sunny, high sun; 0.85 m/s along 60 m rows (passes at ×1.0 / 0.8 /
  1.1 / 0.9), starting mid-field, a headland U-turn after ≈50 s and every ≈75 s after it, a 4 s stop every 120 s
  of driving; 445 s.
* ``rosario-like-02``: 12°; broken clouds drifting over the sun (exposure changes), a rougher field, slower
  (0.6 m/s; legs at ×1.0 / 1.2 / 0.8), a loop that crosses the rows and stops for 3 s every 25 s; 450 s.
* ``rosario-like-03``: 7°; low sun ahead of the robot on every other pass (glare and flare), the roughest ground,
  the tallest plants, fastest (1.1 m/s; passes at ×1.0 / 0.8 / 0.9 / 1.15; a headland U-turn after ≈50 s), a 5 s
  stop every 150 s of driving; 450 s.
* ``tiny``: ``rosario-like-01`` for 3 s (2.2 s standing still) — for tests. Full 672×376 images.
"""

from __future__ import annotations

import dataclasses

from pipeline.sim.config import CameraConfig, FieldConfig, LightingConfig, RouteConfig, SimConfig


def _preset_01() -> SimConfig:
    return SimConfig(
        name="rosario-like-01", duration_s=445.0, start_stamp_ns=1_512_130_000_000_000_000,
        field=FieldConfig(plant_height_m=0.28, roughness_m=0.02, straw_cover=0.25, soil_moisture=0.35,
                          azimuth_deg=12.0, row_length_m=60.0),
        route=RouteConfig(kind="rows", start_row=24, start_y_m=20.0, speed_mps=0.85, still_s=3.0,
                          stop_every_s=120.0, stop_s=4.0, speed_changes=(1.0, 0.8, 1.1, 0.9)),
        camera=CameraConfig(tilt_deg=19.0),
        lighting=LightingConfig(sun_elevation_deg=52.0, sun_azimuth_deg=330.0, cloud_cover=0.2, sun_irradiance=3.2),
    )


def _preset_02() -> SimConfig:
    return SimConfig(
        name="rosario-like-02", duration_s=450.0, start_stamp_ns=1_512_736_400_000_000_000,
        field=FieldConfig(plant_height_m=0.27, roughness_m=0.03, straw_cover=0.4, soil_moisture=0.55,
                          azimuth_deg=12.0, weeds_per_m2=1.0),
        route=RouteConfig(kind="loop", start_row=40, speed_mps=0.6, turn_speed_mps=0.4, still_s=3.0, leg_m=12.0,
                          stop_every_s=25.0, stop_s=3.0, speed_changes=(1.0, 1.2, 0.8)),
        camera=CameraConfig(tilt_deg=12.0),
        lighting=LightingConfig(sun_elevation_deg=38.0, sun_azimuth_deg=300.0, cloud_cover=0.55,
                                cloud_speed_mps=9.0, sun_irradiance=3.0),
    )


def _preset_03() -> SimConfig:
    return SimConfig(
        name="rosario-like-03", duration_s=450.0, start_stamp_ns=1_513_340_200_000_000_000,
        field=FieldConfig(plant_height_m=0.34, roughness_m=0.04, straw_cover=0.3, soil_moisture=0.25,
                          azimuth_deg=12.0, row_length_m=60.0),
        route=RouteConfig(kind="rows", start_row=60, start_y_m=8.0, speed_mps=1.1, turn_speed_mps=0.5,
                          still_s=3.0, stop_every_s=150.0, stop_s=5.0, speed_changes=(1.0, 0.8, 0.9, 1.15)),
        camera=CameraConfig(tilt_deg=7.0),
        lighting=LightingConfig(sun_elevation_deg=21.0, sun_azimuth_deg=18.0, cloud_cover=0.15,
                                sun_irradiance=3.6, glare=1.3),
    )


def _preset_tiny() -> SimConfig:
    base = _preset_01()
    return dataclasses.replace(base, name="tiny", duration_s=3.0,
                               route=dataclasses.replace(base.route, still_s=2.2, accel_mps2=0.5))


PRESETS = {"rosario-like-01": _preset_01, "rosario-like-02": _preset_02, "rosario-like-03": _preset_03,
           "tiny": _preset_tiny}


def preset_names() -> list[str]:
    return list(PRESETS)


def get_preset(name: str) -> SimConfig:
    """The named preset's config (a fresh object). Raises ``KeyError`` listing the known names."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise KeyError(f"unknown simulator preset {name!r}; known: {', '.join(PRESETS)}") from None
