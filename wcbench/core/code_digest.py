"""A digest of a module's code, not of its prose: what a cache or a benchmark record keys on.

A digest is of the code: comments, docstrings (any statement that is a bare string), blank lines
and trailing spaces are left out, so documenting code changes no digest, while any other edit does
(a renamed variable too: a digest cannot tell which change moves a result). The data files that
ship in a package (TOML presets and catalogues, templates) count, TOML without its comment lines.
Files are found where Python imports the module from (an installed package or the checkout), by
their path inside it, so both give one digest. Benchmark JSONs record it per measured module
(:mod:`wcbench.bench.code_version`); a trained model's cache key holds it (docs/design.md §9).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import io
import tokenize
from pathlib import Path

__all__ = ["SOURCE_SUFFIXES", "code_text", "module_files", "source_digest"]

#: Files of a package that can change what it computes (the package data of pyproject.toml).
SOURCE_SUFFIXES = (".py", ".toml", ".json", ".j2", ".js", ".css", ".html", ".txt")


def module_files(module: str) -> list[tuple[str, Path]]:
    """The source files of a module or a package, as (path inside it, file), sorted by path.

    Parameters
    ----------
    module : str
        Dotted name, e.g. ``"wcbench.reference_model"`` (a package: every file of
        :data:`SOURCE_SUFFIXES` under it) or ``"wcbench.bench.model"`` (one file). Only its parent
        packages are imported, not the module itself.

    Raises
    ------
    ValueError
        If no such module can be found.
    """
    spec = importlib.util.find_spec(module)
    if spec is None:
        raise ValueError(f"no module {module!r} to take a digest of")
    if spec.submodule_search_locations:
        files = []
        for location in spec.submodule_search_locations:
            root = Path(location)
            for path in root.rglob("*"):
                rel = path.relative_to(root)
                if path.suffix in SOURCE_SUFFIXES and path.is_file() \
                        and not any(p == "__pycache__" or p.startswith(".") for p in rel.parts):
                    files.append((rel.as_posix(), path))
        return sorted(files)
    if spec.origin is None or not spec.origin.endswith(".py"):
        raise ValueError(f"module {module!r} has no Python source to take a digest of (found {spec.origin})")
    return [(Path(spec.origin).name, Path(spec.origin))]


def code_text(source: str, *, name: str = "<source>") -> str:
    """Python source without its comments, docstrings, blank lines and trailing spaces.

    A bare string statement (a docstring, or a string documenting an attribute) is left out only
    when it is alone on its lines; ``name`` names the file in errors.

    Raises
    ------
    ValueError
        If ``source`` is not valid Python.
    """
    source = source.replace("\r\n", "\n").replace("\r", "\n")
    try:
        tree = ast.parse(source)
    except SyntaxError as exc:
        raise ValueError(f"{name}: not valid Python ({exc.msg}, line {exc.lineno})") from None
    lines = source.split("\n")  # the rows of ast and tokenize (str.splitlines breaks on more)
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            first, last = node.lineno - 1, (node.end_lineno or node.lineno) - 1
            # ast counts columns in UTF-8 bytes
            before = lines[first].encode()[:node.col_offset].decode(errors="replace")
            after = lines[last].encode()[node.end_col_offset or 0:].decode(errors="replace").strip()
            if not before.strip() and (not after or after.startswith("#") or after == ";"):
                for i in range(first, last + 1):
                    lines[i] = ""
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            row, col = tok.start
            lines[row - 1] = lines[row - 1][:col]
    return "\n".join(line.rstrip() for line in lines if line.strip())


def _file_text(rel: str, path: Path) -> bytes:
    if path.suffix == ".py":
        return code_text(path.read_text(encoding="utf-8"), name=str(path)).encode()
    data = path.read_bytes().replace(b"\r\n", b"\n")
    if path.suffix == ".toml":
        data = b"\n".join(line.rstrip() for line in data.split(b"\n")
                          if line.strip() and not line.lstrip().startswith(b"#"))
    return data


def source_digest(module: str) -> str:
    """sha256 (hex) of the code of a module or a package (see the module docstring).

    Raises
    ------
    ValueError
        If the module cannot be found or one of its Python files does not parse.
    """
    h = hashlib.sha256()
    for rel, path in module_files(module):
        h.update(rel.encode() + b"\0" + hashlib.sha256(_file_text(rel, path)).hexdigest().encode() + b"\n")
    return h.hexdigest()
