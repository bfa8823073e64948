"""The physical weather editor: a clear frame turned into rain, snow or fog from the scene's own 3D.

:class:`WeatherEditor` edits raw frame k under a :class:`~wcbench.reference_model.weather.conditions.Weather`
(the same object the physics renderer draws: its rate, visibility and haze), per pixel, from the
scene analysis (:mod:`wcbench.reference_model.scene_analysis`: moving returns, sky, ego vehicle,
sun), the surface maps of the scene's static lidar (:mod:`.maps`) and the models of
:mod:`.shading` (docs/design.md §7, "Weather appearance"):

1. **overcast light** (every edited weather): the raw pixel over the clear sky's light on its
   normal (with the sun's where the analysis found one and the pixel is not in its cast shadow)
   stands for the albedo; the overcast sky's light is put in at the weather's exposure, so
   shadowed and sunlit pixels end under one light;
2. **rain**: a water film on the albedo of open surfaces (full on horizontal ones, damp on
   vertical ones, less in the wheel paths), puddles where the world-anchored puddle field exceeds
   the rate's threshold, and a Fresnel-weighted reflection of the scene and sky mirrored about the
   ground plane (on wet asphalt blurred into vertical streaks, sharp in puddles), in the colours the camera
   sees where the reflected ray meets the scene (never the lidar's);
3. **snow**: cover on surfaces facing up and open to the sky, its amount from the rate, the wheel
   paths mostly cleared, damp bare surfaces and a cooler white balance;
4. **haze**: Koschmieder's law with the weather's own haze (fog visibility, or the rain or snow
   extinction beyond the particles);
5. **the sky**, composited by its matte: the haze's airlight or the overcast sky, over the edited
   surfaces freed of the clear sky showing through a mixed pixel; the ego vehicle's body keeps its
   raw pixels at the weather's exposure.

No particles are drawn: a method that renders the weather draws its own. Everything is anchored in
the world (surface attributes on lidar Gaussians, noise fields over the ground plane), so the
edit does not flicker. Frames are float32 display RGB in [0, 1].
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.options import Option, Range, validate_options
from wcbench.reference_model.appearance.maps import (
    FIELDS,
    SurfaceMaps,
    glossy_blur,
    mirror_distance,
    refine,
    screen_reflection,
    surface_maps,
)
from wcbench.reference_model.appearance.shading import (
    LightModel,
    apply_haze,
    clear_irradiance,
    fresnel_schlick,
    linear_to_srgb,
    overcast_irradiance,
    smoothstep,
    snow_cover,
    srgb_to_linear,
    sunlit_irradiance,
    wet_albedo,
)
from wcbench.reference_model.appearance.surfaces import SurfaceScene, build_surfaces
from wcbench.reference_model.guided_filter import guided_filter
from wcbench.reference_model.scene_analysis.analysis import SceneAnalysis, analyse_scene
from wcbench.reference_model.weather.conditions import Weather, load_presets

__all__ = ["APPEARANCE_KEYS", "FIELDS_READ", "AppearanceParams", "WeatherEditor", "appearance_options",
           "decontaminate", "masked_ego", "over_sky", "shadow_edges"]

#: The surface attributes (:data:`~.maps.FIELDS`) each weather's edit reads: its frames' maps
#: composite only these (fog and every other kind: none; the normal and the distance always).
FIELDS_READ: dict[str, tuple[str, ...]] = {"rain": FIELDS, "snow": ("ground", "open", "track")}


#: Bounds and meaning of every key of the presets' ``[appearance]`` tables (``TABLE.KEY``; sources of
#: the values: the comments of presets.toml). The keys must be those of the presets:
#: :func:`appearance_options` refuses a key with no entry here and an entry of no key.
APPEARANCE_KEYS: dict[str, tuple[Range, str]] = {
    "light.sun_elevation_deg": (Range(0, 90), "elevation of the raw frames' sun (deg)"),
    "light.direct_to_diffuse": (Range(0), "clear sky's direct-normal over diffuse horizontal irradiance"),
    "light.ground_albedo": (Range(0, 1), "albedo of the ground"),
    "rain.exposure": (Range(0, low_open=True), "linear exposure of the overcast scene relative to the clear one"),
    "rain.wetness_horizontal": (Range(0, 1), "water film on open horizontal surfaces"),
    "rain.wetness_vertical": (Range(0, 1), "water film on open vertical surfaces"),
    "rain.fresnel_f0": (Range(0, 1), "water's Fresnel reflectance at normal incidence"),
    "rain.sheen_road": (Range(0, 1), "share of the Fresnel reflection that is a mirror on wet asphalt"),
    "rain.sheen_puddle": (Range(0, 1), "share of the Fresnel reflection that is a mirror in puddles"),
    "rain.rough_blur_px": (Range(0), "blur of the rough reflection across (px at 270 rows)"),
    "rain.puddle_max": (Range(0, 1), "largest fraction of the open ground under puddles"),
    "rain.puddle_rate_mm_h": (Range(0, low_open=True), "rain rate scale of the puddle fraction (mm/h)"),
    "rain.track_wetness": (Range(0, 1), "water film in the wheel paths, as a fraction of the rest"),
    "snow.exposure": (Range(0, low_open=True), "linear exposure of the overcast scene relative to the clear one"),
    "snow.accumulation_h": (Range(0), "hours of snowfall on the ground"),
    "snow.full_cover_mm": (Range(0, low_open=True), "liquid water (mm) that hides asphalt"),
    "snow.facing_from": (Range(-1, 1), "up-component of a normal above which snow settles"),
    "snow.facing_full": (Range(-1, 1), "up-component of a normal above which snow covers fully"),
    "snow.snow_albedo": (Range(0, 1), "fresh snow's albedo"),
    "snow.white_balance": (Range(0, low_open=True), "per-channel linear gains under snow light (R, G, B)"),
    "snow.damp": (Range(0, 1), "water film on bare surfaces"),
    "snow.track_cover": (Range(0, 1), "snow cover in the wheel paths, as a fraction of the rest"),
    "snow.mover_share": (Range(0, 1), "snow cover on a moving object, as a fraction of a parked one's"),
    "fog.exposure": (Range(0, low_open=True), "linear exposure of the overcast scene relative to the clear one"),
    "fog.damp": (Range(0, 1), "water film on surfaces"),
    "sky.color": (Range(0, 1), "overcast sky at the horizon (linear R, G, B)"),
}


#: Guided filter regularisation of the snow cover: edges of the frame weaker than sqrt(eps) = 0.1
#: (display RGB) are smoothed over.
_SNOW_EDGE_EPS = 1e-2
#: Up-component of a pixel's normal above which its surface faces up and takes the ground's shadows.
_FACING_UP = 0.7
#: A pixel brighter than white under its normal's light gives the excess to the light only where the
#: sky's matte is at most this (not a sky edge's mixed pixel).
_EXCESS_MAX_SKY_ALPHA = 0.05
#: Window radius (px at 270 rows) of the guided filter that lays the shadow map's visibility onto
#: the frame's shadows: the map (0.25 m cells, occluders only where the lidar reached) misplaces a
#: far occluder's shadow edge by many pixels (docs/findings.md, thirty-second session).
_SHADOW_EDGE_PX = 20
#: Its regularisation on the log of linear light: steps under 0.4 (a ratio of 1.5: texture) are
#: smoothed over; a cast shadow in sunlight is a ratio of 2 or more, the same step on any albedo.
_SHADOW_EDGE_EPS = 0.4 ** 2


def appearance_options() -> dict[str, Option]:
    """The ``appearance`` option of the physical editor: a table per ``[appearance]`` table of the
    presets, a key per preset value (its kind from the value: a number, or a list of as many), bounded
    by :data:`APPEARANCE_KEYS`.

    Raises
    ------
    ValueError
        A preset key without an entry in :data:`APPEARANCE_KEYS`, or an entry of no preset key.
    """
    tables: dict[str, Option] = {}
    seen = set()
    for table, values in load_presets().get("appearance", {}).items():
        keys: dict[str, Option] = {}
        for key, default in values.items():
            full = f"{table}.{key}"
            if full not in APPEARANCE_KEYS:
                raise ValueError(f"appearance.{full}: a preset key without declared bounds (APPEARANCE_KEYS)")
            bounds, doc = APPEARANCE_KEYS[full]
            seen.add(full)
            if isinstance(default, list):
                keys[key] = Option(key, "floats", doc, default=default, range=bounds, length=len(default))
            else:
                keys[key] = Option(key, "float", doc, default=default, range=bounds)
        tables[table] = Option(table, "table", f"the presets' [appearance.{table}] table", table=keys)
    stray = sorted(set(APPEARANCE_KEYS) - seen)
    if stray:
        raise ValueError(f"APPEARANCE_KEYS: entries of no preset key: {stray}")
    return tables


@dataclass(frozen=True)
class AppearanceParams:
    """The ``[appearance]`` tables of the weather presets (see ``presets.toml`` for each value's source).

    Attributes
    ----------
    light : LightModel
    rain, snow, fog : dict
        Per-kind settings.
    sky_color : ndarray [3]
        The overcast sky where a weather has no haze.
    """

    light: LightModel
    rain: dict[str, Any]
    snow: dict[str, Any]
    fog: dict[str, Any]
    sky_color: np.ndarray

    @classmethod
    def load(cls, overrides: Mapping[str, Mapping[str, Any]] | None = None) -> AppearanceParams:
        """The presets' tables, each updated by ``overrides[kind]`` (kinds: light, rain, snow, fog, sky).

        Raises
        ------
        ValueError
            (:class:`~wcbench.core.options.OptionError`) An unknown table or key in ``overrides``, or
            a value outside its declared kind and bounds (:func:`appearance_options`).
        """
        base = {k: dict(v) for k, v in load_presets().get("appearance", {}).items()}
        checked = validate_options(appearance_options(), overrides or {}, path="appearance", owner="appearance")
        for kind, table in checked.items():
            base[kind].update({k: list(v) if isinstance(v, tuple) else v for k, v in table.items()})
        return cls(light=LightModel.from_mapping(base["light"]), rain=base["rain"], snow=base["snow"],
                   fog=base["fog"], sky_color=np.asarray(base["sky"]["color"], np.float32))

    def to_json(self) -> dict[str, Any]:
        """JSON-ready tables (recorded with every edit)."""
        return {"light": {"sun_elevation_deg": self.light.sun_elevation_deg,
                          "direct_to_diffuse": self.light.direct_to_diffuse,
                          "ground_albedo": self.light.ground_albedo},
                "rain": self.rain, "snow": self.snow, "fog": self.fog, "sky": {"color": self.sky_color.tolist()}}

    def puddle_fraction(self, rate_mm_h: float) -> float:
        """Share of the open ground under puddles at a rain rate (mm/h)."""
        return float(self.rain["puddle_max"]) * (1.0 - np.exp(-rate_mm_h / float(self.rain["puddle_rate_mm_h"])))

    def snow_amount(self, rate_mm_h: float) -> float:
        """Cover of an open horizontal surface at a snow rate (mm/h of liquid water)."""
        depth = rate_mm_h * float(self.snow["accumulation_h"])
        return float(1.0 - np.exp(-depth / float(self.snow["full_cover_mm"])))


class WeatherEditor:
    """Edits a scene's raw frames into a weather (see the module docstring).

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Must have lidar; its sky masks are used when it ships them.
    params : AppearanceParams, optional
        Default: the presets'.
    voxel_m : float
        Voxel of the lidar surfaces (m). 0.1 m: at 0.2 m the PCA normals of a near car's sparse
        side blend with its roof's and the side took snow (docs/design.md §7).
    analysis : SceneAnalysis, optional
        The scene's analysis (moving returns, sky, ego vehicle); default
        :func:`~wcbench.reference_model.scene_analysis.analysis.analyse_scene` of ``scene``.

    Raises
    ------
    InputError
        The scene has no lidar point in any frame.
    """

    def __init__(self, scene: Any, *, params: AppearanceParams | None = None, voxel_m: float = 0.1,
                 analysis: SceneAnalysis | None = None):
        start = time.perf_counter()
        self.scene = scene
        self.params = params or AppearanceParams.load()
        self.analysis = analysis if analysis is not None else analyse_scene(scene)
        self.surfaces: SurfaceScene = build_surfaces(scene, voxel_m=voxel_m, analysis=self.analysis)
        self._maps_memo: tuple[tuple[Any, ...], SurfaceMaps] | None = None
        self._sun_memo: tuple[tuple[Any, ...], np.ndarray] | None = None
        # the puddle threshold per rain rate: a quantile of the field over the open ground
        ground = (self.surfaces.static_attributes[:, 3] > 0.5) & (self.surfaces.static_attributes[:, 4] > 0.5)
        field = self.surfaces.static_attributes[ground, 5]
        self._puddle_values = np.sort(field) if field.size else np.array([0.5], np.float32)
        self.setup_seconds = time.perf_counter() - start

    def _sky(self, index: int, camera: Any, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sky mask, soft matte) of frame ``index`` at ``camera``'s size: the scene's mask where it
        ships one (a hard edge), else the scene analysis's segmentation with its matte."""
        w, h = int(camera.width), int(camera.height)
        path = self.scene.frames[index].sky_mask_path
        if path is not None:
            mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if mask is None:
                raise InputError(f"{path}: not a readable image (a sky mask, 8-bit grayscale, was expected)")
            sky = cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST) > 127
            return sky, sky.astype(np.float32)
        sky = self.analysis.sky_mask(index, (w, h))
        return sky, self.analysis.sky_matte(index, image)

    def _solid(self, index: int, camera: Any) -> np.ndarray:
        """[H, W] bool: pixels of frame ``index`` a lidar return lands in, at ``camera``'s size."""
        return self.analysis.solid_mask(index, (int(camera.width), int(camera.height)))

    def maps(self, index: int, camera: Any, image: np.ndarray, *, fields: tuple[str, ...] = FIELDS) -> SurfaceMaps:
        """The completed surface maps of frame ``index`` at ``camera``'s size, with at least the
        attributes ``fields`` of :data:`~.maps.FIELDS` (the last view's are kept: every weather of a
        frame shares them when they hold what it reads); ``image`` is the frame at that size
        (display RGB), the guide of the sky's matte and of the walls' distances."""
        key = (index, np.asarray(camera.K, np.float64).tobytes(), int(camera.width), int(camera.height),
               np.asarray(camera.camera_to_world, np.float64).tobytes())
        memo = self._maps_memo
        if memo is None or memo[0] != key or not set(fields) <= set(memo[1].fields):
            sky, matte = self._sky(index, camera, image)
            reach = self.analysis.reach
            self._maps_memo = memo = (key, surface_maps(
                self.surfaces, index, camera, sky, sky_alpha=matte, solid=self._solid(index, camera), fields=fields,
                image=image, reach=None if reach is None else (reach.range_m, reach.elevation_deg)))
        return memo[1]

    def sun_visibility(self, index: int, camera: Any, image: np.ndarray) -> np.ndarray:
        """[H, W] float32 the sun's visibility in frame ``index`` at ``camera``'s size: each pixel's
        surface point against the shadow map of the scene's occluders and the frame's moving
        objects, laid onto the frame's own shadows by :func:`shadow_edges` (radius 20 px at 270
        rows); 1 without a sun.

        A surface facing up (the ground, a roof) takes the map of the ground's shadows
        (:attr:`~.sun.SunEstimate.ground_direction`), every other one the sun's, tested off its
        surface (:meth:`~.sun.ShadowMap.lit_off_surface`: a facade the sun grazes, a pole, does not
        shadow itself through the map's cells)."""
        sun = self.analysis.sun
        h, w = int(camera.height), int(camera.width)
        if sun.direction is None:
            return np.ones((h, w), np.float32)
        key = (index, np.asarray(camera.K, np.float64).tobytes(), w, h)
        if self._sun_memo is not None and self._sun_memo[0] == key:
            return self._sun_memo[1]
        m = self.maps(index, camera, image, fields=())
        cloud, _ = self.surfaces.at_frame(index)
        moving = np.asarray(cloud.means[len(self.surfaces.gaussians.static):], np.float64)
        shadow = sun.shadow_map(moving)
        ground_shadow = shadow if sun.ground_direction is None else sun.shadow_map(moving, ground=True)
        assert shadow is not None and ground_shadow is not None
        finite = np.isfinite(m.distance)
        points = np.asarray(camera.center, np.float64) + m.rays[finite] * m.distance[finite, None]
        normals = m.normal[finite].astype(np.float64)
        upward = normals @ self.surfaces.up > _FACING_UP
        lit = np.empty(len(points), bool)
        lit[upward] = ground_shadow.lit(points[upward])
        lit[~upward] = shadow.lit_off_surface(points[~upward], normals[~upward])
        vis = np.ones((h, w), np.float32)
        vis[finite] = lit.astype(np.float32)
        vis = shadow_edges(vis, image, radius=max(1, round(_SHADOW_EDGE_PX * h / 270)))
        self._sun_memo = (key, vis)
        return vis

    def overcast_sky(self, rays: np.ndarray) -> np.ndarray:
        """[H, W, 3] display RGB of the overcast sky where a weather has no haze: the CIE standard
        overcast sky's luminance, (1 + 2 sin e) of the horizon's in linear light at elevation e
        (Moon & Spencer 1942), from the ``[appearance.sky]`` horizon colour, clipped."""
        e = np.clip(rays @ self.surfaces.up.astype(np.float32), 0.0, 1.0)[..., None]
        horizon = srgb_to_linear(self.params.sky_color)
        return linear_to_srgb(horizon * (1.0 + 2.0 * e))

    def edit(self, raw: np.ndarray, index: int, camera: Any, weather: Weather) -> tuple[np.ndarray, dict[str, Any]]:
        """Raw frame ``index`` under ``weather``.

        Parameters
        ----------
        raw : ndarray [H, W, 3] float32
            The clear frame, display RGB in [0, 1], at ``camera``'s size.
        index : int
        camera : Camera
            The frame's camera at the size of ``raw``.
        weather : Weather
            Its kind, rate and haze drive the edit; ``clear`` returns ``raw``.

        Returns
        -------
        image : ndarray [H, W, 3] float32
        info : dict
            Timings (ms) and the fractions of the frame wet, in puddles and under snow.
        """
        if raw.shape[:2] != (int(camera.height), int(camera.width)):
            raise ValueError(f"raw is {raw.shape[1]}x{raw.shape[0]}, the camera {camera.width}x{camera.height}")
        if weather.kind == "clear":
            return np.asarray(raw, np.float32), {}
        t0 = time.perf_counter()
        m = self.maps(index, camera, raw, fields=FIELDS_READ.get(weather.kind, ()))
        t_maps = time.perf_counter()
        p, kind = self.params, weather.kind
        table = getattr(p, kind)
        h = raw.shape[0]
        radius = max(1, round(2 * h / 270))
        up = self.surfaces.up
        n_up = m.normal @ up.astype(np.float32)
        exposure = float(table["exposure"])
        # where the sky shows through partly (an edge, a wire, a branch), the surface's own colour: a
        # pixel sums the radiance of what it sees, so the matting equation holds in linear light
        lin = decontaminate(srgb_to_linear(raw), m.sky_alpha)
        # the raw pixel stands for the albedo under the clear sky's light on its normal (and the sun's,
        # where the frames show where it shone); weather changes the albedo (a water film, snow), then
        # the overcast sky lights it at the weather's exposure, shadowed and sunlit pixels alike
        sun = self.analysis.sun
        if sun.direction is not None:
            clear = sunlit_irradiance(m.normal, self.sun_visibility(index, camera, raw), up=up, sun=sun.direction,
                                      direct_to_diffuse=sun.direct_to_diffuse, ground_albedo=p.light.ground_albedo)
        else:
            clear = clear_irradiance(n_up, model=p.light)[..., None]
        albedo = lin / np.maximum(clear, 1e-3)
        light = exposure * overcast_irradiance(n_up, model=p.light)[..., None]
        # a pixel brighter than white under the light its normal gets (an albedo over 1: a wall lamp's
        # downward normals spread over the bright wall round it, a sunlit facade the shadow map calls
        # shaded) was lit by more than the model says: the excess is the light's, moved out of the
        # albedo into the overcast light, which keeps the pixel's hue and texture (clipped to 1 per
        # channel by the water film and the snow, it left a grey, flat halo, docs/findings.md), up to
        # the overcast light of a surface facing the zenith, which no surface exceeds
        # but not where the matte says the pixel is partly sky: there the excess is the sky's own
        # radiance the matte (low at a pole's or a roof's edge) left in it, blue that the clip greys
        # and the light would keep (clear-sky blue beside a pole in every weather, docs/findings.md)
        # (the channels' maximum pairwise: a reduction over the last axis of three takes 20 times as long)
        brightest = np.maximum(np.maximum(albedo[..., 0], albedo[..., 1]), albedo[..., 2])
        excess = np.where(m.sky_alpha[..., None] > _EXCESS_MAX_SKY_ALPHA, 1.0, np.maximum(brightest, 1.0)[..., None])
        albedo /= excess
        light = np.minimum(light * excess, exposure * float(overcast_irradiance(np.float32(1.0), model=p.light)))
        beta, haze_color, offset = weather.haze()
        # the sky: at infinity, the haze's airlight; without haze, the overcast sky
        sky = np.broadcast_to(np.asarray(haze_color, np.float32), raw.shape) if beta > 0 else self.overcast_sky(m.rays)
        info: dict[str, Any] = {}
        if kind == "rain":
            rate = weather.precipitation_rate()
            fraction = p.puddle_fraction(rate)
            # both snapped in one guided filter: its statistics of the frame are shared
            snapped = refine(np.dstack([m.ground, m.open]), raw, radius=radius)
            ground, openness = snapped[..., 0], snapped[..., 1]
            if fraction > 0:
                threshold = float(np.quantile(self._puddle_values, 1.0 - fraction))
                # a puddle's edge fades over a band of the noise (the water thins out at its rim)
                puddle = smoothstep(m.puddle, threshold - 0.03, threshold + 0.05) * ground * openness
            else:  # no puddle at all (a drizzle, or puddle_max 0)
                puddle = np.zeros_like(ground)
            vertical_wet = float(table["wetness_vertical"])
            wet = (vertical_wet + (float(table["wetness_horizontal"]) - vertical_wet) * smoothstep(n_up, 0.3, 0.9))
            wet = wet * openness * (1.0 - (1.0 - float(table["track_wetness"])) * m.track)
            wet = np.maximum(wet, puddle) * ~m.sky
            base = wet_albedo(albedo, wet) * light
            # the reflection in the wet ground: where the mirrored ray meets the scene (the lidar's
            # surfaces mirrored about the ground plane), in the colours the camera sees there under
            # the weather (the edit without reflection, its haze over the camera's path to the
            # reflected point, close to the reflected path's beyond the ground point; the pixel's own
            # haze, camera to ground, is added with everything else below)
            refl_dist = mirror_distance(self.surfaces, index, camera, m.ground_height)
            seen = apply_haze(linear_to_srgb(base), m.distance, beta=beta, color=haze_color, offset_m=offset)
            seen = over_sky(seen, sky, m.sky_alpha)
            mirrored = m.rays - 2.0 * (m.rays @ up.astype(np.float32))[..., None] * up.astype(np.float32)
            sky_mirrored = np.broadcast_to(np.asarray(haze_color, np.float32), raw.shape) if beta > 0 else \
                self.overcast_sky(mirrored)
            refl, _ = screen_reflection(seen, camera, m, refl_dist, up=up, sky=sky_mirrored)
            blur = float(table["rough_blur_px"]) * h / 270.0
            rough = glossy_blur(refl, ground, m.rays, up=up, sigma_px=blur)
            # the water's surface is level (a puddle stands flat, a film fills the asphalt's grain) and
            # the reflection mirrors about the ground plane: Fresnel takes the ray's angle to the plane,
            # not to the lidar's normal, whose tilt from ring to ring (a degree or two) moved F by a
            # tenth at a grazing view and striped a puddle across (docs/findings.md)
            cos = np.abs(m.rays @ up.astype(np.float32))
            fresnel = fresnel_schlick(cos, float(table["fresnel_f0"]))
            road = ground * (1.0 - puddle) * float(table["sheen_road"]) * wet
            still = puddle * float(table["sheen_puddle"])
            reflect_lin = srgb_to_linear(rough) * (fresnel * road)[..., None] + \
                srgb_to_linear(refl) * (fresnel * still)[..., None]
            weight = (fresnel * (road + still))[..., None]
            base = base * (1.0 - weight) + reflect_lin
            info.update(rate_mm_h=rate, puddle_fraction_of_frame=round(float((puddle > 0.5).mean()), 4),
                        wet_fraction_of_frame=round(float((wet > 0.5).mean()), 4))
        elif kind == "snow":
            rate = weather.precipitation_rate()
            amount = p.snow_amount(rate)
            openness = refine(m.open, raw, radius=radius)
            # the ground faces up by its fitted cells, not by each return's noisy normal (a kerb's
            # face is no ground): open ground takes one even cover
            facing = np.maximum(n_up, m.ground)
            cover = snow_cover(facing, openness, amount=amount, facing_from=float(table["facing_from"]),
                               facing_full=float(table["facing_full"]))
            cover = cover * (1.0 - (1.0 - float(table["track_cover"])) * m.track) * ~m.sky
            if m.moving is not None:  # a car driven through the falling snow holds a share of a parked one's
                cover = cover * (1.0 - (1.0 - float(table["mover_share"])) * m.moving)
            # snapped to the frame's strong edges only (a car against the road), not to the texture
            # of the asphalt or a paving stone, which would print the clear frame's patches into
            # the snow and move with them from frame to frame
            cover = refine(cover, raw, radius=radius, eps=_SNOW_EDGE_EPS)
            bare = wet_albedo(albedo, float(table["damp"]) * openness)
            # snow is lit by the overcast sky: its albedo at the overcast exposure and irradiance
            base = (bare * (1.0 - cover[..., None]) + float(table["snow_albedo"]) * cover[..., None]) * light
            base = base * np.asarray(table["white_balance"], np.float32)
            info.update(rate_mm_h=rate, snow_amount=round(amount, 4),
                        snow_fraction_of_frame=round(float((cover > 0.5).mean()), 4))
        else:
            base = wet_albedo(albedo, float(table["damp"]) * ~m.sky) * light
        surface = apply_haze(linear_to_srgb(base), m.distance, beta=beta, color=haze_color, offset_m=offset)
        out = over_sky(surface, sky, m.sky_alpha)
        ego = self.analysis.ego_mask((raw.shape[1], raw.shape[0]))
        if ego.any():
            out[ego] = masked_ego(raw[ego], kind, p)
        t_end = time.perf_counter()
        info["timings_ms"] = {"maps": round(1e3 * (t_maps - t0), 2), "shade": round(1e3 * (t_end - t_maps), 2)}
        info["haze"] = {"beta_per_m": beta, "color": np.asarray(haze_color).tolist(), "offset_m": offset}
        return np.clip(out, 0.0, 1.0).astype(np.float32), info


