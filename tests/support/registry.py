"""Tests that fetch from a package registry: skipped where none is reachable, failed in CI."""

from __future__ import annotations

import os

import pytest


def registry_unreachable(reason: str) -> None:
    """Skip the test (a machine without a package registry), or fail it when ``$CI`` is set: CI can
    reach the registries, so a fetch that fails there is a fault, not a missing resource."""
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        pytest.fail(f"CI is set, so the package registry must be reachable: {reason}")
    pytest.skip(reason)
