"""The frames of the synthetic scenes, clear and under each truth weather: the materials under each
weather, the sky, and the reference model's weather renderer (docs/design.md §3, §7).

Rendering needs the reference model (torch and numba, the ``[model]`` extra); it is imported when
a scene is generated (:func:`reference_model`), so that the scene sets load without it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.scenes.synth.content import Content, cloud_at
from wcbench.scenes.synth.geometry import Cloud, gaussian_normals
from wcbench.scenes.synth.layout import FOCAL, HEIGHT, MATERIALS, TRUTH_WEATHERS, WIDTH

__all__ = ["TruthRenderer", "reference_model", "shade_gaussians", "sky_colors"]


def sky_colors(rays_up: np.ndarray, weather: str) -> np.ndarray:
    """[H, W, 3] sky colour by the elevation of each pixel's ray (``rays_up``: sine of it)."""
    e = np.clip(rays_up, 0.0, 1.0)[..., None]
    if weather == "clear":
        horizon, zenith = np.array([0.78, 0.84, 0.92]), np.array([0.30, 0.52, 0.88])
        return horizon + (zenith - horizon) * (1.0 - np.exp(-e / 0.22))
    # an overcast sky is brighter overhead than at the horizon: luminance (1 + 2 sin e) / 3 in the CIE
    # overcast sky (Moon & Spencer 1942), softened
    grey = np.asarray(MATERIALS[weather]["overcast_sky"], np.float64)
    return grey * (0.8 + 0.2 * (1.0 + 2.0 * e) / 3.0)


def shade_gaussians(weather: str, cloud: Cloud, normals: np.ndarray, eye: np.ndarray, reflected: np.ndarray
                    ) -> np.ndarray:
    """[N, 3] colours of the Gaussians under ``weather`` seen from ``eye`` (docs/design.md §3).

    ``reflected`` [3] is the sky colour a wet surface mirrors (the weather's overcast or haze colour).
    """
    up = normals[:, 2]
    if weather == "clear":
        m = MATERIALS["clear"]
        sun = np.asarray(m["sun_direction"], np.float64)
        light = m["ambient"] + m["sun"] * np.maximum(normals @ (sun / np.linalg.norm(sun)), 0.0)
        return cloud.albedo * light[:, None]
    m = MATERIALS[weather]
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
        # a wet surface mirrors the sky it sees: the weather's haze colour when it has haze (the sky then
        # takes that colour, docs/design.md §7), else its overcast colour
        self.reflected = {w: np.asarray(r.fog_color if r.beta > 0 else MATERIALS[w].get("overcast_sky", (0, 0, 0)),
                                        np.float64) for w, r in self.renderers.items()}
        K = self.cameras[0].K
        jj, ii = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
        rays = np.stack([(jj - K[0, 2]) / FOCAL, (ii - K[1, 2]) / FOCAL, np.ones_like(jj)], -1)
        self._rays_cam = rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def frame(self, k: int) -> tuple[dict[str, Any], int]:
        """Frame ``k`` clear and under every truth weather.

        Returns
        -------
        frames : dict of str to WeatherFrame
            Per weather (``"clear"`` first), the renderer's frame (float32 image and alpha).
        gaussians : int
            Scene Gaussians of the frame.
        """
        cam = self.cameras[k]
        cloud = cloud_at(self.content, k)
        normals = gaussian_normals(cloud.quats, cloud.scales)
        means = cloud.means - self.shift
        rays_up = self._rays_cam @ cam.camera_to_world[2, :3]
        velocity = self._camera_velocity(self.centers, self.times, k)
        frames = {}
        for w, r in self.renderers.items():
            colors = shade_gaussians(w, cloud, normals, cam.center + self.shift, self.reflected[w])
            splats = self._arrays(*(np.asarray(a, np.float32) for a in (
                means, cloud.quats, cloud.scales, cloud.opacities, np.clip(colors, 0.0, 1.0))))
            sky = sky_colors(rays_up, w).astype(np.float32) if r.background_visible else None
            frames[w] = r.render(cam, float(self.times[k]), camera_velocity=velocity, gaussians=splats,
                                 background_image=sky)
        return frames, len(cloud)

    def record(self) -> dict[str, Any]:
        """What ``truth/weather.json`` holds: per truth weather its preset, seed, rate, visibility,
        the renderer's settings and the materials; for clear the materials and the sky."""
        truth = {}
        for w in TRUTH_WEATHERS:
            info = self.renderers[w].info()
            truth[w] = {"kind": w, "preset": info["preset"], "seed": self.content.spec.seed, "weather": info["weather"],
                        "rate_mm_h": info.get("particles", {}).get("spec", {}).get("rate_mm_h"),
                        "visibility_m": info["fog"]["visibility_m"], "renderer": info,
                        "materials": MATERIALS[w], "sky_mirrored_by_wet_surfaces": self.reflected[w]}
        truth["clear"] = {"materials": MATERIALS["clear"], "sky": "per-pixel gradient by ray elevation"}
        return truth
