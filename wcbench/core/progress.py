"""Progress bars (tqdm on stderr, shown only on a terminal unless forced)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import TypeVar

T = TypeVar("T")


def progress(items: Iterable[T], *, desc: str, total: int | None = None, enabled: bool = True,
             unit: str = "frame") -> Iterable[T]:
    """Wrap ``items`` in a tqdm bar counting ``unit``; ``WCBENCH_PROGRESS=0/1`` forces it off/on."""
    env = os.environ.get("WCBENCH_PROGRESS")
    if not enabled or env == "0":
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, total=total, leave=False, disable=None if env != "1" else False, unit=unit)
