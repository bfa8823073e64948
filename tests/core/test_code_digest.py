"""A digest of a module's code, not its prose (wcbench.core.code_digest): what benchmark JSONs
record and a trained model's cache key holds."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from wcbench.core.code_digest import code_text, source_digest

_MODULE = '''"""A module."""

import math  # the one import

RATE = 2.0
"""The rate (a documented attribute)."""


def area(r):
    """Area of a circle.

    Of radius ``r``.
    """
    # pi r^2
    return math.pi * r ** RATE  # exact
'''


@pytest.fixture
def package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An importable package ``digestpkg`` of a module and a TOML data file."""
    root = tmp_path / "digestpkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "geometry.py").write_text(_MODULE)
    (root / "presets.toml").write_text("# presets\nrate = 2.0\n")
    (root / "notes.md").write_text("not code")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    return root


def test_code_text_leaves_out_comments_docstrings_and_blank_lines() -> None:
    assert code_text(_MODULE) == ("import math\nRATE = 2.0\ndef area(r):\n    return math.pi * r ** RATE")
    kept = 'x = 1; "not alone on its line"\ny = f("an argument")  # a comment\n'
    assert code_text(kept) == 'x = 1; "not alone on its line"\ny = f("an argument")'
    with pytest.raises(ValueError, match=r"m\.py: not valid Python"):
        code_text("def (", name="m.py")


def test_the_digest_follows_the_code_not_its_prose(package: Path) -> None:
    module = package / "sub" / "geometry.py"
    before = source_digest("digestpkg")
    assert source_digest("digestpkg.sub.geometry") != before  # one file against the whole package

    module.write_text(_MODULE.replace("# pi r^2", "# the area").replace("Of radius", "For a radius") + "\n\n")
    (package / "presets.toml").write_text("# the presets\n\nrate = 2.0\n")
    (package / "notes.md").write_text("other prose")
    assert source_digest("digestpkg") == before

    (package / "presets.toml").write_text("rate = 3.0\n")
    assert source_digest("digestpkg") != before
    (package / "presets.toml").write_text("rate = 2.0\n")
    assert source_digest("digestpkg") == before
    module.write_text(_MODULE.replace("** RATE", "** RATE * 1.0"))
    assert source_digest("digestpkg") != before
    with pytest.raises(ValueError, match=r"no module 'digestpkg\.absent'"):
        source_digest("digestpkg.absent")


def test_a_models_key_digests_both_packages_by_the_prose_free_digest(monkeypatch: pytest.MonkeyPatch) -> None:
    """The model cache's key (wcbench.methods.scene_training) digests ``wcbench`` and its reference
    model through :func:`source_digest`: a documenting edit trains nothing again, a code edit does."""
    pytest.importorskip("torch")
    from wcbench.methods import scene_training

    seen: list[str] = []

    def fake(module: str) -> str:
        seen.append(module)
        return {"wcbench": "a", "wcbench.reference_model": "b"}[module]

    scene_training._source_digest.cache_clear()
    monkeypatch.setattr(scene_training, "source_digest", fake)
    try:
        first = scene_training._source_digest()
        assert sorted(seen) == ["wcbench", "wcbench.reference_model"]
        scene_training._source_digest.cache_clear()
        monkeypatch.setattr(scene_training, "source_digest",
                            lambda m: {"wcbench": "a", "wcbench.reference_model": "c"}[m])
        assert scene_training._source_digest() != first
    finally:
        scene_training._source_digest.cache_clear()
