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
        "sim-editor": "wcbench.methods.sim_editor:SimEditorMethod",
        "physical-editor": "wcbench.methods.physical_editor:PhysicalEditorMethod",
        "lidar_init": "wcbench.methods.lidar_init:LidarInitMethod",
        "weathercity": "wcbench.methods.weathercity:WeatherCityMethod",
        **{name: f"wcbench.methods.readers:{name.replace('-', '_')}" for name in _READERS},
    },
)


#: What to install for a method whose code needs a missing package.
INSTALL_HINT = 'pip install "wcbench[model]"'


class MethodUnavailableError(InputError):
    """A registered method whose code needs a package that is not installed (``package``)."""

    def __init__(self, name: str, package: str):
        super().__init__(f"method {name!r} needs the package {package!r}, which is not installed "
                         f"(the reference model's methods come with the [model] extra: {INSTALL_HINT})")
        self.package = package


def _factory(name: str) -> Any:
    try:
        return METHODS.get(name)
    except ModuleNotFoundError as exc:
        raise MethodUnavailableError(name, exc.name or str(exc)) from None


def method_options(name: str) -> list[str]:
    """The options the method registered as ``name`` takes (keyword arguments of its factory).

    Raises
    ------
    UnknownNameError, MethodUnavailableError
    """
    params = inspect.signature(_factory(name)).parameters
    return [p for p, v in params.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)]


def get_method(name: str, **options: Any) -> Method:
    """Instantiate the method registered as ``name`` with ``options``.

    Raises
    ------
    UnknownNameError
        With close-name suggestions.
    InputError
        If the method does not take one of ``options`` (the message lists the ones it takes).
    MethodUnavailableError
        If its code needs a package that is not installed.
    """
    factory = _factory(name)
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
    "METHODS", "WEATHERS", "Method", "MethodInfo", "MethodUnavailableError", "RunnableMethod", "get_method",
    "is_runnable", "method_options",
]
