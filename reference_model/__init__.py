"""The reference WeatherCity model: a differentiable CPU Gaussian rasterizer and what builds on it.

Public API (imported lazily, so ``import wcbench.reference_model`` needs neither torch nor numba and
compiles nothing):

* :func:`rasterize` and its output :class:`RenderOutput` (module :mod:`.raster`);
* :func:`rasterize_torch` and :func:`project_torch`, the pure-torch twin (module :mod:`._raster_torch`);
* :data:`EPS2D`, the 0.3 px^2 screen-space dilation every rendered Gaussian gets;
* weather: :class:`Weather`, :class:`WeatherRenderer`, :func:`render_weather` (module :mod:`.weather`),
  particles (:class:`Wind`, :class:`ParticleField`, :mod:`.particles`), fog (:mod:`.fog`);
* the untrained scene: :class:`GaussianCloud`, :func:`init_scene_from_lidar` (module :mod:`.lidar_init`)
  and the runnable method :class:`LidarInitMethod`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._raster_common import EPS2D, RenderOutput
    from ._raster_torch import project_torch, rasterize_torch
    from .fog import compose_exact, density_from_visibility, fog_postprocess, gaussian_transmittance
    from .lidar_init import GaussianCloud, SceneGaussians, init_from_lidar, init_scene_from_lidar
    from .lidar_init_method import LidarInitMethod
    from .particles import ParticleField, ParticleGaussians, ParticleSpec, Wind
    from .raster import numba_available, rasterize
    from .weather import Weather, WeatherFrame, WeatherRenderer, load_presets, render_weather

# Public name -> module holding it. The API module is ``raster`` (not ``rasterize``) so that the
# submodule can never shadow the function as an attribute of this package.
_LAZY = {
    "rasterize": ".raster",
    "numba_available": ".raster",
    "RenderOutput": "._raster_common",
    "EPS2D": "._raster_common",
    "rasterize_torch": "._raster_torch",
    "project_torch": "._raster_torch",
    "compose_exact": ".fog",
    "density_from_visibility": ".fog",
    "fog_postprocess": ".fog",
    "gaussian_transmittance": ".fog",
    "GaussianCloud": ".lidar_init",
    "SceneGaussians": ".lidar_init",
    "init_from_lidar": ".lidar_init",
    "init_scene_from_lidar": ".lidar_init",
    "LidarInitMethod": ".lidar_init_method",
    "ParticleField": ".particles",
    "ParticleGaussians": ".particles",
    "ParticleSpec": ".particles",
    "Wind": ".particles",
    "Weather": ".weather",
    "WeatherFrame": ".weather",
    "WeatherRenderer": ".weather",
    "load_presets": ".weather",
    "render_weather": ".weather",
}

__all__ = [
    "EPS2D",
    "GaussianCloud",
    "LidarInitMethod",
    "ParticleField",
    "ParticleGaussians",
    "ParticleSpec",
    "RenderOutput",
    "SceneGaussians",
    "Weather",
    "WeatherFrame",
    "WeatherRenderer",
    "Wind",
    "compose_exact",
    "density_from_visibility",
    "fog_postprocess",
    "gaussian_transmittance",
    "init_from_lidar",
    "init_scene_from_lidar",
    "load_presets",
    "numba_available",
    "project_torch",
    "rasterize",
    "rasterize_torch",
    "render_weather",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
