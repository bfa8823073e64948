"""The metric working resolution."""

from __future__ import annotations

import pytest

from wcbench.core.errors import InputError
from wcbench.core.working_size import METRIC_RESOLUTION, parse_metric_resolution, working_size


@pytest.mark.parametrize(("size", "res", "expected"), [
    ((1920, 1080), 960, (960, 540)),
    ((1080, 1920), 960, (540, 960)),  # the longer side, whichever it is
    ((1920, 1080), None, (1920, 1080)),
    ((480, 270), 960, (480, 270)),  # never enlarged
    ((1920, 1086), 960, (960, 543)),
    ((5000, 3), 100, (100, 1)),  # at least one pixel
])
def test_working_size(size, res, expected) -> None:
    assert working_size(size, res) == expected


def test_parse_metric_resolution() -> None:
    assert parse_metric_resolution("native") is None
    assert parse_metric_resolution(None) == METRIC_RESOLUTION
    assert parse_metric_resolution("720") == 720
    for bad in ("0", "31", "-5", "big", "9.5"):
        with pytest.raises(InputError, match="'native' or the longer side"):
            parse_metric_resolution(bad)
