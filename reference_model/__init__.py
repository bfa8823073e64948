"""The reference WeatherCity model: a differentiable CPU Gaussian rasterizer and what builds on it.

Public API (imported lazily, so ``import wcbench.reference_model`` needs neither torch nor numba and
compiles nothing):

* :func:`rasterize` and its output :class:`RenderOutput` (module :mod:`.raster`);
* :func:`rasterize_torch` and :func:`project_torch`, the pure-torch twin (module :mod:`._raster_torch`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._raster_common import RenderOutput
    from ._raster_torch import project_torch, rasterize_torch
    from .raster import numba_available, rasterize

# Public name -> module holding it. The API module is ``raster`` (not ``rasterize``) so that the
# submodule can never shadow the function as an attribute of this package.
_LAZY = {
    "rasterize": ".raster",
    "numba_available": ".raster",
    "RenderOutput": "._raster_common",
    "rasterize_torch": "._raster_torch",
    "project_torch": "._raster_torch",
}

__all__ = ["RenderOutput", "numba_available", "project_torch", "rasterize", "rasterize_torch"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