def shadow_edges(visibility: np.ndarray, image: np.ndarray, *, radius: int,
                 eps: float = _SHADOW_EDGE_EPS) -> np.ndarray:
    """The sun's visibility of a shadow map laid onto the frame's own shadows: a guided filter (He
    et al. 2013) guided by the log of the frame's linear light, the soft shadow matte of shadow
    removal (Guo, Dai & Hoiem 2013 mat the detected shadow's boundary the same way).

    A cast shadow divides the light of whatever it falls on by the same ratio, so in log light it
    is one step on every albedo, and the filter's local linear model puts a step in the
    visibility where the frame's is, within ``radius`` of the map's edge, spreading what is left
    of the map's edge over its window (a map edge 12 px off: a step of about 0.3 at the frame's
    edge, then a ramp; tests/reference_model/appearance/test_editor_shadow_edges.py); a window
    where the map does not change returns it unchanged whatever the frame shows there (a dark
    patch of asphalt the map calls lit stays lit), and steps under ``sqrt(eps)`` in log light
    (texture) are smoothed over.

    Parameters
    ----------
    visibility : ndarray [H, W] float
        The map's visibility in [0, 1].
    image : ndarray [H, W, 3] float32
        The frame, display RGB in [0, 1].
    radius : int
        Window radius (px); 0 returns ``visibility``.
    eps : float
        Regularisation, in squared log light.

    Returns
    -------
    ndarray [H, W] float32 in [0, 1]
    """
    if radius <= 0:
        return np.asarray(visibility, np.float32)
    # log light from 1e-3 (about 3 of 255 levels in sRGB: below it, noise) to 1, scaled to [0, 1]
    span = float(np.log(1e3))
    guide = 1.0 + np.log(np.maximum(srgb_to_linear(np.asarray(image, np.float32)), 1e-3)) / span
    out = guided_filter(np.clip(guide, 0.0, 1.0), visibility, radius=int(radius), eps=float(eps) / span ** 2)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def masked_ego(raw: np.ndarray, kind: str, params: AppearanceParams) -> np.ndarray:
    """The ego vehicle's own body under ``kind``: masked, not weathered (no water, snow or haze on
    it, nor a lighting by normals it has none of): the raw pixels at the weather's overcast exposure
    in linear light; ``clear`` keeps them.

    Parameters
    ----------
    raw : ndarray [..., 3]
        Display RGB in [0, 1].
    kind : str
    params : AppearanceParams

    Returns
    -------
    ndarray [..., 3] float32
    """
    if kind == "clear":
        return np.asarray(raw, np.float32)
    return linear_to_srgb(srgb_to_linear(raw) * float(getattr(params, kind)["exposure"]))


