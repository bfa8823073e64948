"""Light of the scenes with cast shadows: the sun and the sky of the clear frames, the overcast sky
of the weathers and their radiance as the camera sees it (docs/design.md §3); :mod:`.shadows` says
which Gaussians the sun reaches.

Light is added in linear light and encoded to sRGB once per Gaussian, so a shadow is a ratio of
irradiances in linear light. This is the truth's own model of the light, independent of the
weather editor's (``reference_model/appearance/``), which must infer from the pixels what this
module knows.
"""

from __future__ import annotations

import math

import numpy as np

from wcbench.scenes.synth.layout import Sun

__all__ = ["OVERCAST_HORIZON", "clear_irradiance", "clear_sky", "linear_to_srgb", "overcast_irradiance",
           "overcast_sky", "srgb_to_linear"]

#: The overcast sky's colour at the horizon (sRGB): a grey a little bluer than neutral, the truth's
#: own (the sky shows only without haze; the truth weathers all have haze, which replaces it).
OVERCAST_HORIZON = (0.70, 0.72, 0.76)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear light (IEC 61966-2-1), same shape, float64."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """Linear light to sRGB-encoded values (IEC 61966-2-1), clipped to [0, 1], same shape, float64."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


def clear_sky(rays_up: np.ndarray) -> np.ndarray:
    """[..., 3] the clear sky's colour (sRGB) by ray elevation (``rays_up``: its sine, [...]): a pale
    horizon turning deep blue within ~15 degrees."""
    e = np.clip(rays_up, 0.0, 1.0)[..., None]
    horizon, zenith = np.array([0.78, 0.84, 0.92]), np.array([0.30, 0.52, 0.88])
    return horizon + (zenith - horizon) * (1.0 - np.exp(-e / 0.22))


def overcast_sky(rays_up: np.ndarray, horizon: np.ndarray | tuple[float, float, float] = OVERCAST_HORIZON
                 ) -> np.ndarray:
    """[..., 3] the overcast sky's colour (sRGB) by ray elevation (``rays_up``: its sine, [...]).

    The CIE standard overcast sky's gradation (Moon & Spencer 1942): the luminance at elevation e
    is (1 + 2 sin e) times the horizon's, in linear light, from ``horizon`` (sRGB); below the
    horizon, the horizon's.
    """
    e = np.clip(rays_up, 0.0, 1.0)[..., None]
    return linear_to_srgb(srgb_to_linear(np.asarray(horizon)) * (1.0 + 2.0 * e))


def overcast_irradiance(up: np.ndarray, ground_albedo: float) -> np.ndarray:
    """[N] irradiance of surfaces under the overcast sky relative to a horizontal one's: the CIE
    overcast sky they see plus the ground's reflection, ``ground_albedo`` (1 - n_z) / 2.

    The CIE standard overcast sky has luminance L_z (1 + 2 cos theta) / 3 at zenith angle theta
    (Moon & Spencer 1942). A plane tilted by beta (cos beta = n_z) sees (1 + cos beta) / 2 of the
    uniform third, pi (1 + cos beta) / 2 of irradiance, and of the cosine part the integral of two
    clamped cosines over the sphere, (2 / 3) ((pi - beta) cos beta + sin beta); a horizontal plane
    gets 7 pi / 9 L_z in all, a vertical one 0.396 of that.

    Parameters
    ----------
    up : ndarray [N]
        Up components of the unit normals.
    ground_albedo : float
    """
    cos = np.clip(up, -1.0, 1.0)
    beta = np.arccos(cos)
    sky = (math.pi * (1.0 + cos) / 6.0 + (4.0 / 9.0) * ((math.pi - beta) * cos + np.sin(beta))) / (7.0 * math.pi / 9.0)
    return sky + ground_albedo * (1.0 - cos) / 2.0


def clear_irradiance(sun: Sun, normals: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """[N, 3] linear irradiance of surfaces in the clear frames (:class:`~.layout.Sun`).

    Parameters
    ----------
    sun : Sun
    normals : ndarray [N, 3]
        Unit normals (street coordinates, z up).
    visibility : ndarray [N]
        Share of each surface's sun rays that reach the sun (0: in cast shadow).

    Returns
    -------
    ndarray [N, 3]
        Sky light (1 + n_z) / 2 of ``sky_rgb``, ground light (1 - n_z) / 2 of the ground's
        irradiance times ``ground_albedo``, and the sun's ``sun_rgb`` max(n.s, 0) x visibility.
    """
    s = sun.direction()
    sky, direct = np.asarray(sun.sky_rgb), np.asarray(sun.sun_rgb)
    ground = sun.ground_albedo * (sky + sun.lit_ground_fraction * direct * s[2])
    up = normals[:, 2:3]
    facing = np.maximum(normals @ s, 0.0)[:, None]
    return sky * (1.0 + up) / 2.0 + ground * (1.0 - up) / 2.0 + direct * facing * visibility[:, None]
