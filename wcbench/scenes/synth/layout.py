"""What the synthetic scenes are: image, camera and street constants, the truth weathers and v1's
materials, the profiles of the two generations of scenes (what a scene set has: its lidar, its sun,
its masks) and the scenes of the ``synth_1`` / ``synth_3`` and ``synth_hard_1`` sets
(docs/design.md §3)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["HARD", "HARD_SCENES", "MATERIALS_V1", "SCENES", "TRUTH_WEATHERS", "V1", "VERSION", "LidarSpec", "Profile",
           "Sun", "SynthSpec", "scene_folder"]


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

#: How each weather changes the materials of the v1 scenes (``synth_1``, ``synth_3``) before rendering
#: (docs/design.md §3). Frozen: those scenes must regenerate byte for byte under their cache folder
#: (``synth-v1``), so these numbers stay v1's even where the shared appearance tables
#: (reference_model/weather/presets.toml, ``[appearance.*]``) now say otherwise (snow from normal-up
#: 0.5 to 0.87 there, albedo 0.85 in linear light); later sets read those tables
#: (:mod:`.materials`). The factors act on sRGB values, not linear light. ``light`` scales the
#: albedo (overcast days are dimmer than the clear sun); under rain a wet surface keeps ``wet`` of
#: its albedo (a water film darkens asphalt to about half) and adds a Fresnel reflection of the sky
#: (Schlick's approximation, ``fresnel_f0`` of water) weighted by the Gaussian's sheen; under snow a
#: Gaussian whose normal (its smallest-scale axis) points up is covered by snow of ``snow_albedo``.
MATERIALS_V1: dict[str, dict[str, Any]] = {
    "clear": {"ambient": 0.55, "sun": 0.5, "sun_direction": [-0.35, -0.45, 0.82]},
    "rain": {"light": 0.68, "sky_light": 0.15, "fresnel_f0": 0.02, "asphalt_wet": 0.55, "puddle_wet": 0.3,
             "asphalt_sheen": 0.3, "puddle_sheen": 1.0, "overcast_sky": [0.60, 0.62, 0.66]},
    "snow": {"light": 0.82, "sky_light": 0.15, "snow_albedo": [0.93, 0.94, 0.97], "normal_up_from": 0.55,
             "normal_up_full": 0.9, "wet": 0.85, "overcast_sky": [0.80, 0.81, 0.85]},
    "fog": {"light": 0.78, "sky_light": 0.15, "wet": 0.95, "overcast_sky": [0.78, 0.78, 0.81]},
}


@dataclass(frozen=True)
class LidarSpec:
    """A spinning lidar on the vehicle's roof: a grid of rays, ``beams`` elevations by ``columns``
    azimuths, cast once per frame (docs/design.md §3).

    Attributes
    ----------
    mount_m : tuple of 3 float
        Sensor position in the vehicle frame (m; x forward, y left, z up from the ground).
    beams : int
        Elevation rows, evenly spaced over ``elevation_deg``.
    elevation_deg : tuple of 2 float
        Lowest and highest beam elevation (degrees above the vehicle's horizontal).
    columns : int
        Azimuth columns, evenly spaced over +-``azimuth_deg``.
    azimuth_deg : float
        Half the horizontal span about the vehicle's x axis (degrees).
    range_m : float
        Farthest return (m).
    range_noise_m : float
        Standard deviation of the range noise (m; 0: exact ranges), seeded by the scene and frame.
    """

    mount_m: tuple[float, float, float]
    beams: int
    elevation_deg: tuple[float, float]
    columns: int
    azimuth_deg: float
    range_m: float
    range_noise_m: float = 0.0

    def elevations(self) -> np.ndarray:
        """[B] beam elevations (rad), increasing."""
        return np.radians(np.linspace(*self.elevation_deg, self.beams))

    def azimuths(self) -> np.ndarray:
        """[C] column azimuths (rad, counter-clockwise from the vehicle's x axis), increasing."""
        return np.radians(np.linspace(-self.azimuth_deg, self.azimuth_deg, self.columns))


@dataclass(frozen=True)
class Sun:
    """The clear sky of a scene with cast shadows: a sun and a sky, as irradiance in linear light.

    A surface of normal n whose sun ray is unblocked receives ``sun_rgb`` max(n.s, 0) from the sun
    (s the unit vector toward it), ``sky_rgb`` (1 + n_z) / 2 from the sky (a sky of uniform
    radiance: the fraction of it a tilted plane sees) and ``ground_albedo`` times the ground's
    irradiance, (1 - n_z) / 2 of it, reflected from below (docs/design.md §3).

    Attributes
    ----------
    elevation_deg : float
        Sun elevation above the horizon (degrees).
    azimuth_deg : float
        Direction toward the sun, counter-clockwise from the street's direction at its start (the
        camera's heading; degrees): 90 is to the left.
    sun_rgb : tuple of 3 float
        Direct-normal irradiance of the sun (linear RGB, in units where 1 exposes a white
        horizontal surface at 1).
    sky_rgb : tuple of 3 float
        Diffuse irradiance of the sky on a horizontal surface (linear RGB, same units).
    ground_albedo : float
        Mean albedo of the street's ground for the light it reflects up.
    lit_ground_fraction : float
        Share of the ground in sun, for the reflected light.
    angular_radius_deg : float
        The sun disk's radius: shadow edges get its penumbra.
    """

    elevation_deg: float
    azimuth_deg: float
    sun_rgb: tuple[float, float, float]
    sky_rgb: tuple[float, float, float]
    ground_albedo: float
    lit_ground_fraction: float
    angular_radius_deg: float = 0.267

    def direction(self) -> np.ndarray:
        """[3] unit vector toward the sun in street coordinates (z up)."""
        el, az = np.radians(self.elevation_deg), np.radians(self.azimuth_deg)
        return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


@dataclass(frozen=True)
class Profile:
    """What the scenes of a generation have: one profile per cache folder (docs/design.md §3).

    Attributes
    ----------
    name : str
        Scene folder prefix (``synth``: folders ``synth_000`` ...).
    cache : str
        Cache folder under ``<cache>/scenes/`` (``synth-v1``); keyed by the version.
    version : int
        Bumped when what the profile generates changes.
    lidar : LidarSpec
    building_height_m : tuple of 2 (float, float)
        Range of block heights (m) on the right and on the left side of the street.
    sun : Sun or None
        The clear frames' sun and sky with cast shadows; ``None``: v1's shadowless sunlight
        (:data:`MATERIALS_V1` ``clear``) and v1's materials under every weather.
    sky_masks : bool
        Ship ``sky_masks/`` (real scenes ship none: methods then derive the sky).
    truth_masks : bool
        Write ``truth/masks/{sky,shadow,movers}/`` for scoring.
    road_patches : int
        Dark patches (tar repairs, oil stains) on the road: lit, yet as dark as a shadow.
    white_facade_s : float or None
        Arc length (m) where the block on the right is painted white.
    mirror_windows : bool
        Window glass mirrors the sky (a Fresnel term).
    traced_mirrors : bool
        Under rain the wet ground mirrors what its reflected view ray meets in the street (the cars,
        trunks, canopies and facades; :mod:`.mirrors`), the sky only where it meets nothing;
        otherwise it mirrors the sky through them.
    """

    name: str
    cache: str
    version: int
    lidar: LidarSpec
    building_height_m: tuple[tuple[float, float], tuple[float, float]]
    sun: Sun | None = None
    sky_masks: bool = True
    truth_masks: bool = False
    road_patches: int = 0
    white_facade_s: float | None = None
    mirror_windows: bool = False
    traced_mirrors: bool = False


#: The v1 scenes (``synth_1``, ``synth_3``): a 32-beam roof lidar over the front half (the camera sees
#: 77 degrees of it) that reaches the tops of the 7-22 m blocks, sky masks shipped, no cast shadows.
V1 = Profile(
    name="synth", cache=f"synth-v{VERSION}", version=VERSION,
    lidar=LidarSpec(mount_m=(1.4, 0.0, 2.1), beams=32, elevation_deg=(-24.0, 3.0), columns=480, azimuth_deg=80.0,
                    range_m=75.0),  # Waymo's top lidar range
    building_height_m=((7.0, 22.0), (7.0, 22.0)),
)

#: The harder scenes (``synth_hard_1``; docs/design.md §3): a late-afternoon sun behind the camera on
#: the left (28 degrees up, 155 degrees left of the heading; direct-normal / diffuse-horizontal 4 in
#: green, a warm sun and a bluish sky) casting shadows forward and to the right; a PandaSet-like
#: 64-beam lidar (Hesai Pandar64: -25 to +15 degrees, 0.2 degree columns, 1.9 m up, ~2 cm range
#: noise) under blocks of 8-30 m whose upper floors it does not reach; no sky masks; truth masks for
#: scoring; dark road patches, a white facade and mirroring windows. The blocks on the sun's side
#: (left) are 8-14 m: their shadows reach 0.8 of their height across the street, 6.6-11.5 m from
#: the facades, so they cover the left sidewalk and lane and, behind the taller ones, part of the
#: camera's lane, not the whole street. Under rain its wet ground mirrors the street it faces, traced
#: (version 2; version 1 mirrored the sky through every car and tree, docs/findings.md).
HARD = Profile(
    name="synth_hard", cache="synth-hard-v2", version=2,
    lidar=LidarSpec(mount_m=(1.2, 0.0, 1.9), beams=64, elevation_deg=(-25.0, 15.0), columns=500, azimuth_deg=50.0,
                    range_m=120.0, range_noise_m=0.02),
    building_height_m=((12.0, 30.0), (8.0, 14.0)),
    sun=Sun(elevation_deg=28.0, azimuth_deg=155.0, sun_rgb=(1.50, 1.36, 1.16), sky_rgb=(0.28, 0.34, 0.44),
            ground_albedo=0.15, lit_ground_fraction=0.5),
    sky_masks=False, truth_masks=True, road_patches=6, white_facade_s=42.0, mirror_windows=True,
    traced_mirrors=True,
)


@dataclass(frozen=True)
class SynthSpec:
    """What one synthetic scene contains.

    Attributes
    ----------
    index : int
        Scene number k; the folder is ``{profile.name}_{k:03d}`` (``synth_000``).
    seed : int
        Seeds the layout (buildings, trees, parked cars, colours) and the weather particles.
    curvature : float
        Street curvature (1/m): 0 straight, positive bending left.
    pedestrian : {"right", "left"} or None
        Sidewalk a pedestrian walks on (``"right"``: along the driving direction, ``"left"``:
        towards the camera), or no pedestrian.
    movers : tuple of str
        Tracked moving cars (an instance box each): ``"oncoming"`` (left lane, towards the camera)
        and/or ``"lead"`` (ahead in the camera's lane, slower).
    untracked : tuple of str
        Moving cars of the same kinds with no instance box and no dynamic mask.
    walkers : tuple of str
        Pedestrians with no instance box: ``"right"``, ``"left"`` (on that sidewalk, as
        ``pedestrian``; the one on the right stays in view all along) and ``"crossing"`` (crossing
        the road far ahead, from the left sidewalk towards the right).
    profile : Profile
        What the scene's generation has (its lidar, sun, masks, materials).
    """

    index: int
    seed: int
    curvature: float
    pedestrian: str | None
    movers: tuple[str, ...]
    untracked: tuple[str, ...] = ()
    walkers: tuple[str, ...] = ()
    profile: Profile = V1

    @property
    def folder(self) -> str:
        """Folder name, also the scene id (``synth_000``, ``synth_hard_000``)."""
        return f"{self.profile.name}_{self.index:03d}"


#: The scenes of the synth sets: ``synth_1`` is scene 0, ``synth_3`` scenes 0-2.
SCENES: tuple[SynthSpec, ...] = (
    SynthSpec(index=0, seed=1000, curvature=0.0, pedestrian=None, movers=("oncoming",)),
    SynthSpec(index=1, seed=1001, curvature=1.0 / 300.0, pedestrian="right", movers=("oncoming", "lead")),
    SynthSpec(index=2, seed=1002, curvature=-1.0 / 400.0, pedestrian="left", movers=("lead", "oncoming")),
)


#: The scenes of ``synth_hard_1``: one straight street with a tracked oncoming car, an untracked
#: lead car and two untracked pedestrians.
HARD_SCENES: tuple[SynthSpec, ...] = (
    SynthSpec(index=0, seed=2000, curvature=0.0, pedestrian=None, movers=("oncoming",), untracked=("lead",),
              walkers=("right", "crossing"), profile=HARD),
)


def scene_folder(index: int) -> str:
    """Folder name of v1 synthetic scene ``index`` (``"synth_000"``), also its scene id."""
    return SCENES[index].folder
