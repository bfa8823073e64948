"""Physically based appearance models of weather on a surface (numpy, numba where it loads; no torch).

The built-in weather editor (:mod:`.editor`) turns a clear, sunlit frame into rain, snow or fog
with these models, pixel by pixel, from the surface geometry the scene's lidar gives
(:mod:`.surfaces`, :mod:`.maps`). Every model works in linear light (sRGB decoded, IEC 61966-2-1)
and its parameters live in the ``[appearance]`` tables of the weather presets
(``reference_model/weather/presets.toml``), each with its source (docs/design.md §7):

* **overcast relighting**: the frame's illumination, a clear sky with a sun of unknown azimuth, is
  divided out and that of a CIE overcast sky (Moon & Spencer 1942) put in, per surface normal;
* **wet surfaces**: the water-film albedo of Lekner & Dorf (1988), light trapped in the film by
  total internal reflection, plus a Fresnel reflection (Schlick 1994, water's f0 = 0.02);
* **snow cover**: on surfaces facing up and open to the sky, its amount from the accumulated
  liquid-water depth of the snow rate;
* **haze and fog**: Koschmieder's law, t = exp(-beta d), toward the airlight (:func:`apply_haze`),
  with the physics weather's own beta, colour and offset.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from wcbench.reference_model._numba_backend import load_numba_kernels

__all__ = [
    "LightModel",
    "apply_haze",
    "clear_irradiance",
    "fresnel_schlick",
    "linear_to_srgb",
    "overcast_gain",
    "overcast_irradiance",
    "smoothstep",
    "snow_cover",
    "srgb_to_linear",
    "sunlit_irradiance",
    "wet_albedo",
]


#: Values below which the sRGB conversions stay in numpy: a parallel kernel's launch costs more.
_KERNEL_MIN_VALUES = 4096


def _transfer_kernel(c: np.ndarray, name: str, fast: bool) -> Any:
    """The numba kernel ``name`` of :mod:`.shading_kernels` for ``c`` (float32), or None: not
    ``fast``, a small array, or numba unavailable."""
    if not fast or c.size < _KERNEL_MIN_VALUES:
        return None
    kernels = load_numba_kernels("appearance.shading_kernels")
    return None if kernels is None else getattr(kernels, name)


def srgb_to_linear(c: np.ndarray, *, fast: bool = True) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear light (IEC 61966-2-1), float32, same shape.

    ``fast``: in one pass with the numba kernel (:func:`.shading_kernels.srgb_to_linear_kernel`,
    within 5e-7 of numpy's) where it loads and the array is not small, else with numpy.
    """
    c = np.asarray(c, np.float32)
    kernel = _transfer_kernel(c, "srgb_to_linear_kernel", fast)
    if kernel is not None:
        out = np.empty(c.shape, np.float32)
        kernel(np.ascontiguousarray(c).reshape(-1), out.reshape(-1))
        return out
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray, *, fast: bool = True) -> np.ndarray:
    """Encode linear light to sRGB in [0, 1] (inputs clipped to [0, 1]), float32, same shape.

    ``fast``: as :func:`srgb_to_linear`'s (:func:`.shading_kernels.linear_to_srgb_kernel`).
    """
    c = np.asarray(c, np.float32)
    kernel = _transfer_kernel(c, "linear_to_srgb_kernel", fast)
    if kernel is not None:
        out = np.empty(c.shape, np.float32)
        kernel(np.ascontiguousarray(c).reshape(-1), out.reshape(-1))
        return out
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055).astype(np.float32)


