"""Every repository path the prose names exists: docs/, the README, and the comments and docstrings
of the source and test folders.

A path is a token starting with a top-level folder of the repository (``wcbench/``, ``metrics/``,
``reports/``, ``reference_model/``, ``tests/``, ``docs/``, ``.ci/``) or naming ``tox.ini`` /
``pyproject.toml``. It is resolved against the repository root; ``wcbench/metrics/...``,
``wcbench/reports/...`` and ``wcbench/reference_model/...`` also against the folders they ship from
(the ``package-dir`` mapping in ``pyproject.toml``). ``<name>``, ``{name}`` and ``*`` are wildcards.
"""

from __future__ import annotations

import ast
import functools
import io
import re
import tokenize
from collections.abc import Iterator
from pathlib import Path

from paths import REPO

#: Top-level folders whose paths are checked (a path to anything else, e.g. ``runs/...``, is a user's).
FOLDERS = ("wcbench", "metrics", "reports", "reference_model", "tests", "docs", ".ci")
#: Installed layout -> source folder (pyproject.toml, [tool.setuptools] package-dir).
PACKAGE_DIR = {"wcbench/metrics": "metrics", "wcbench/reports": "reports",
               "wcbench/reference_model": "reference_model"}
#: Source folders whose comments and docstrings are read.
CODE_FOLDERS = ("wcbench", "metrics", "reports", "reference_model", "tests")

#: Paths named on purpose although they are not in the repository: path -> why.
EXCEPTIONS: dict[str, str] = {
    "metrics/<w>/images_full_<time>.json": "in the released WeatherCity code's log folder, not here "
                                           "(tests/methods/test_tool_layouts.py)",
}

_PATH = re.compile(
    r"(?<![\w./\\-])"                                      # not inside a longer path, URL or name
    r"((?:" + "|".join(re.escape(f) for f in FOLDERS) + r")/[\w./*<>{}-]*"
    r"|tox\.ini|pyproject\.toml)"
)


def _candidates(token: str) -> list[str]:
    token = token.rstrip(".,:;)")
    out = [token]
    for installed, source in PACKAGE_DIR.items():
        if token == installed or token.startswith(installed + "/"):
            out.append(source + token[len(installed):])
    return out


def _exists(token: str) -> bool:
    for cand in _candidates(token):
        if cand.rstrip(".,:;)") in EXCEPTIONS:
            return True
        pattern = re.sub(r"<[^>/]*>|\{[^}/]*\}", "*", cand.rstrip("/"))
        if any(c in pattern for c in "*?["):
            if any(REPO.glob(pattern)):
                return True
        elif (REPO / pattern).exists():
            return True
    return False


def _code_prose(path: Path) -> Iterator[tuple[int, str]]:
    """(line, text) of every comment and docstring of a Python file, or of every TOML comment."""
    text = path.read_text()
    if path.suffix == ".toml":
        for i, line in enumerate(text.splitlines(), 1):
            if "#" in line:
                yield i, line[line.index("#"):]
        return
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    todo: list[ast.AST] = [ast.parse(text)]
    while todo:  # modules, classes and functions only: docstrings live nowhere else
        node = todo.pop()
        body = getattr(node, "body", [])
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                and isinstance(body[0].value.value, str):
            for k, line in enumerate(body[0].value.value.splitlines()):
                yield body[0].lineno + k, line
        for child in body:
            if isinstance(child, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                todo.append(child)
            elif isinstance(child, (ast.If, ast.Try, ast.With)):  # definitions under `if TYPE_CHECKING:`...
                todo.extend(c for c in ast.iter_child_nodes(child) if hasattr(c, "body"))


@functools.cache
def _prose() -> list[tuple[Path, int, str]]:
    return list(_read_prose())


def _read_prose() -> Iterator[tuple[Path, int, str]]:
    docs = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    for path in docs:
        for i, line in enumerate(path.read_text().splitlines(), 1):
            yield path, i, line
    for folder in CODE_FOLDERS:
        for path in sorted((REPO / folder).rglob("*")):
            if path.suffix in (".py", ".toml") and "__pycache__" not in path.parts:
                for i, line in _code_prose(path):
                    yield path, i, line


def broken_paths() -> list[str]:
    broken = []
    for path, line_no, line in _prose():
        for match in _PATH.finditer(line):
            if not _exists(match.group(1)):
                broken.append(f"{path.relative_to(REPO)}:{line_no}: {match.group(1)}")
    return broken


def test_every_named_repository_path_exists() -> None:
    broken = broken_paths()
    assert not broken, "paths that do not exist:\n" + "\n".join(broken)


def test_every_cited_design_section_exists() -> None:
    """``docs/design.md §N`` (or ``design §N``) names a section heading ``## N.`` of docs/design.md."""
    design = (REPO / "docs" / "design.md").read_text()
    sections = {int(n) for n in re.findall(r"^## (\d+)\.", design, flags=re.M)}
    cite = re.compile(r"design(?:\.md)?`?\s*(?:§|section )(\d+)")
    broken = [f"{path.relative_to(REPO)}:{line_no}: §{m.group(1)}" for path, line_no, line in _prose()
              for m in cite.finditer(line) if int(m.group(1)) not in sections]
    assert not broken, "design sections that do not exist:\n" + "\n".join(broken)


def test_the_finder_sees_paths_and_wildcards() -> None:
    assert _exists("wcbench/metrics/registry.py")  # the installed layout
    assert _exists("wcbench/scenes/specs/*.toml") and _exists("docs/bench/<suite>.json")
    assert not _exists("wcbench/benchmark.py")
    assert [m.group(1) for m in _PATH.finditer("see `docs/design.md` §5, https://x.org/docs/a.md, "
                                                 "tox.ini and runs/docs/b.md")] == ["docs/design.md", "tox.ini"]
