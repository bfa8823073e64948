"""Optional numba kernels: import a kernel module once, or remember why it could not be.

The rasterizer, the particle field and the fog each keep their compiled kernels in a module of
their own (``raster.kernels``, ``weather.particle_kernels``, ``weather.fog_kernels``) beside a pure
numpy/torch reference. Without numba (or with a broken LLVM) the reference runs instead.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["load_numba_kernels", "numba_error"]

_loaded: dict[str, ModuleType] = {}
_failed: dict[str, str] = {}


def load_numba_kernels(name: str) -> ModuleType | None:
    """The kernel module ``wcbench.reference_model.<name>``, or ``None`` if it cannot be imported.

    Parameters
    ----------
    name : str
        Module path inside this package, e.g. ``"weather.particle_kernels"``.

    Returns
    -------
    ModuleType or None
        Imported once; a failure is remembered (see :func:`numba_error`) and not retried.
    """
    if name in _loaded:
        return _loaded[name]
    if name in _failed:
        return None
    try:
        module = importlib.import_module(f".{name}", __package__)
    except Exception as exc:  # any import-time failure (numba missing, LLVM error) means "fall back"
        _failed[name] = f"{type(exc).__name__}: {exc}"
        return None
    _loaded[name] = module
    return module


def numba_error(name: str) -> str | None:
    """Why :func:`load_numba_kernels` returned ``None`` for ``name`` (``None`` if it did not)."""
    return _failed.get(name)
