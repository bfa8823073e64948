"""Arguments shared by several verbs."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """``--scenes`` and ``--data-root``."""
    parser.add_argument("--scenes", required=True,
                        help="scene set name (see `wcbench scenes list`) or path to one processed scene folder")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder holding the datasets (default: $WCBENCH_DATA)")


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def split_list(values: list[str] | None) -> list[str] | None:
    """Accept both ``--x a b`` and ``--x a,b``."""
    if not values:
        return None
    return [v for item in values for v in item.split(",") if v]
