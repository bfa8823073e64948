"""Method adapters: runnable methods and output readers, resolved lazily by name.

Built-ins are listed here as import strings; packages add their own through the entry-point
group ``wcbench.methods`` (a callable returning a :class:`~wcbench.methods.protocol.Method`).
Method names use one separator, the hyphen (``lidar-init``, ``sim-editor``, ``qwen-image``); the
old spellings (``lidar_init``, ``sim_editor``...) are deprecated aliases (:data:`METHOD_ALIASES`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.options import Option, validate_options
from wcbench.core.registry import LazyRegistry
from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import Method, MethodInfo, RunnableMethod

#: Deprecated method names (one release): the underscore spellings of the hyphenated names.
METHOD_ALIASES = {"lidar_init": "lidar-init", "sim_editor": "sim-editor", "physical_editor": "physical-editor",
                  "qwen_image": "qwen-image", "weathercity_release": "weathercity-release"}

_READERS = ("folder", "controlnet", "turboedit", "fresco", "qwen-image", "climatenerf", "weathercity-release")

METHODS: LazyRegistry = LazyRegistry(
    "method",
    {
        "identity": "wcbench.methods.identity:IdentityMethod",
        "filter2d": "wcbench.methods.filter2d:Filter2DMethod",
        "sim-editor": "wcbench.methods.sim_editor:SimEditorMethod",
        "physical-editor": "wcbench.methods.physical_editor:PhysicalEditorMethod",
        "lidar-init": "wcbench.methods.lidar_init:LidarInitMethod",
        "weathercity": "wcbench.methods.weathercity:WeatherCityMethod",
        **{name: f"wcbench.methods.readers:{name.replace('-', '_')}" for name in _READERS},
    },
    aliases=METHOD_ALIASES,
)


def canonical_method_name(name: str) -> str:
    """The current name of method ``name``: itself, or the hyphenated name of an old underscore
    spelling (``lidar_init`` -> ``lidar-init``; no warning: results written under an old name are
    read as the method's)."""
    return METHODS.canonical(name, warn=False)


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


def _any_value(value: Any) -> Any:
    return value


def method_schema(name: str) -> dict[str, Option]:
    """The declared options of the method registered as ``name``: its factory's ``OPTIONS`` (type,
    range, default, meaning of each keyword option). A factory that declares none (a plugin's) has
    its keyword parameters, each taking any value.

    Raises
    ------
    UnknownNameError, MethodUnavailableError
    """
    factory = _factory(METHODS.canonical(name))
    declared = getattr(factory, "OPTIONS", None)
    if declared is not None:
        return dict(declared)
    params = inspect.signature(factory).parameters
    return {p: Option(p, "custom", "an undeclared option of the method's factory", check=_any_value,
                      allowed="any value")
            for p, v in params.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)}


def method_options(name: str) -> list[str]:
    """The names of the options the method registered as ``name`` takes (:func:`method_schema`).

    Raises
    ------
    UnknownNameError, MethodUnavailableError
    """
    return list(method_schema(name))


def renamed_method_options(name: str) -> dict[str, str]:
    """Old name -> new name of each renamed option of method ``name`` (accepted for one release).

    Raises
    ------
    UnknownNameError, MethodUnavailableError
    """
    return {key: opt.renamed_to for key, opt in method_schema(name).items() if opt.renamed_to}


def validate_method_options(name: str, options: dict[str, Any], *,
                            deprecated: Callable[[str, str], None] | None = None) -> dict[str, Any]:
    """Check ``options`` against the declared options of method ``name`` before anything is built or
    written; return them as the constructor takes them (lists of numbers as tuples, an option given
    by its old name under its new one).

    Parameters
    ----------
    name : str
    options : dict
    deprecated : callable, optional
        Called as ``deprecated(old, new)`` for an option given by its old name; default a
        :class:`DeprecationWarning` (see :func:`wcbench.core.options.validate_options`).

    Raises
    ------
    OptionError
        One line naming the first unknown option or bad value and what is allowed
        (``physical-editor option size=5: expected a list of 2 integers >= 1 or null``), or an
        option given by both its old and its new name.
    UnknownNameError, MethodUnavailableError
    """
    name = METHODS.canonical(name, warn=False)
    return validate_options(method_schema(name), options, prefix=f"{name} option ", owner=f"method {name!r}",
                            deprecated=deprecated)


def get_method(name: str, **options: Any) -> Method:
    """Instantiate the method registered as ``name`` with ``options``.

    Raises
    ------
    UnknownNameError
        With close-name suggestions.
    OptionError
        If the method does not take one of ``options``, or a value is not one its declared option
        allows (:func:`validate_method_options`).

    Warns
    -----
    DeprecationWarning
        When ``name`` is an old spelling (``lidar_init``); the method of the current name is returned.
        When an option is given by its old name (``weathers``, now ``physics``); it is passed on
        under the new one.
    MethodUnavailableError
        If its code needs a package that is not installed.
    """
    name = METHODS.canonical(name)
    factory = _factory(name)
    method = factory(**validate_method_options(name, options))
    if not isinstance(method, Method):
        raise TypeError(f"method {name!r} does not implement the Method protocol")
    return method


def is_runnable(method: Method) -> bool:
    """Whether wcbench can run ``method`` itself (it has ``render``)."""
    return isinstance(method, RunnableMethod) and method.info.kind == "runnable"


__all__ = [
    "METHODS", "METHOD_ALIASES", "WEATHERS", "Method", "MethodInfo", "MethodUnavailableError", "RunnableMethod",
    "canonical_method_name", "get_method", "is_runnable", "method_options", "method_schema",
    "renamed_method_options", "validate_method_options",
]
