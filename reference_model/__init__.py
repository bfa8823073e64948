"""The reference WeatherCity model: a differentiable CPU Gaussian rasterizer and what builds on it.

Public API (imported lazily, so ``import wcbench.reference_model`` needs neither torch nor numba and
compiles nothing):

* :func:`rasterize` and its output :class:`RenderOutput` (package :mod:`.raster`);
* :func:`rasterize_torch` and :func:`project_torch`, the pure-torch twin (:mod:`.raster.torch_twin`);
* :data:`EPS2D`, the 0.3 px^2 screen-space dilation every rendered Gaussian gets;
* weather (package :mod:`.weather`): :class:`Weather`, :class:`WeatherRenderer`,
  particles (:class:`Wind`, :class:`ParticleField`), fog;
* the scene graph (package :mod:`.scene_graph`): :class:`GaussianCloud`, :class:`SceneGaussians`
  and the lidar initialisation :func:`init_scene_from_lidar`.

The library imports only the core layer (``wcbench.core``); scenes reach it as duck-typed objects
(see :mod:`.scene_graph.lidar_init`), and the runnable methods built on it live in
``wcbench.methods``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from wcbench.reference_model.raster.common import EPS2D, RenderOutput
    from wcbench.reference_model.raster.rasterizer import numba_available, rasterize
    from wcbench.reference_model.raster.torch_twin import project_torch, rasterize_torch
    from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
    from wcbench.reference_model.scene_graph.lidar_init import init_from_lidar, init_scene_from_lidar
    from wcbench.reference_model.scene_graph.nodes import SceneGaussians
    from wcbench.reference_model.weather.conditions import Weather, load_presets
    from wcbench.reference_model.weather.fog import (
        compose_exact,
        density_from_visibility,
        fog_postprocess,
        gaussian_transmittance,
    )
    from wcbench.reference_model.weather.particle_spec import ParticleGaussians, ParticleSpec, Wind
    from wcbench.reference_model.weather.particles import ParticleField
    from wcbench.reference_model.weather.renderer import WeatherFrame, WeatherRenderer

# Public name -> module holding it. Package and module names differ from the public names
# (``raster`` vs ``rasterize``), so importing a submodule never shadows a function here.
_LAZY = {
    "rasterize": "raster.rasterizer",
    "numba_available": "raster.rasterizer",
    "RenderOutput": "raster.common",
    "EPS2D": "raster.common",
    "rasterize_torch": "raster.torch_twin",
    "project_torch": "raster.torch_twin",
    "compose_exact": "weather.fog",
    "density_from_visibility": "weather.fog",
    "fog_postprocess": "weather.fog",
    "gaussian_transmittance": "weather.fog",
    "GaussianCloud": "scene_graph.gaussians",
    "SceneGaussians": "scene_graph.nodes",
    "init_from_lidar": "scene_graph.lidar_init",
    "init_scene_from_lidar": "scene_graph.lidar_init",
    "ParticleField": "weather.particles",
    "ParticleGaussians": "weather.particle_spec",
    "ParticleSpec": "weather.particle_spec",
    "Wind": "weather.particle_spec",
    "Weather": "weather.conditions",
    "WeatherFrame": "weather.renderer",
    "WeatherRenderer": "weather.renderer",
    "load_presets": "weather.conditions",
}

__all__ = [
    "EPS2D",
    "GaussianCloud",
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
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
