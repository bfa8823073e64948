"""wcbench: weather editing of driving scenes, a reference implementation and a benchmark harness.

The evaluation side (scenes, method adapters, metrics, results) needs no torch; the reference
model (``wcbench.reference_model``) needs the ``[model]`` extra.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType
from typing import Any

__version__ = "0.1.0"

#: Top-level folders of the repository that install as subpackages of wcbench (pyproject.toml).
_FOLDERS = ("metrics", "reports", "reference_model")


class _CheckoutFinder(importlib.abc.MetaPathFinder):
    """Finds ``wcbench.metrics``, ``wcbench.reports`` and ``wcbench.reference_model`` in a source
    checkout, where they are the folders beside ``wcbench/`` rather than inside it.

    Python started in the repository root imports ``./wcbench`` before the installed package; without
    this a notebook, ``python -m wcbench`` or a Dask worker started there could not import the three.
    """

    def __init__(self, root: Path):
        self.root = root

    def find_spec(self, fullname: str, path: Any = None, target: ModuleType | None = None) -> ModuleSpec | None:
        prefix, _, name = fullname.partition(".")
        if prefix != __name__ or name not in _FOLDERS:
            return None
        folder = self.root / name
        return importlib.util.spec_from_file_location(fullname, folder / "__init__.py",
                                                      submodule_search_locations=[str(folder)])


def _install_checkout_finder() -> None:
    here = Path(__file__).resolve().parent
    root = here.parent
    if all((here / name).is_dir() for name in _FOLDERS):  # an installed package: the folders are inside
        return
    if not all((root / name / "__init__.py").is_file() for name in _FOLDERS):
        return
    if not any(isinstance(f, _CheckoutFinder) for f in sys.meta_path):
        sys.meta_path.append(_CheckoutFinder(root))  # last: an editable install's own finder goes first


_install_checkout_finder()
