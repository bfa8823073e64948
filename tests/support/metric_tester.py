"""One shared tester for every Metric (torchmetrics style).

``check_metric(factory, pred, source=..., reference=...)`` verifies, on a sequence [T, H, W, 3]:

- one update with all frames == frame-by-frame updates (sufficient statistics, up to FP order);
- reset forgets everything; a pickled and restored metric continues identically;
- float32 and float64 inputs agree (to float32 precision);
- every output is a finite number, or None with a reason;
- the functional form of each output (``functional={output: fn(pred, source, reference)}``)
  gives the class's number.
"""

from __future__ import annotations

import math
import pickle
from collections.abc import Callable, Mapping

import numpy as np

from wcbench.metrics.base import Metric, MetricValue

#: float64 sums in a different order differ in the last bits only.
ACCUMULATION_RTOL = 1e-9
#: float32 inputs are rounded versions of the float64 ones.
DTYPE_RTOL = 1e-4


def _run(metric: Metric, pred, source, reference, *, split: list[int]) -> dict[str, MetricValue]:
    metric.reset()
    start = 0
    for stop in [*split, len(pred)]:
        sl = slice(start, stop)
        if stop > start:
            metric.update(pred[sl], source=None if source is None else source[sl],
                          reference=None if reference is None else reference[sl])
        start = stop
    return metric.compute()


def _close(a: MetricValue, b: MetricValue, rtol: float, what: str) -> None:
    if a.value is None or b.value is None:
        assert a.value is None and b.value is None, f"{what}: {a.value} vs {b.value}"
        assert a.reason and b.reason, f"{what}: a null value must carry a reason"
        return
    assert math.isclose(a.value, b.value, rel_tol=rtol, abs_tol=1e-12), f"{what}: {a.value} != {b.value}"


#: ``fn(pred, source, reference) -> float``: a metric's functional form for one output.
Functional = Callable[[np.ndarray, np.ndarray | None, np.ndarray | None], float]


def check_metric(factory: Callable[[], Metric], pred: np.ndarray, *, source: np.ndarray | None = None,
                 reference: np.ndarray | None = None,
                 functional: Mapping[str, Functional] | None = None) -> dict[str, MetricValue]:
    """Run the shared checks; return the outputs of the all-at-once run."""
    metric = factory()
    whole = _run(metric, pred, source, reference, split=[])
    assert set(whole) == set(type(metric).outputs), f"outputs {set(whole)} != declared {type(metric).outputs}"
    for name, fn in (functional or {}).items():
        value = fn(pred, source, reference)
        expected = whole[name].value
        assert expected is not None, f"{name}: the class gave null ({whole[name].reason}), the functional {value}"
        assert math.isclose(value, expected, rel_tol=ACCUMULATION_RTOL, abs_tol=1e-12), \
            f"{name}: functional {value} != class {expected}"
    for name, v in whole.items():
        assert v.value is None or math.isfinite(v.value), f"{name}: non-finite value {v.value}"
        assert v.value is not None or v.reason, f"{name}: null without a reason"
    stepwise = _run(metric, pred, source, reference, split=list(range(1, len(pred))))
    for name in whole:
        _close(whole[name], stepwise[name], ACCUMULATION_RTOL, f"{name} batch vs accumulated")
    # reset: a second run from scratch equals the first
    again = _run(metric, pred, source, reference, split=[])
    for name in whole:
        _close(whole[name], again[name], 0.0, f"{name} after reset")
    # pickling mid-sequence
    if len(pred) >= 2:
        metric.reset()
        half = len(pred) // 2
        metric.update(pred[:half], source=None if source is None else source[:half],
                      reference=None if reference is None else reference[:half])
        clone = pickle.loads(pickle.dumps(metric))
        clone.update(pred[half:], source=None if source is None else source[half:],
                     reference=None if reference is None else reference[half:])
        restored = clone.compute()
        for name in whole:
            _close(whole[name], restored[name], ACCUMULATION_RTOL, f"{name} after pickling")
    # dtype: float32 inputs give the float64 answer to float32 precision
    as32 = _run(factory(), pred.astype(np.float32),
                None if source is None else source.astype(np.float32),
                None if reference is None else reference.astype(np.float32), split=[])
    for name in whole:
        _close(whole[name], as32[name], DTYPE_RTOL, f"{name} float32 vs float64")
    return whole
