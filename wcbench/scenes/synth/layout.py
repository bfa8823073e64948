"""What the synthetic scenes are: image, camera, lidar and street constants, the truth weathers
and their materials, and the scenes of the ``synth_1`` / ``synth_3`` sets (docs/design.md §3)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MATERIALS", "SCENES", "TRUTH_WEATHERS", "VERSION", "SynthSpec", "scene_folder"]


VERSION = 1  # bump when the generated content changes: the cache folder is keyed by it
WIDTH, HEIGHT, FOCAL = 480, 270, 300.0  # pixels; horizontal field of view 77 degrees
N_FRAMES, FPS, SPEED = 30, 10.0, 8.0  # frames, Hz, m/s
MARKER = "synth.json"  # written last: a scene folder holding it is complete
#: Where the street's origin sits in the "global" frame written to disk: far from 0, so the
#: loaders' re-basing (docs/design.md §2) is exercised as on real data.
GLOBAL_ORIGIN = np.array([1520.0, -830.0, 12.0])
#: Camera 0 (FRONT) on the vehicle: position (m, vehicle frame x forward, y left, z up; origin on the
#: ground under the rear axle as in Waymo) and a small downward pitch.
CAMERA_MOUNT_M = (1.5, 0.0, 1.65)
CAMERA_PITCH_DEG = 2.0
#: A spinning roof lidar: 32 beams over the front half (the camera sees 77 degrees of it).
LIDAR_MOUNT_M = (1.4, 0.0, 2.1)
LIDAR_BEAMS, LIDAR_COLUMNS = 32, 480
LIDAR_ELEVATION_DEG = (-24.0, 3.0)
LIDAR_AZIMUTH_DEG = 80.0  # +- about the vehicle's x axis
LIDAR_RANGE_M = 75.0  # Waymo's top lidar range
#: Street cross-section (m): two lanes, a parking lane each side, raised sidewalks, facades.
LANE_M, PARKING_M, SIDEWALK_M, CURB_M = 3.5, 2.2, 3.5, 0.15
ROAD_HALF_M = LANE_M + PARKING_M
BUILDING_LINE_M = ROAD_HALF_M + SIDEWALK_M
STREET_START_M, STREET_END_M = -2.0, 185.0  # arc length of the ground; a building closes the street
EGO_LATERAL_M = -LANE_M / 2  # right-hand traffic: the camera car drives in the right lane
SIGMA_OF_SPACING = 0.7  # in-plane standard deviation of a surface Gaussian / its grid spacing
THIN_M = 0.01  # thickness (smallest scale) of a surface Gaussian: its normal axis
OPACITY = 0.98
SURFACE_SPACING_PER_M = 0.012  # grid spacing (m) per metre of distance: ~3.6 px at f = 300 px
#: A street is seen at grazing angles: its ground (camera 1.65 m above it) and facades (~11 m to the
#: side) are foreshortened along the street, so their Gaussians are spaced that much wider along it.
GROUND_STRETCH, FACADE_STRETCH = 3.0, 2.0

#: The weathers rendered as truth: :class:`~wcbench.reference_model.weather.conditions.Weather`
#: fields (presets in reference_model/weather/presets.toml; the scene's seed is added). Heavy rain
#: (25 mm/h) and heavy snow (2.5 mm/h), fog of 150 m visibility. Heavy snow has ~29,000 flakes in
#: the particle box: drawn one by one (instead of the preset's 16,000 of higher opacity) it reads as
#: heavy at 480x270.
TRUTH_WEATHERS: dict[str, dict[str, Any]] = {
    "rain": {"preset": "heavy"},
    "snow": {"preset": "heavy", "max_particles": 30000},
    "fog": {"preset": "moderate"},
}

#: How each weather changes the materials before rendering (docs/design.md §3). ``light`` scales the
#: albedo (overcast days are dimmer than the clear sun); under rain a wet surface keeps ``wet`` of
#: its albedo (a water film darkens asphalt to about half) and adds a Fresnel reflection of the sky
#: (Schlick's approximation, ``fresnel_f0`` of water) weighted by the Gaussian's sheen; under snow a
#: Gaussian whose normal (its smallest-scale axis) points up is covered by snow of ``snow_albedo``.
MATERIALS: dict[str, dict[str, Any]] = {
    "clear": {"ambient": 0.55, "sun": 0.5, "sun_direction": [-0.35, -0.45, 0.82]},
    "rain": {"light": 0.68, "sky_light": 0.15, "fresnel_f0": 0.02, "asphalt_wet": 0.55, "puddle_wet": 0.3,
             "asphalt_sheen": 0.3, "puddle_sheen": 1.0, "overcast_sky": [0.60, 0.62, 0.66]},
    "snow": {"light": 0.82, "sky_light": 0.15, "snow_albedo": [0.93, 0.94, 0.97], "normal_up_from": 0.55,
             "normal_up_full": 0.9, "wet": 0.85, "overcast_sky": [0.80, 0.81, 0.85]},
    "fog": {"light": 0.78, "sky_light": 0.15, "wet": 0.95, "overcast_sky": [0.78, 0.78, 0.81]},
}


@dataclass(frozen=True)
class SynthSpec:
    """What one synthetic scene contains.

    Attributes
    ----------
    index : int
        Scene number k; the folder is ``synth_{k:03d}``.
    seed : int
        Seeds the layout (buildings, trees, parked cars, colours) and the weather particles.
    curvature : float
        Street curvature (1/m): 0 straight, positive bending left.
    pedestrian : {"right", "left"} or None
        Sidewalk a pedestrian walks on (``"right"``: along the driving direction, ``"left"``:
        towards the camera), or no pedestrian.
    movers : tuple of str
        Moving cars: ``"oncoming"`` (left lane, towards the camera) and/or ``"lead"`` (ahead in the
        camera's lane, slower).
    """

    index: int
    seed: int
    curvature: float
    pedestrian: str | None
    movers: tuple[str, ...]


#: The scenes of the synth sets: ``synth_1`` is scene 0, ``synth_3`` scenes 0-2.
SCENES: tuple[SynthSpec, ...] = (
    SynthSpec(index=0, seed=1000, curvature=0.0, pedestrian=None, movers=("oncoming",)),
    SynthSpec(index=1, seed=1001, curvature=1.0 / 300.0, pedestrian="right", movers=("oncoming", "lead")),
    SynthSpec(index=2, seed=1002, curvature=-1.0 / 400.0, pedestrian="left", movers=("lead", "oncoming")),
)


def scene_folder(index: int) -> str:
    """Folder name of synthetic scene ``index`` (``"synth_000"``), also its scene id."""
    return f"synth_{index:03d}"
