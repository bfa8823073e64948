"""The torch-free environments (tox py310/py312/py313; docs/design.md §1) collect every test module:
a module that needs torch, transformers, Dask or gsplat skips itself (``pytest.importorskip``)
instead of failing collection, which would stop the whole env. This runs the collection here with
those packages hidden, so a forgotten guard fails in the fast suite rather than only in CI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent

#: The packages the torch-free tox envs do not install (tox.ini: their extras are ``test`` only).
HIDDEN = ("torch", "transformers", "distributed", "dask", "gsplat", "onnx")

# A finder that reports the packages missing (ModuleNotFoundError, as a real absence does) rather
# than putting None into sys.modules, which libraries that probe sys.modules for torch (scipy's
# array API layer) would trip over.
_COLLECT = """
import sys
import pytest

HIDDEN = {hidden!r}

class _Hidden:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in HIDDEN:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None

sys.meta_path.insert(0, _Hidden())
sys.exit(pytest.main(["--collect-only", "-q", "-p", "no:cacheprovider", {tests!r}]))
"""


def test_every_test_module_collects_without_the_model_packages() -> None:
    code = _COLLECT.format(hidden=HIDDEN, tests=str(TESTS))
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=TESTS.parent
    )
    errors = [line for line in proc.stdout.splitlines() if line.startswith("ERROR")]
    assert proc.returncode == 0 and not errors, (
        "collection fails without torch/transformers/Dask/gsplat (a module lacks "
        f"pytest.importorskip):\n{proc.stdout[-3000:]}\n{proc.stderr[-2000:]}"
    )
    # The guard itself works: the model's own tests are skipped, not collected.
    assert "could not import 'torch'" in proc.stdout