def smoothstep(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """0 below ``lo``, 1 above ``hi``, 3u^2 - 2u^3 between (float32)."""
    u = np.clip((np.asarray(x, np.float32) - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


# --------------------------------------------------------------------------------------------
# Overcast relighting


@dataclass(frozen=True)
class LightModel:
    """The two skies of overcast relighting.

    Attributes
    ----------
    sun_elevation_deg : float
        Elevation of the sun the raw frames were taken under (degrees); its azimuth is unknown and
        averaged over.
    direct_to_diffuse : float
        Direct-normal sun irradiance over the clear sky's diffuse horizontal irradiance.
    ground_albedo : float
        Albedo of the ground lighting surfaces that face sideways or down (both skies).
    """

    sun_elevation_deg: float = 45.0
    direct_to_diffuse: float = 4.0
    ground_albedo: float = 0.2

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any]) -> LightModel:
        """From the ``[appearance.light]`` table of the presets (unknown keys ignored)."""
        keys = ("sun_elevation_deg", "direct_to_diffuse", "ground_albedo")
        return cls(**{k: float(table[k]) for k in keys if k in table})


@functools.lru_cache(maxsize=8)
def _irradiance_tables(model: LightModel, n: int = 65) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(normal elevation sines [n], clear-sky irradiance [n], overcast irradiance [n]) of a plane,
    relative to a horizontal plane, by numerical integration over the sky (float64)."""
    s_up = np.linspace(-1.0, 1.0, n)
    # sky directions: zenith angle theta in (0, pi/2), azimuth phi; the plane's normal has azimuth 0
    th = (np.arange(90) + 0.5) * (math.pi / 2) / 90
    ph = (np.arange(180) + 0.5) * (2 * math.pi) / 180
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    d_omega = np.sin(TH) * (math.pi / 2 / 90) * (2 * math.pi / 180)
    dirs = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1)
    cie = (1.0 + 2.0 * np.cos(TH)) / 3.0  # CIE standard overcast sky luminance over the zenith's
    sun_el = math.radians(model.sun_elevation_deg)
    clear, overcast = np.zeros(n), np.zeros(n)
    for i, s in enumerate(s_up):
        normal = np.array([math.sqrt(max(0.0, 1.0 - s * s)), 0.0, s])
        cos_i = np.clip(dirs @ normal, 0.0, None)
        overcast[i] = np.sum(cie * cos_i * d_omega)
        clear[i] = np.sum(cos_i * d_omega)  # a uniform diffuse clear sky
        # the sun at its elevation, azimuth averaged: E[max(n . s, 0)] over 360 azimuths
        az = np.linspace(0.0, 2 * math.pi, 360, endpoint=False)
        sun = np.stack([math.cos(sun_el) * np.cos(az), math.cos(sun_el) * np.sin(az),
                        np.full_like(az, math.sin(sun_el))], -1)
        clear[i] += model.direct_to_diffuse * math.pi * np.mean(np.clip(sun @ normal, 0.0, None))
    # light from the ground below the horizon: a Lambertian ground lit like a horizontal plane
    view_ground = (1.0 - s_up) / 2.0
    clear_h, overcast_h = clear[-1], overcast[-1]
    clear += model.ground_albedo * clear_h * view_ground
    overcast += model.ground_albedo * overcast_h * view_ground
    return s_up, clear / clear[-1], overcast / overcast[-1]


def overcast_gain(normal_up: np.ndarray, *, model: LightModel, exposure: float) -> np.ndarray:
    """Linear-light factor turning a clear, sunlit pixel into the same surface under an overcast sky.

    gain(n) = exposure * (E_overcast(n) / E_overcast(up)) / (E_clear(n) / E_clear(up)): the
    illumination ratio of the two skies on a plane whose normal has up-component ``normal_up``,
    normalised on a horizontal plane, where it is ``exposure`` (the camera's exposure of the
    overcast scene relative to the clear one's).

    Parameters
    ----------
    normal_up : ndarray [...]
        Up-component of the unit surface normal (sine of its elevation), in [-1, 1].
    model : LightModel
    exposure : float
        Linear gain on a horizontal surface (> 0).

    Returns
    -------
    ndarray [...] float32
    """
    if not exposure > 0:
        raise ValueError(f"exposure must be > 0, got {exposure}")
    s, clear, overcast = _irradiance_tables(model)
    # a plane lit by neither sky (facing down, no ground light) keeps its (black) pixel: ratio 1
    sky_ratio = np.divide(overcast, clear, out=np.ones_like(clear), where=clear > 1e-9)
    ratio = np.interp(np.clip(np.asarray(normal_up, np.float64), -1.0, 1.0), s, sky_ratio)
    return (exposure * ratio).astype(np.float32)


def clear_irradiance(normal_up: np.ndarray, *, model: LightModel) -> np.ndarray:
    """Irradiance of the clear sky with its sun (azimuth averaged) and the ground it lights, on a
    plane whose normal has up-component ``normal_up``, relative to a horizontal plane's (float32,
    same shape). A raw pixel in linear light divided by it stands for the surface's albedo, in
    the units of a camera exposed so that a white horizontal surface in the sun reads 1."""
    s, clear, _ = _irradiance_tables(model)
    return np.interp(np.clip(np.asarray(normal_up, np.float64), -1.0, 1.0), s, clear).astype(np.float32)


def sunlit_irradiance(normal: np.ndarray, visibility: np.ndarray, *, up: np.ndarray, sun: np.ndarray,
                      direct_to_diffuse: np.ndarray, ground_albedo: float) -> np.ndarray:
    """Per-channel irradiance of the clear sky and a sun of known direction, relative to a sunlit
    horizontal surface's (the image-formation model of shadow removal, Guo, Dai & Hoiem 2013: sky
    light everywhere, the sun's where it is visible).

    E_c(n, v) = [(1 + n_up) / 2 + rho (1 - n_up) / 2 (1 + r_c) + v k_c max(n . s, 0)] / (1 + r_c),
    with r_c the sun's direct light over the sky's on a horizontal surface
    (``direct_to_diffuse``), k_c = r_c / (up . s) the same per unit of the sun's cosine, a sky of
    uniform radiance (a plane sees (1 + n_up) / 2 of it) and ground of albedo rho lit by both.

    Parameters
    ----------
    normal : ndarray [..., 3]
        Unit surface normals (world).
    visibility : ndarray [...]
        The sun's visibility in [0, 1] (0 in a cast shadow).
    up, sun : ndarray [3]
        Unit up vector and unit vector toward the sun (above the horizon).
    direct_to_diffuse : ndarray [3]
        r_c per channel (>= 0).
    ground_albedo : float

    Returns
    -------
    ndarray [..., 3] float32
    """
    n = np.asarray(normal, np.float32)
    s = np.asarray(sun, np.float64)
    r = np.asarray(direct_to_diffuse, np.float32)
    n_up = n @ np.asarray(up, np.float32)
    cos_sun = np.clip(n @ s.astype(np.float32), 0.0, None)
    k = r / np.float32(max(float(s @ np.asarray(up, np.float64)), 1e-3))
    sky = ((1.0 + n_up) / 2.0)[..., None] + ground_albedo * ((1.0 - n_up) / 2.0)[..., None] * (1.0 + r)
    direct = (np.asarray(visibility, np.float32) * cos_sun)[..., None] * k
    return ((sky + direct) / (1.0 + r)).astype(np.float32)


def overcast_irradiance(normal_up: np.ndarray, *, model: LightModel) -> np.ndarray:
    """Irradiance of the overcast sky (and the ground it lights) on a plane whose normal has
    up-component ``normal_up``, relative to a horizontal plane's: 1 facing up, ~0.5 vertical
    (float32, same shape)."""
    s, _, overcast = _irradiance_tables(model)
    return np.interp(np.clip(np.asarray(normal_up, np.float64), -1.0, 1.0), s, overcast).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Wet surfaces


def _diffuse_fresnel(n: float) -> float:
    """Hemispherical (diffuse) Fresnel reflectance of light from air onto a medium of index ``n``,
    unpolarised, by integration over incidence angles (float)."""
    th = (np.arange(2000) + 0.5) * (math.pi / 2) / 2000
    ci = np.cos(th)
    st = np.sin(th) / n
    ct = np.sqrt(1.0 - st * st)
    rs = ((ci - n * ct) / (ci + n * ct)) ** 2
    rp = ((n * ci - ct) / (n * ci + ct)) ** 2
    r = 0.5 * (rs + rp)
    return float(np.sum(r * 2.0 * np.sin(th) * ci) * (math.pi / 2) / 2000)


def wet_albedo(albedo: np.ndarray, wetness: np.ndarray | float, *, water_index: float = 1.333) -> np.ndarray:
    """Linear albedo of a surface under a water film (Lekner & Dorf 1988), blended by ``wetness``.

    Light entering the film (1 - r_e) is reflected diffusely by the surface (A) and, going up,
    partly sent back down by the water-air interface (its diffuse internal reflectance
    r_i = 1 - (1 - r_e) / n^2), so A_wet = (1 - r_e)(1 - r_i) A / (1 - r_i A): about half the albedo of
    a dark surface such as asphalt, nearly all of a bright one. The film's own specular reflection
    is not included (:func:`fresnel_schlick` adds it).

    Parameters
    ----------
    albedo : ndarray [..., 3]
        Linear albedo (or linear pixel values standing for it) in [0, 1].
    wetness : ndarray [...] or float
        0 dry, 1 a full film.
    water_index : float
        Refractive index of water.

    Returns
    -------
    ndarray [..., 3] float32
    """
    a = np.clip(np.asarray(albedo, np.float32), 0.0, 1.0)
    r_e = _diffuse_fresnel(water_index)
    r_i = 1.0 - (1.0 - r_e) / water_index ** 2
    film = (1.0 - r_e) * (1.0 - r_i) * a / (1.0 - r_i * a)
    w = np.clip(np.asarray(wetness, np.float32), 0.0, 1.0)
    if w.ndim == a.ndim - 1:
        w = w[..., None]
    return (a + w * (film - a)).astype(np.float32)


def fresnel_schlick(cos_theta: np.ndarray, f0: float) -> np.ndarray:
    """Schlick's (1994) Fresnel reflectance f0 + (1 - f0)(1 - cos)^5 at incidence cosine ``cos_theta``
    (its absolute value), float32."""
    c = np.clip(np.abs(np.asarray(cos_theta, np.float32)), 0.0, 1.0)
    return (f0 + (1.0 - f0) * (1.0 - c) ** 5).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Snow


def snow_cover(normal_up: np.ndarray, exposure: np.ndarray, *, amount: float, facing_from: float,
               facing_full: float) -> np.ndarray:
    """Fraction of a surface under snow.

    Parameters
    ----------
    normal_up : ndarray [...]
        Up-component of the surface normal; snow settles where it exceeds ``facing_from`` and
        fully from ``facing_full`` (smoothstep between).
    exposure : ndarray [...]
        How open the surface is to the falling snow, in [0, 1] (0 under a roof, a tree or a car).
    amount : float
        Cover of an open horizontal surface, in [0, 1] (:meth:`AppearanceParams.snow_amount`).

    Returns
    -------
    ndarray [...] float32 in [0, 1]
    """
    facing = smoothstep(normal_up, facing_from, facing_full)
    return np.clip(amount * facing * np.clip(np.asarray(exposure, np.float32), 0.0, 1.0), 0.0, 1.0)


# --------------------------------------------------------------------------------------------
# Haze


def apply_haze(image: np.ndarray, distance_m: np.ndarray, *, beta: float, color: np.ndarray,
               offset_m: float = 0.0) -> np.ndarray:
    """Koschmieder's law: ``t I + (1 - t) color`` with t = exp(-beta max(d - offset, 0)).

    The same law, colour and offset as the physics renderer's fog and precipitation haze
    (:meth:`~wcbench.reference_model.weather.conditions.Weather.haze`), applied per pixel at the
    pixel's distance; an infinite distance (the sky) gives the airlight ``color``.

    Parameters
    ----------
    image : ndarray [H, W, 3]
        Display RGB in [0, 1] (the renderer fogs display values too).
    distance_m : ndarray [H, W]
        Distance along each pixel's ray (m); ``inf`` for the sky.
    beta : float
        Extinction (1/m); 0 returns ``image``.
    color : ndarray [3]
        Airlight, display RGB.
    offset_m : float
        Distance from which the attenuation starts (m).

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    if beta <= 0:
        return np.asarray(image, np.float32)
    d = np.maximum(np.asarray(distance_m, np.float64) - offset_m, 0.0)
    t = np.exp(-beta * d).astype(np.float32)[..., None]
    return (t * np.asarray(image, np.float32) + (1.0 - t) * np.asarray(color, np.float32)).astype(np.float32)
