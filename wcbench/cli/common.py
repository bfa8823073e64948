"""Arguments shared by several verbs."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """``--scenes`` and ``--data-root``."""
    parser.add_argument("--scenes", required=True,
                        help="scene set name (see `wcbench scenes list`) or path to one processed scene folder")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder holding the datasets (default: $WCBENCH_DATA)")


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def parse_metric_options(items: list[str]) -> dict[str, dict[str, Any]]:
    """``["sem_cs.segmenter=segformer-b0-ade", "clip_s.batch_size=8"]`` -> ``{metric: {key: value}}``.

    Values are read as JSON when they parse (numbers, booleans), else kept as text.

    Raises
    ------
    InputError
        On an item not of the form ``METRIC.KEY=VALUE``.
    """
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        metric, dot, option = key.partition(".")
        if not (sep and dot and metric and option):
            raise InputError(
                f"--metric-option {item!r}: expected METRIC.KEY=VALUE, e.g. sem_cs.segmenter=segformer-b0-ade"
            )
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out.setdefault(metric, {})[option] = value
    return out


def split_list(values: list[str] | None) -> list[str] | None:
    """Accept both ``--x a b`` and ``--x a,b``."""
    if not values:
        return None
    return [v for item in values for v in item.split(",") if v]
