"""How surfaces look in the scenes with cast shadows, clear and under each truth weather, in linear
light (docs/design.md §3).

Where a number is a property of a material under a weather (where snow settles and its albedo,
how wet rain makes a surface, water's Fresnel reflectance, the sheen of wet asphalt), it comes from
the one physics table, the ``[appearance.*]`` tables of ``reference_model/weather/presets.toml``
that the weather editor reads too (:func:`physical_materials`). What the truth knows and an editor
must infer (the sun, the sky, the light levels, each surface's albedo) is the truth's own
(:mod:`.light`), so the truth stays an independent model of the same physics. v1's scenes keep
their own, frozen, numbers (:data:`~.layout.MATERIALS_V1`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from wcbench.reference_model.weather.conditions import load_presets
from wcbench.scenes.synth.geometry import Cloud
from wcbench.scenes.synth.layout import Sun
from wcbench.scenes.synth.light import clear_irradiance, linear_to_srgb, overcast_irradiance, srgb_to_linear

__all__ = ["GLASS_F0", "OVERCAST_LIGHT", "Surfaces", "physical_materials", "shade_physical"]

#: Light on a horizontal surface under each overcast weather, relative to the sunlit clear one (linear):
#: v1's ratios on a horizontal surface (rain 0.68, snow 0.82, fog 0.78 of a sunlit 0.96, on sRGB
#: values) in linear light. The camera's exposure is set for the scene, so overcast frames are
#: about as bright as they were in v1.
OVERCAST_LIGHT = {"rain": 0.45, "snow": 0.70, "fog": 0.62}
#: Fresnel reflectance of window glass at normal incidence: ((1.5 - 1) / (1.5 + 1))^2 for n = 1.5.
GLASS_F0 = 0.04
#: Wet factors of the road (linear albedo of the fully wet surface over the dry one): a water film
#: about halves asphalt's albedo (Lekner & Dorf 1988 give 0.5 for an albedo of 0.06), still water
#: in puddles hides more of it.
_ASPHALT_WET, _PUDDLE_WET = 0.55, 0.3


def physical_materials() -> dict[str, dict[str, Any]]:
    """The materials of the truth weathers: the shared appearance tables where they say how a
    surface behaves, the truth's own light levels.

    Returns
    -------
    dict
        Per weather (``rain``, ``snow``, ``fog``) a table of JSON numbers: ``light``
        (:data:`OVERCAST_LIGHT`); rain: ``fresnel_f0`` (water), ``wetness_horizontal`` and
        ``wetness_vertical`` (film fraction by facing), ``asphalt_wet``, ``puddle_wet`` (wet albedo
        factors), ``asphalt_sheen`` and ``puddle_sheen`` (mirror share of the Fresnel
        reflection); snow: ``facing_from``, ``facing_full`` (normal-up range where it settles),
        ``snow_albedo`` (linear), ``damp`` (film fraction of the bare surfaces), ``mover_share``
        (the cover a moving car holds, as a share of a parked one's); fog: ``damp``.
    """
    a = load_presets()["appearance"]
    rain, snow, fog = a["rain"], a["snow"], a["fog"]
    return {
        "rain": {"light": OVERCAST_LIGHT["rain"], "fresnel_f0": rain["fresnel_f0"],
                 "wetness_horizontal": rain["wetness_horizontal"], "wetness_vertical": rain["wetness_vertical"],
                 "asphalt_wet": _ASPHALT_WET, "puddle_wet": _PUDDLE_WET, "asphalt_sheen": rain["sheen_road"],
                 "puddle_sheen": rain["sheen_puddle"]},
        "snow": {"light": OVERCAST_LIGHT["snow"], "facing_from": snow["facing_from"],
                 "facing_full": snow["facing_full"], "snow_albedo": [float(snow["snow_albedo"])] * 3,
                 "damp": snow["damp"], "mover_share": snow["mover_share"]},
        "fog": {"light": OVERCAST_LIGHT["fog"], "damp": fog["damp"]},
    }


def _fresnel(f0: float, cos: np.ndarray) -> np.ndarray:
    """Schlick's approximation of the Fresnel reflectance at incidence cosine ``cos`` [N]."""
    return f0 + (1.0 - f0) * (1.0 - cos) ** 5


@dataclass
class Surfaces:
    """What shading a frame's Gaussians needs, whatever the weather (computed once per frame).

    Attributes
    ----------
    cloud : Cloud
        The Gaussians (street coordinates; sRGB albedo and the material columns).
    albedo : ndarray [N, 3]
        Their albedo in linear light.
    up : ndarray [N]
        Up component of their unit normals.
    normals : ndarray [N, 3]
        Unit normals.
    cos : ndarray [N]
        |cosine| between the view ray and the normal.
    mirror_up : ndarray [N]
        Up component of the view ray mirrored about the normal: the sine of the elevation of the
        sky a mirror there shows.
    overcast : ndarray [N]
        Irradiance under the overcast sky relative to a horizontal surface's
        (:func:`~.light.overcast_irradiance`).
    """

    cloud: Cloud
    albedo: np.ndarray
    up: np.ndarray
    normals: np.ndarray
    cos: np.ndarray
    mirror_up: np.ndarray
    overcast: np.ndarray

    @staticmethod
    def of(cloud: Cloud, normals: np.ndarray, eye: np.ndarray, sun: Sun, albedo: np.ndarray | None = None
           ) -> Surfaces:
        """The surfaces of ``cloud`` (normals [N, 3]) seen from ``eye`` [3] (m) under ``sun``'s sky
        (its ground albedo reflects the overcast light too); ``albedo``: their linear albedo when the
        caller has it."""
        view = cloud.means - eye
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-9)
        along = np.sum(view * normals, axis=1)
        up = normals[:, 2]
        return Surfaces(cloud, srgb_to_linear(cloud.albedo) if albedo is None else albedo, up, normals,
                        np.abs(along), view[:, 2] - 2.0 * along * up, overcast_irradiance(up, sun.ground_albedo))


