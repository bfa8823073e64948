"""The frames of the synthetic scenes, clear and under each truth weather: the materials under each
weather, the sky, and the reference model's weather renderer (docs/design.md §3, §7). v1's scenes
are shaded by :func:`shade_gaussians`; scenes whose profile has a sun by
:func:`~.materials.shade_physical`, with the cast shadows of :mod:`.shadows` and truth masks (sky,
shadow, movers) rasterized with the clear frame.

Rendering needs the reference model (torch and numba, the ``[model]`` extra); it is imported when
a scene is generated (:func:`reference_model`), so that the scene sets load without it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.scenes.synth.content import Content, boxes_at, cloud_at
from wcbench.scenes.synth.geometry import Cloud, gaussian_normals
from wcbench.scenes.synth.layout import FOCAL, HEIGHT, MATERIALS_V1, TRUTH_WEATHERS, WIDTH
from wcbench.scenes.synth.light import clear_sky, overcast_sky, srgb_to_linear
from wcbench.scenes.synth.materials import GLASS_F0, Surfaces, physical_materials, shade_physical
from wcbench.scenes.synth.mirrors import mirrored_colors, mirrors_meeting
from wcbench.scenes.synth.shadows import ShadowCaster

__all__ = ["TruthFrame", "TruthRenderer", "reference_model", "shade_gaussians", "sky_colors"]


def sky_colors(rays_up: np.ndarray, weather: str) -> np.ndarray:
    """[H, W, 3] v1's sky colour by the elevation of each pixel's ray (``rays_up``: sine of it)."""
    if weather == "clear":
        return clear_sky(rays_up)
    e = np.clip(rays_up, 0.0, 1.0)[..., None]
    # an overcast sky is brighter overhead than at the horizon: luminance (1 + 2 sin e) / 3 in the CIE
    # overcast sky (Moon & Spencer 1942), softened
    grey = np.asarray(MATERIALS_V1[weather]["overcast_sky"], np.float64)
    return grey * (0.8 + 0.2 * (1.0 + 2.0 * e) / 3.0)


def shade_gaussians(weather: str, cloud: Cloud, normals: np.ndarray, eye: np.ndarray, reflected: np.ndarray
                    ) -> np.ndarray:
    """[N, 3] colours of v1's Gaussians under ``weather`` seen from ``eye`` (docs/design.md §3).

    ``reflected`` [3] is the sky colour a wet surface mirrors (the weather's overcast or haze colour).
    """
    up = normals[:, 2]
    if weather == "clear":
        m = MATERIALS_V1["clear"]
        sun = np.asarray(m["sun_direction"], np.float64)
        light = m["ambient"] + m["sun"] * np.maximum(normals @ (sun / np.linalg.norm(sun)), 0.0)
        return cloud.albedo * light[:, None]
    m = MATERIALS_V1[weather]
    light = (m["light"] * (1.0 - m["sky_light"] + m["sky_light"] * up))[:, None]  # the overcast sky lights from above
    if weather == "rain":
        view = cloud.means - eye
        cos = np.abs(np.sum(view * normals, axis=1)) / np.maximum(np.linalg.norm(view, axis=1), 1e-9)
        fresnel = (m["fresnel_f0"] + (1.0 - m["fresnel_f0"]) * (1.0 - cos) ** 5) * cloud.sheen
        return cloud.albedo * cloud.wet[:, None] * light * (1.0 - fresnel[:, None]) + fresnel[:, None] * reflected
    if weather == "snow":
        lo, hi = m["normal_up_from"], m["normal_up_full"]
        facing = np.clip((up - lo) / (hi - lo), 0.0, 1.0)
        cover = (cloud.snow * facing * facing * (3.0 - 2.0 * facing))[:, None]  # smoothstep
        # what snow leaves bare is damp
        return light * ((1.0 - cover) * cloud.albedo * m["wet"] + cover * np.asarray(m["snow_albedo"]))
    return cloud.albedo * light * m["wet"]


def reference_model() -> tuple[Any, Any, Any, Any]:
    """The renderer's classes, imported only when a scene is generated (they need torch and numba).

    Returns
    -------
    tuple
        ``Weather``, ``WeatherRenderer``, ``camera_velocity`` and ``GaussianArrays`` of
        :mod:`wcbench.reference_model.weather`.

    Raises
    ------
    InputError
        Without torch or numba, naming the extra to install.
    """
    try:
        from wcbench.reference_model.weather.conditions import Weather
        from wcbench.reference_model.weather.renderer import GaussianArrays, WeatherRenderer, camera_velocity
    except ImportError as exc:
        raise InputError(
            f"the synth_* scene sets are rendered with the reference model, which needs torch and numba "
            f"({exc}); install them with: pip install \"wcbench[model]\""
        ) from None
    return Weather, WeatherRenderer, camera_velocity, GaussianArrays


@dataclass
class TruthFrame:
    """One frame of a scene, clear and under every truth weather.

    Attributes
    ----------
    frames : dict of str to WeatherFrame
        Per weather (``"clear"`` first), the renderer's frame (float32 image and alpha).
    gaussians : int
        Scene Gaussians of the frame.
    masks : dict of str to ndarray [H, W] uint8
        With a profile's ``truth_masks``: ``sky``, ``shadow`` and ``movers`` of the clear frame
        (255 where set); else empty.
    """

    frames: dict[str, Any]
    gaussians: int
    masks: dict[str, np.ndarray]


@dataclass
class TruthRenderer:
    """Renders every frame of a scene clear and under each of :data:`TRUTH_WEATHERS`.

    Parameters
    ----------
    content : Content
        The scene (street coordinates).
    cameras : list of Camera
        Every frame's camera, where the loaders put the scene (first camera at the origin).
    times : ndarray [F]
        Timestamps (s).
    shift : ndarray [3]
        Street coordinates of the first camera (subtracted from every position).
    """

    content: Content
    cameras: list[Any]
    times: np.ndarray
    shift: np.ndarray
    renderers: dict[str, Any] = field(init=False)
    reflected: dict[str, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        Weather, WeatherRenderer, camera_velocity, GaussianArrays = reference_model()
        self._camera_velocity, self._arrays = camera_velocity, GaussianArrays
        self.profile = self.content.spec.profile
        self.centers = np.array([c.center for c in self.cameras])
        first = cloud_at(self.content, 0)
        geometry = GaussianArrays(*(np.asarray(a, np.float32) for a in (
            first.means - self.shift, first.quats, first.scales, first.opacities, first.albedo)))
        self.renderers = {
            w: WeatherRenderer(geometry, Weather(kind=w, seed=self.content.spec.seed, **TRUTH_WEATHERS.get(w, {})),
                               up=np.array([0.0, 0.0, 1.0]), heading=self.cameras[0].camera_to_world[:3, 2],
                               anchor=self.centers[0])
            for w in ("clear", *TRUTH_WEATHERS)
        }
        if self.profile.sun is None:
            # a wet surface mirrors the sky it sees: the weather's haze colour when it has haze (the sky
            # then takes that colour, docs/design.md §7), else its overcast colour
            self.reflected = {w: np.asarray(r.fog_color if r.beta > 0 else
                                            MATERIALS_V1[w].get("overcast_sky", (0, 0, 0)), np.float64)
                              for w, r in self.renderers.items()}
        else:
            # a mirror (wet ground, window glass) sees the haze's colour where there is haze (the sky is
            # at infinity, behind all of it), else the sky at the reflected ray's elevation
            self.reflected = {w: np.asarray(r.fog_color, np.float64) for w, r in self.renderers.items() if r.beta > 0}
            self.materials = physical_materials()
            self.shadows = ShadowCaster(self.content)
            self._static_albedo = srgb_to_linear(self.content.static.albedo)  # linear, for every frame
        K = self.cameras[0].K
        jj, ii = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
        rays = np.stack([(jj - K[0, 2]) / FOCAL, (ii - K[1, 2]) / FOCAL, np.ones_like(jj)], -1)
        self._rays_cam = rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def _mirrored_sky(self, weather: str) -> Any:
        """The sRGB sky a mirror sees under ``weather``: the haze's colour [3], or a function of the
        sine of the reflected ray's elevation (see :func:`~.materials.shade_physical`)."""
        if weather in self.reflected:
            return self.reflected[weather]
        return clear_sky if weather == "clear" else overcast_sky

    def _traced_mirrors(self, k: int, cloud: Cloud, surfaces: Surfaces, sky: Any, renderer: Any) -> np.ndarray:
        """[N, 3] sRGB what each Gaussian of frame ``k`` mirrors under rain: for the wet ones
        (``sheen`` > 0) what their reflected view ray meets in the street (:mod:`.mirrors`), in the
        colours the street has under rain, hazed over the reflected path; ``sky`` (the sky a mirror
        sees: a function of the reflected ray's elevation, or one colour) elsewhere. Window glass
        keeps the sky: a material the editors are not to read (docs/design.md §3)."""
        assert self.profile.sun is not None
        bare = shade_physical("rain", surfaces, sun=self.profile.sun, visibility=None, sky=np.zeros(3),
                              materials=self.materials, mirror_windows=self.profile.mirror_windows)
        everywhere = sky(surfaces.mirror_up) if callable(sky) else np.asarray(sky, np.float64)
        seen, _ = mirrored_colors(cloud.means, surfaces.normals, self.cameras[k].center + self.shift, cloud.sheen > 0,
                                  bare, everywhere, boxes_at(self.content, k), self.content.spheres,
                                  beta=float(renderer.beta), haze=np.asarray(renderer.fog_color, np.float64))
        return seen

    def frame(self, k: int) -> TruthFrame:
        """Frame ``k`` clear and under every truth weather (and, with the profile's ``truth_masks``,
        the clear frame's sky, shadow and movers masks)."""
        cam = self.cameras[k]
        cloud = cloud_at(self.content, k)
        normals = gaussian_normals(cloud.quats, cloud.scales)
        means = cloud.means - self.shift
        rays_up = self._rays_cam @ cam.camera_to_world[2, :3]
        velocity = self._camera_velocity(self.centers, self.times, k)
        frames: dict[str, Any] = {}
        masks: dict[str, np.ndarray] = {}
        sun = self.profile.sun
        visibility, surfaces = None, None
        if sun is not None:
            visibility = self.shadows.visibility(k, cloud)
            n_static = len(self.content.static)
            albedo = np.concatenate([self._static_albedo, srgb_to_linear(cloud.albedo[n_static:])])
            surfaces = Surfaces.of(cloud, normals, cam.center + self.shift, sun, albedo)
        for w, r in self.renderers.items():
            if sun is None:
                colors = shade_gaussians(w, cloud, normals, cam.center + self.shift, self.reflected[w])
            else:
                assert surfaces is not None
                sky_seen = self._mirrored_sky(w)
                if w == "rain" and self.profile.traced_mirrors:
                    sky_seen = self._traced_mirrors(k, cloud, surfaces, sky_seen, r)
                colors = shade_physical(w, surfaces, sun=sun, visibility=visibility if w == "clear" else None,
                                        sky=sky_seen, materials=self.materials,
                                        mirror_windows=self.profile.mirror_windows)
            splats = self._arrays(*(np.asarray(a, np.float32) for a in (
                means, cloud.quats, cloud.scales, cloud.opacities, np.clip(colors, 0.0, 1.0))))
            sky = sky_colors(rays_up, w).astype(np.float32) if r.background_visible else None
            if w == "clear" and self.profile.truth_masks:
                assert visibility is not None and sky is not None
                moving = np.zeros(len(cloud))
                moving[len(self.content.static):] = 1.0  # cloud_at: the static Gaussians, then the moving ones
                frames[w], masks = self._clear_with_masks(r, cam, splats, np.stack([visibility, moving], 1), sky)
            else:
                frames[w] = r.render(cam, float(self.times[k]), camera_velocity=velocity, gaussians=splats,
                                     background_image=sky)
        return TruthFrame(frames, len(cloud), masks)

    def _clear_with_masks(self, renderer: Any, cam: Any, splats: Any, channels: np.ndarray, sky: np.ndarray
                          ) -> tuple[Any, dict[str, np.ndarray]]:
        """The clear frame, rasterized with two more channels, and the truth masks they give.

        The clear renderer draws no particles and no fog, so its frame is the scene's colour over
        the sky, ``C + (1 - A) sky``; the visibility and mover channels ride in the same
        rasterization, composited like a colour. A pixel whose alpha is below 0.5 is sky; of the
        others, one whose composited visibility over alpha is below 0.5 is in cast shadow, and
        one whose composited mover share over alpha is 0.5 or more shows a moving object.

        Returns
        -------
        frame : WeatherFrame
        masks : dict of str to ndarray [H, W] uint8
            ``sky``, ``shadow``, ``movers``: 255 where set.
        """
        import torch

        from wcbench.reference_model.weather.renderer import WeatherFrame

        colors = np.concatenate([np.asarray(splats.colors, np.float32), channels.astype(np.float32)], 1)
        t = {name: torch.from_numpy(np.ascontiguousarray(getattr(splats, name), np.float32))
             for name in ("means", "quats", "scales", "opacities")}
        with torch.no_grad():
            out = renderer.rasterizer(t["means"], t["quats"], t["scales"], t["opacities"], torch.from_numpy(colors),
                                      torch.from_numpy(np.asarray(cam.world_to_camera, np.float32)),
                                      torch.from_numpy(np.asarray(cam.K, np.float32)), int(cam.width),
                                      int(cam.height), near=renderer.near, background=None, render_depth=False)
        color, alpha = out.color.numpy(), out.alpha.numpy()
        image = np.clip(color[..., :3] + (1.0 - alpha)[..., None] * sky, 0.0, 1.0)
        solid = alpha >= 0.5
        masks = {"sky": ~solid, "shadow": solid & (color[..., 3] < 0.5 * alpha),
                 "movers": solid & (color[..., 4] >= 0.5 * alpha)}
        frame = WeatherFrame(image=image, alpha=alpha, depth=None, info={}, timings_ms={})
        return frame, {name: np.where(m, 255, 0).astype(np.uint8) for name, m in masks.items()}

    def _composite(self, k: int, cloud: Any, values: np.ndarray) -> np.ndarray:
        """[H, W] the per-Gaussian ``values`` [N] of frame ``k``'s ``cloud`` composited like a colour
        (premultiplied by alpha) in frame ``k``'s camera."""
        import torch

        cam, r = self.cameras[k], self.renderers["clear"]
        marks = np.repeat(np.asarray(values, np.float32)[:, None], 3, axis=1)
        t = [torch.from_numpy(np.ascontiguousarray(a, np.float32))
             for a in (cloud.means - self.shift, cloud.quats, cloud.scales, cloud.opacities, marks)]
        with torch.no_grad():
            out = r.rasterizer(*t, torch.from_numpy(np.asarray(cam.world_to_camera, np.float32)),
                               torch.from_numpy(np.asarray(cam.K, np.float32)), int(cam.width), int(cam.height),
                               near=r.near, background=None, render_depth=False)
        result: np.ndarray = out.color.numpy()[..., 0]
        return result

    def silhouette(self, k: int, content: Content, span: tuple[int, int], *, weight: float) -> np.ndarray:
        """[H, W] bool: where the Gaussians ``span`` (start, stop) of ``content``'s frame ``k``
        (:func:`~.content.cloud_at` order) have a composited weight of at least ``weight`` in frame
        ``k``'s camera, in front of and behind the rest of the scene as it is drawn."""
        cloud = cloud_at(content, k)
        marks = np.zeros(len(cloud))
        marks[span[0]:span[1]] = 1.0
        result: np.ndarray = self._composite(k, cloud, marks) >= weight
        return result

    def mirrored_object(self, k: int, mover: int) -> np.ndarray:
        """[H, W] where frame ``k``'s wet ground mirrors moving object ``mover`` under rain, composited
        like a colour (the share of the pixel's Gaussians whose reflected view ray meets the object's
        boxes first; :mod:`.mirrors`); zero without traced mirrors."""
        cloud = cloud_at(self.content, k)
        if not self.profile.traced_mirrors:
            return np.zeros((HEIGHT, WIDTH))
        normals = gaussian_normals(cloud.quats, cloud.scales)
        sees = mirrors_meeting(cloud.means, normals, self.cameras[k].center + self.shift, cloud.sheen > 0,
                               boxes_at(self.content, k), self.content.spheres, mover)
        return self._composite(k, cloud, sees.astype(np.float64))

    def sun_visibility(self, k: int) -> np.ndarray:
        """[H, W] the share of the sun each pixel's Gaussians see in frame ``k``, composited
        (premultiplied by alpha; profiles with a sun only)."""
        cloud = cloud_at(self.content, k)
        return self._composite(k, cloud, self.shadows.visibility(k, cloud))

    def record(self) -> dict[str, Any]:
        """What ``truth/weather.json`` holds: per truth weather its preset, seed, rate, visibility,
        the renderer's settings and the materials; for clear the materials and the sky (with a sun:
        the sun and sky light, the special materials and what the truth masks mean)."""
        truth: dict[str, Any] = {}
        sun = self.profile.sun
        for w in TRUTH_WEATHERS:
            info = self.renderers[w].info()
            truth[w] = {"kind": w, "preset": info["preset"], "seed": self.content.spec.seed, "weather": info["weather"],
                        "rate_mm_h": info.get("particles", {}).get("spec", {}).get("rate_mm_h"),
                        "visibility_m": info["fog"]["visibility_m"], "renderer": info,
                        "materials": MATERIALS_V1[w] if sun is None else self.materials[w]}
            if sun is None:
                truth[w]["sky_mirrored_by_wet_surfaces"] = self.reflected[w]
            else:
                truth[w]["light"] = ("overcast, no sun and no shadows: the CIE standard overcast sky's irradiance "
                                     "by the normal's tilt plus the ground's reflection, times 'light' on a "
                                     "horizontal surface (linear)")
                truth[w]["sky_mirrored"] = (self.reflected[w] if w in self.reflected else
                                            "CIE overcast gradation from the horizon colour")
                if w == "rain" and self.profile.traced_mirrors:
                    truth[w]["wet_ground_mirrors"] = (
                        "what the view ray reflected at each wet Gaussian meets first (the lidar's boxes, the "
                        "canopy spheres, the ground plane), in that Gaussian's rain colour without its own "
                        "mirror, hazed over the reflected path; 'sky_mirrored' where it meets none; window "
                        "glass mirrors 'sky_mirrored'")
        if sun is None:
            truth["clear"] = {"materials": MATERIALS_V1["clear"], "sky": "per-pixel gradient by ray elevation"}
            return truth
        truth["clear"] = {
            "sky": "per-pixel gradient by ray elevation", "light": "linear; colours are sRGB-encoded per Gaussian",
            "sun": {**asdict(sun), "direction_street": sun.direction().tolist(),
                    "model": "irradiance = sky_rgb (1 + n_z) / 2 + ground_albedo E_ground (1 - n_z) / 2 "
                             "+ sun_rgb max(n.s, 0) V, V the share of 4 rays per Gaussian toward the sun disk "
                             "that no box or canopy sphere blocks"},
        }
        truth["materials"] = {
            "road_patches": self.content.road_patches,
            "white_facade": self.content.white_facade,
            "mirror_windows": {"enabled": self.profile.mirror_windows, "fresnel_f0": GLASS_F0,
                               "model": "window glass (share 'gloss' of a facade Gaussian) adds Schlick's Fresnel "
                                        "reflection of the sky at the reflected ray's elevation: the clear sky in "
                                        "the clear frames, the haze colour under the truth weathers"},
        }
        truth["masks"] = {
            "sky": "truth/masks/sky/{t:03d}_0.png: 255 where the clear render's alpha is below 0.5",
            "shadow": "truth/masks/shadow/{t:03d}_0.png: 255 where a surface facing the sun is in cast shadow "
                      "(composited sun visibility over alpha below 0.5; surfaces facing away from the sun are "
                      "not cast shadow; sky 0)",
            "movers": "truth/masks/movers/{t:03d}_0.png: 255 on moving objects, tracked or not (composited "
                      "mover share over alpha 0.5 or more)",
        }
        return truth
