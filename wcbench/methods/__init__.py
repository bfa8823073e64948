"""Method adapters: runnable methods and output readers, resolved lazily by name.

Built-ins are listed here as import strings; packages add their own through the entry-point
group ``wcbench.methods`` (a callable returning a :class:`~wcbench.methods.protocol.Method`).
"""

from __future__ import annotations

from wcbench.methods.protocol import WEATHERS, Method, MethodInfo, RunnableMethod
from wcbench.registry import LazyRegistry

_READERS = ("folder", "controlnet", "turboedit", "fresco", "qwen-image", "climatenerf", "weathercity")

METHODS: LazyRegistry = LazyRegistry(
    "method",
    {
        "identity": "wcbench.methods.identity:IdentityMethod",
        "filter2d": "wcbench.methods.filter2d:Filter2DMethod",
        "lidar_init": "wcbench.reference_model.lidar_init_method:LidarInitMethod",
        **{name: f"wcbench.methods.readers:{name.replace('-', '_')}" for name in _READERS},
    },
)


def get_method(name: str) -> Method:
    """Instantiate the method registered as ``name``.

    Raises
    ------
    UnknownNameError
        With close-name suggestions.
    """
    method = METHODS.get(name)()
    if not isinstance(method, Method):
        raise TypeError(f"method {name!r} does not implement the Method protocol")
    return method


def is_runnable(method: Method) -> bool:
    """Whether wcbench can run ``method`` itself (it has ``render``)."""
    return isinstance(method, RunnableMethod) and method.info.kind == "runnable"


__all__ = ["METHODS", "WEATHERS", "Method", "MethodInfo", "RunnableMethod", "get_method", "is_runnable"]