def over_sky(surface: np.ndarray, sky: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The edited surface and the new sky composited by the sky's matte in linear light: a pixel
    sums the radiance of the sky and of the surface in the shares of its area they cover (the
    compositing equation, Porter & Duff 1984, holds for radiance, not for display values: blended
    in display values a dark pole's or wire's edge against a bright overcast reads darker and wider
    than its share of the pixel).

    Parameters
    ----------
    surface, sky : ndarray [H, W, 3]
        Display RGB in [0, 1].
    alpha : ndarray [H, W]
        Soft sky matte in [0, 1].

    Returns
    -------
    ndarray [H, W, 3] float32
        Display RGB.
    """
    a = np.clip(np.asarray(alpha, np.float32), 0.0, 1.0)
    sky = np.broadcast_to(np.asarray(sky, np.float32), np.shape(surface))
    out = np.array(surface, np.float32)
    np.copyto(out, sky, where=(a >= 1.0)[..., None])
    mixed = (a > 0.0) & (a < 1.0)  # only the edge needs the round trip through linear light
    share = a[mixed][:, None]
    out[mixed] = linear_to_srgb(share * srgb_to_linear(sky[mixed]) + (1.0 - share) * srgb_to_linear(out[mixed]))
    return out


def decontaminate(image: np.ndarray, alpha: np.ndarray, *, sigma_px: float | None = None) -> np.ndarray:
    """The foreground colour of pixels the sky shows through partly: F = (I - a B) / (1 - a) per
    pixel (the compositing equation of matting, Porter & Duff 1984; Chuang et al. 2001), with B the
    clear sky's colour there (a normalised convolution of the pixels with a >= 0.99, Gaussian of
    ``sigma_px``, default 6 px at 270 rows) and a clipped at 0.9 (so noise is amplified at most 10x).

    Parameters
    ----------
    image : ndarray [H, W, 3] float32
        Display RGB in [0, 1].
    alpha : ndarray [H, W] float32
        Soft sky matte.

    Returns
    -------
    ndarray [H, W, 3] float32
        ``image`` where a = 0, the estimate elsewhere (clipped to [0, 1]).
    """
    img = np.asarray(image, np.float32)
    a = np.clip(np.asarray(alpha, np.float32), 0.0, 0.9)
    mixed = (a > 0.0) & (a < 0.9)
    if not mixed.any():
        return img
    sigma = sigma_px if sigma_px is not None else 6.0 * img.shape[0] / 270.0
    # the blur only where it is read: the mixed pixels' bounding rectangle grown by the kernel's
    # radius (OpenCV's for float images, 4 sigma), so every pixel read sees the same neighbours
    # and, at the frame's edges, the same reflected border as on the whole frame
    radius = (round(float(sigma) * 8 + 1) | 1) // 2
    rows, cols = np.flatnonzero(mixed.any(axis=1)), np.flatnonzero(mixed.any(axis=0))
    y0, y1 = max(0, int(rows[0]) - radius), min(img.shape[0], int(rows[-1]) + 1 + radius)
    x0, x1 = max(0, int(cols[0]) - radius), min(img.shape[1], int(cols[-1]) + 1 + radius)
    crop = img[y0:y1, x0:x1]
    inside = (np.asarray(alpha)[y0:y1, x0:x1] >= 0.99).astype(np.float32)
    # the numerator and the weight blurred as one four-channel image (OpenCV filters each alone)
    blurred = cv2.GaussianBlur(np.dstack([crop * inside[..., None], inside]), (0, 0), sigma)
    rr, cc = np.nonzero(mixed[y0:y1, x0:x1])
    num, den, seen = blurred[rr, cc, :3], blurred[rr, cc, 3:], crop[rr, cc]
    behind = np.where(den > 1e-3, num / np.maximum(den, 1e-3), seen)
    share = a[rr + y0, cc + x0][:, None]
    out = img.copy()
    out[rr + y0, cc + x0] = np.clip((seen - share * behind) / (1.0 - share), 0.0, 1.0)
    return out
