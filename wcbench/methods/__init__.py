"""Method adapters: runnable methods and output readers, resolved lazily by name.

Built-ins are listed here as import strings; packages add their own through the entry-point
group ``wcbench.methods`` (a callable returning a :class:`~wcbench.methods.protocol.Method`).
"""

from __future__ import annotations

import inspect
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.registry import LazyRegistry
from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import Method, MethodInfo, RunnableMethod

_READERS = ("folder", "controlnet", "turboedit", "fresco", "qwen-image", "climatenerf", "weathercity-release")

METHODS: LazyRegistry = LazyRegistry(
    "method",
    {
        "identity": "wcbench.methods.identity:IdentityMethod",
        "filter2d": "wcbench.methods.filter2d:Filter2DMethod",
        "lidar_init": "wcbench.methods.lidar_init:LidarInitMethod",
        "weathercity": "wcbench.methods.weathercity:WeatherCityMethod",
        **{name: f"wcbench.methods.readers:{name.replace('-', '_')}" for name in _READERS},
    },
)


def method_options(name: str) -> list[str]:
    """The options the method registered as ``name`` takes (keyword arguments of its factory)."""
    params = inspect.signature(METHODS.get(name)).parameters
    return [p for p, v in params.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)]


def get_method(name: str, **options: Any) -> Method:
    """Instantiate the method registered as ``name`` with ``options``.

    Raises
    ------
    UnknownNameError
        With close-name suggestions.
    InputError
        If the method does not take one of ``options`` (the message lists the ones it takes).
    """
    factory = METHODS.get(name)
    unknown = sorted(set(options) - set(method_options(name)))
    if unknown:
        takes = ", ".join(method_options(name)) or "none"
        raise InputError(f"method {name!r} takes no option {', '.join(unknown)} (it takes: {takes})")
    method = factory(**options)
    if not isinstance(method, Method):
        raise TypeError(f"method {name!r} does not implement the Method protocol")
    return method


def is_runnable(method: Method) -> bool:
    """Whether wcbench can run ``method`` itself (it has ``render``)."""
    return isinstance(method, RunnableMethod) and method.info.kind == "runnable"


__all__ = [
    "METHODS", "WEATHERS", "Method", "MethodInfo", "RunnableMethod", "get_method", "is_runnable", "method_options",
]
