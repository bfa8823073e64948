"""Sizes of the stress suites (tests/stress): a quick pass with the other tests, the full counts
under ``WCBENCH_STRESS=full`` (``tox -e stress``)."""

from __future__ import annotations

import os
from collections import Counter

#: ``WCBENCH_STRESS=full``: the full counts; anything else: the quick pass.
FULL = os.environ.get("WCBENCH_STRESS", "").lower() == "full"

#: Cases tried per suite, printed at the end of the run (tests/stress/conftest.py).
COUNTS: Counter[str] = Counter()


def cases(quick: int, full: int) -> int:
    """How many cases a suite tries: ``full`` under ``WCBENCH_STRESS=full``, else ``quick``."""
    return full if FULL else quick
