"""One ``wcbench bench all --quick`` run shared by the tests of each suite's quick pass.

Each suite's test used to run its own quick pass, and ``bench all``'s test ran them all again: every
suite twice. Here ``bench all`` runs once, into the session's temporary folder, the first time a test
asks for it (``bench_all_quick``), and each suite's test reads its suite's JSON from there. Under
pytest-xdist the tests that ask for it go to one worker (tests/conftest.py): a second worker would
run ``bench all`` a second time.
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def bench_all_quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder of one ``wcbench bench all --quick`` run (no data root: the built-in scenes and
    stand-ins), with ``<suite>.json`` for every suite, ``summary.md`` and ``charts/``."""
    pytest.importorskip("torch")
    from wcbench.cli import main

    out = tmp_path_factory.mktemp("bench_all_quick")
    assert main(["bench", "all", "--quick", "--out", str(out)]) == 0
    return out
