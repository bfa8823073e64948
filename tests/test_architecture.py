"""The layers of docs/architecture.md hold: imports point downward only, with no cycle anywhere.

The contracts live in pyproject.toml ([tool.importlinter]) and run as ``lint-imports`` in the lint
env; here they run on a copy of the package laid out as the wheel ships it (an editable install
maps metrics/, reports/ and reference_model/ from the top of the repository), once as they are and
once with a deliberate upward import that must break them.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from paths import REPO

pytest.importorskip("importlinter", reason="import-linter is in the test extra")

PACKAGES = ("wcbench", "wcbench.metrics", "wcbench.reference_model", "wcbench.reports")


@pytest.fixture(scope="module")
def package_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the installed package in its shipped layout; the folder to put on sys.path."""
    root = tmp_path_factory.mktemp("package")
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        assert spec is not None and spec.submodule_search_locations, name
        src = Path(next(iter(spec.submodule_search_locations)))
        shutil.copytree(src, root.joinpath(*name.split(".")), dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _lint_imports(tree: Path) -> subprocess.CompletedProcess[str]:
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run(
        [sys.executable, "-c", code, "--config", str(REPO / "pyproject.toml"), "--no-cache"],
        capture_output=True, text=True, env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"}, cwd=tree,
        check=False,
    )


def test_layer_contracts_hold(package_tree: Path) -> None:
    proc = _lint_imports(package_tree)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Contracts: 4 kept, 0 broken." in proc.stdout


def test_an_upward_import_breaks_the_contracts(tmp_path: Path, package_tree: Path) -> None:
    tree = tmp_path / "package"
    shutil.copytree(package_tree, tree)
    errors = tree / "wcbench" / "core" / "errors.py"
    errors.write_text(errors.read_text() + "\nfrom wcbench import evaluation  # deliberate upward import\n")
    proc = _lint_imports(tree)
    assert proc.returncode != 0
    assert "BROKEN" in proc.stdout and "wcbench.core.errors -> wcbench.evaluation" in proc.stdout


def test_no_module_level_import_cycle(package_tree: Path) -> None:
    # Tarjan's strongly connected components over every import grimp sees, function-level ones
    # included (only TYPE_CHECKING imports are left out): any component of two modules is a cycle
    code = """
import json, sys
import grimp
g = grimp.build_graph("wcbench", exclude_type_checking_imports=True)
sys.setrecursionlimit(100000)
index, low, stack, on, out = {}, {}, [], set(), []
def visit(v):
    index[v] = low[v] = len(index); stack.append(v); on.add(v)
    for w in sorted(g.find_modules_directly_imported_by(v)):
        if w not in index:
            visit(w); low[v] = min(low[v], low[w])
        elif w in on:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop(); on.discard(w); comp.append(w)
            if w == v:
                break
        if len(comp) > 1:
            out.append(sorted(comp))
for m in sorted(g.modules):
    if m not in index:
        visit(m)
print(json.dumps({"modules": len(g.modules), "cycles": out}))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={"PYTHONPATH": str(package_tree)}, cwd=package_tree)
    result = json.loads(proc.stdout)
    assert result["modules"] > 80
    assert result["cycles"] == []
