"""A benchmark suite that measures nothing, for the tests of what ``wcbench bench`` records."""

from __future__ import annotations

from pathlib import Path

from wcbench.bench.schema import BenchCase, BenchReport


def run(*, data_root: Path | None, quick: bool) -> BenchReport:
    """One case, no work (``SUITES["fake"] = "bench_fakes:run"``)."""
    return BenchReport("fake", cases=[BenchCase("one", "knob", 1, 1.0, 0.0, "abs")])