def shade_physical(weather: str, surfaces: Surfaces, *, sun: Sun, visibility: np.ndarray | None, sky: Any,
                   materials: dict[str, dict[str, Any]], mirror_windows: bool) -> np.ndarray:
    """[N, 3] sRGB colours of the Gaussians under ``weather`` (docs/design.md §3).

    Parameters
    ----------
    weather : {"clear", "rain", "snow", "fog"}
    surfaces : Surfaces
        The frame's Gaussians as seen from its camera.
    sun : Sun
        The clear frames' sun and sky.
    visibility : ndarray [N] or None
        Share of the sun each Gaussian sees (clear only).
    sky : callable or ndarray [3] or [N, 3]
        The sRGB a mirror reflects: ``sky(rays_up [N]) -> [N, 3]`` by the sine of the reflected
        ray's elevation (the clear or the overcast sky), one colour (the haze's), or one per
        Gaussian (what each mirror sees, :mod:`.mirrors`).
    materials : dict
        :func:`physical_materials`.
    mirror_windows : bool
        Window glass (the Cloud's ``gloss``) mirrors the sky with glass's Fresnel reflectance.

    Returns
    -------
    ndarray [N, 3]
        In [0, 1].
    """
    cloud, albedo, up, cos = surfaces.cloud, surfaces.albedo, surfaces.up, surfaces.cos
    glass = mirror_windows and bool(np.any(cloud.gloss > 0))
    shiny = weather == "rain" or glass
    # the sky a mirror sees, only where something mirrors
    sky_seen = None
    if shiny:
        sky_seen = srgb_to_linear(sky(surfaces.mirror_up) if callable(sky) else np.asarray(sky))
    if weather == "clear":
        assert visibility is not None
        color = albedo * clear_irradiance(sun, surfaces.normals, visibility)
    else:
        m = materials[weather]
        light = (m["light"] * surfaces.overcast)[:, None]  # no sun: no shadows
        if weather == "rain":
            assert sky_seen is not None
            # a water film on every surface, thinner on steep ones that drain
            film = m["wetness_vertical"] + (m["wetness_horizontal"] - m["wetness_vertical"]) * np.clip(up, 0.0, 1.0)
            wet = 1.0 - film * (1.0 - cloud.wet)
            fresnel = (_fresnel(m["fresnel_f0"], cos) * cloud.sheen)[:, None]
            color = albedo * wet[:, None] * light * (1.0 - fresnel) + fresnel * sky_seen
        elif weather == "snow":
            lo, hi = m["facing_from"], m["facing_full"]
            facing = np.clip((up - lo) / (hi - lo), 0.0, 1.0)
            cover = (cloud.snow * facing * facing * (3.0 - 2.0 * facing))[:, None]  # smoothstep
            damp = (1.0 - m["damp"] * (1.0 - cloud.wet))[:, None]  # what snow leaves bare is damp
            color = light * ((1.0 - cover) * albedo * damp + cover * np.asarray(m["snow_albedo"]))
        else:
            color = albedo * light * (1.0 - m["damp"] * (1.0 - cloud.wet))[:, None]
    if glass:
        assert sky_seen is not None
        mirror = (_fresnel(GLASS_F0, cos) * cloud.gloss)[:, None]
        color = color * (1.0 - mirror) + mirror * sky_seen
    return linear_to_srgb(color)
