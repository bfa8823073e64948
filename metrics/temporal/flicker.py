"""Temporal consistency: VBench-style temporal flicker and the flow warping error.

Temporal flicker (cheap)
    mean over consecutive frame pairs of mean |V_t - V_{t+1}|, RGB in [0, 1]. VBench reports
    1 - this (x255 scaled); we keep the raw mean absolute difference (lower is better) and the
    ratio edited / source, so camera motion that is in the source is factored out.
Flow warping error (docs/design.md §5)
    E_warp = mean_t [ sum_i M_t(i) ||V_t(i) - V_{t+1}(i + F_t(i))||^2 / sum_i M_t(i) ], squared
    error summed over RGB channels in [0, 1]. The flow F (t -> t+1) and the mask M come from the
    *source* sequence, so a method is judged on whether its edit moves with the scene. M = 1 where
    i + F(i) lies inside the frame and the pixel is neither occluded (forward-backward check
    |F + B~|^2 > 0.01 (|F|^2 + |B~|^2) + 0.5, with B~(i) = B(i + F(i)) the backward flow sampled at
    the target) nor on a motion boundary (|grad B~|^2 > 0.01 |B~|^2 + 0.002): the tests of Ruder et
    al. 2016, written in frame t's pixel grid. Reported with the edited / source ratio.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import cv2
import numpy as np

from wcbench.core.byte_cache import ByteBudgetCache
from wcbench.core.image_io import to_uint8
from wcbench.core.options import Option
from wcbench.core.parallel import parallel_map
from wcbench.metrics.base import (
    Metric,
    MetricValue,
    as_float_image_pair,
    as_float_images,
    check_same_shape,
    finite_or_none,
)

FlowFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- optical flow
def _gray8(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(to_uint8(img), cv2.COLOR_RGB2GRAY)


#: Smallest frames OpenCV's DIS (preset MEDIUM, 8 px patches) takes: (short side, long side) in px.
DIS_MIN_SIDES = (8, 12)


def dis_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense flow a -> b [H, W, 2] (pixels, x then y) with OpenCV DIS, preset MEDIUM.

    Raises
    ------
    ValueError
        If the frames are smaller than :data:`DIS_MIN_SIDES` (8 px on the short side and 12 px on
        the long one): OpenCV would stop with its own size error.
    """
    h, w = a.shape[:2]
    if min(h, w) < DIS_MIN_SIDES[0] or max(h, w) < DIS_MIN_SIDES[1]:
        raise ValueError(f"dis flow needs frames of at least {DIS_MIN_SIDES[0]} px on the short side and "
                         f"{DIS_MIN_SIDES[1]} px on the long side, got {h}x{w} px (use flow='farneback' "
                         "for smaller frames)")
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(_gray8(a), _gray8(b), None)


def farneback_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense flow a -> b [H, W, 2] with OpenCV Farneback (pyramid 0.5, 5 levels, window 15)."""
    return cv2.calcOpticalFlowFarneback(_gray8(a), _gray8(b), None, 0.5, 5, 15, 3, 5, 1.2, 0)


def deepflow_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense flow a -> b [H, W, 2] with OpenCV contrib DeepFlow (slow, most exact of the three)."""
    return cv2.optflow.createOptFlow_DeepFlow().calc(_gray8(a), _gray8(b), None)


FLOW_METHODS: dict[str, FlowFn] = {"dis": dis_flow, "farneback": farneback_flow, "deepflow": deepflow_flow}


def warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Sample ``img`` [H, W, C] at i + flow(i) (bilinear; zero outside) -> [H, W, C]."""
    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx, my = gx + flow[..., 0], gy + flow[..., 1]
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(img.shape)


def _central_gradient(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d/dy and d/dx of [H, W, C] like ``np.gradient`` (central inside, one-sided at the border);
    0 along an axis one pixel long, where no difference exists."""
    gy, gx = np.zeros_like(a), np.zeros_like(a)
    if a.shape[0] > 1:
        gy[1:-1] = (a[2:] - a[:-2]) * 0.5
        gy[0], gy[-1] = a[1] - a[0], a[-1] - a[-2]
    if a.shape[1] > 1:
        gx[:, 1:-1] = (a[:, 2:] - a[:, :-2]) * 0.5
        gx[:, 0], gx[:, -1] = a[:, 1] - a[:, 0], a[:, -1] - a[:, -2]
    return gy, gx


def _sq_norm(v: np.ndarray) -> np.ndarray:
    """Squared norm over the last axis, [H, W, C] -> [H, W]: ``(v * v).sum(-1)`` to the bit.

    NumPy reduces a short trailing axis ~7x slower than these C-1 whole-array additions, which add
    in the same order (v0^2 + v1^2) + v2^2.
    """
    out = v[..., 0] * v[..., 0]
    for c in range(1, v.shape[-1]):
        out += v[..., c] * v[..., c]
    return out


def consistency_mask(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """Valid-pixel mask [H, W] bool for warping frame t+1 onto frame t (see module docstring).

    Parameters
    ----------
    forward : ndarray [H, W, 2]
        Flow t -> t+1 in pixels.
    backward : ndarray [H, W, 2]
        Flow t+1 -> t in pixels.

    Notes
    -----
    Computed in float32: the thresholds (0.01 relative, 0.5 and 0.002 px^2 absolute) are far above
    float32 rounding of flows of a few hundred pixels.
    """
    h, w = forward.shape[:2]
    f = forward.astype(np.float32, copy=False)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    tx, ty = gx + f[..., 0], gy + f[..., 1]
    inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)
    b = warp(backward.astype(np.float32), f)
    f2 = _sq_norm(f)
    b2 = _sq_norm(b)
    fb = f + b
    occluded = _sq_norm(fb) > 0.01 * (f2 + b2) + 0.5
    gy_b, gx_b = _central_gradient(b)
    grad2 = _sq_norm(gx_b) + _sq_norm(gy_b)
    boundary = grad2 > 0.01 * b2 + 0.002
    return inside & ~occluded & ~boundary


def warp_error_pair(v0: np.ndarray, v1: np.ndarray, forward: np.ndarray, mask: np.ndarray) -> float:
    """Masked mean over pixels of the squared RGB error between v0 and v1 warped by ``forward``.

    Per-pixel errors in float32, the long sum over pixels in float64. NaN when the mask is empty.
    """
    diff = v0.astype(np.float32, copy=False) - warp(v1.astype(np.float32, copy=False), forward)
    err = _sq_norm(diff)
    total = int(np.count_nonzero(mask))
    return float(err[mask].sum(dtype=np.float64) / total) if total > 0 else float("nan")


def frame_digest(frame: np.ndarray) -> bytes:
    """A 16-byte digest of a frame's shape, dtype and values (cache keys)."""
    h = hashlib.sha256(f"{frame.shape}{frame.dtype}".encode())  # SHA extensions: twice blake2b's speed
    h.update(np.ascontiguousarray(frame).data)
    return h.digest()[:16]


@dataclass
class SourcePair:
    """What a pair of consecutive source frames gives every edit scored on it."""

    forward: np.ndarray  # [H, W, 2] flow t -> t+1 (px)
    mask: np.ndarray  # [H, W] bool, valid pixels
    source_error: float  # the source's own warping error on this pair (the ratio's denominator)

    @property
    def nbytes(self) -> int:
        return self.forward.nbytes + self.mask.nbytes


def _pair(flow: FlowFn, s0: np.ndarray, s1: np.ndarray) -> SourcePair:
    fwd = _checked_flow(flow(s0, s1), s0.shape[:2])
    bwd = _checked_flow(flow(s1, s0), s0.shape[:2])
    mask = consistency_mask(fwd, bwd)
    return SourcePair(fwd, mask, warp_error_pair(s0, s1, fwd, mask))


#: Source-sequence flows, masks and warping errors by (flow method, frame digests), shared by every
#: weather and method scored in one process: they depend only on the source frames, so scoring
#: rain, snow and fog of a scene computes them once.
FLOW_CACHE: ByteBudgetCache[SourcePair] = ByteBudgetCache(2 << 30)


def _checked_flow(flow: Any, size: tuple[int, ...]) -> np.ndarray:
    """A flow [H, W, 2] as float32, or a ValueError: a NaN flow would turn into NaN errors."""
    f = np.asarray(flow, np.float32)
    if f.shape != (*size, 2) or not np.all(np.isfinite(f)):
        raise ValueError(f"the flow must return finite [H, W, 2] = [{size[0]}, {size[1]}, 2] pixel offsets, "
                         f"got shape {f.shape}" + ("" if f.shape != (*size, 2) else " with non-finite values"))
    return f


def _check_frame_size(frame: np.ndarray, last: np.ndarray) -> None:
    """A batch continues the sequence of the previous one: its frames must have the same size."""
    if frame.shape != last.shape:
        raise ValueError(f"frames of one sequence must share a size: this batch has {frame.shape[:2]}, "
                         f"the previous frame {last.shape[:2]}")


def _too_few_frames(n: int) -> str:
    """The reason a temporal metric gives for a sequence too short for a frame pair (the wording of
    :meth:`Metric.skip_reason <wcbench.metrics.base.Metric.skip_reason>` for ``min_frames``)."""
    return f"needs at least 2 frames, got {n}"


def _mean_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    """mean |a - b|: differences in the inputs' precision, the long sum in float64."""
    return float(np.abs(a - b).sum(dtype=np.float64) / a.size)


def _sequence(frames: np.ndarray, name: str, what: str) -> np.ndarray:
    f = as_float_images(frames, name=name)
    if len(f) < 2:
        raise ValueError(f"{what}: {_too_few_frames(len(f))}")
    return f


def source_pair(flow: str | FlowFn, s0: np.ndarray, s1: np.ndarray, keys: tuple[bytes, bytes] | None = None
                ) -> SourcePair:
    """Flow, occlusion mask and warping error of consecutive source frames [H, W, 3] (float32).

    Named flows are cached per process (:data:`FLOW_CACHE`) under the frames' digests ``keys``
    (computed when not given); a callable flow is never cached.
    """
    if isinstance(flow, str):
        keys = keys or (frame_digest(s0), frame_digest(s1))
        fn = FLOW_METHODS[flow]
        return FLOW_CACHE.get((flow, *keys), lambda: _pair(fn, s0, s1))
    return _pair(flow, s0, s1)


# --------------------------------------------------------------------------- functional API
def temporal_flicker(frames: np.ndarray) -> float:
    """Mean absolute difference of consecutive frames (RGB in [0, 1]); lower is steadier.

    :class:`TemporalFlicker` accumulates the same per-pair values.

    Parameters
    ----------
    frames : ndarray [T, H, W, 3]
        T >= 2.

    Raises
    ------
    ValueError
        On fewer than 2 frames (the class reports such a sequence as a null value with the same
        reason, and the evaluation skips it through ``min_frames``), or on frames that are not
        finite RGB in [0, 1].
    """
    f = _sequence(frames, "frames", "temporal_flicker")
    return float(np.mean([_mean_abs_diff(f[k + 1], f[k]) for k in range(len(f) - 1)]))


def flow_warping_errors(edited: np.ndarray, source: np.ndarray | None = None, *,
                        flow: str | FlowFn = "dis") -> np.ndarray:
    """Per-pair flow warping errors [T - 1] of ``edited`` with flow and mask from ``source``.

    ``source`` defaults to ``edited`` itself (the error of a raw video). RGB in [0, 1]; NaN for a
    pair whose mask is empty.

    Raises
    ------
    ValueError
        On fewer than 2 frames (as :func:`temporal_flicker`), frames that are not finite RGB in
        [0, 1], mismatched shapes, frames too small for DIS (:data:`DIS_MIN_SIDES`), or a flow that
        is not finite [H, W, 2].
    """
    e = _sequence(edited, "edited", "flow_warping_error").astype(np.float32)
    s = e if source is None else _sequence(source, "source", "flow_warping_error").astype(np.float32)
    if e.shape != s.shape:
        raise ValueError(f"edited has shape {e.shape} but source has shape {s.shape}")
    if isinstance(flow, str) and flow not in FLOW_METHODS:
        raise ValueError(f"flow must be one of {sorted(FLOW_METHODS)} or a callable, got {flow!r}")
    out = []
    for k in range(len(e) - 1):
        pair = source_pair(flow, s[k], s[k + 1])
        out.append(warp_error_pair(e[k], e[k + 1], pair.forward, pair.mask))
    return np.asarray(out, np.float64)


def flow_warping_error(edited: np.ndarray, source: np.ndarray | None = None, *,
                       flow: str | FlowFn = "dis") -> float:
    """Flow warping error E_warp of ``edited`` [T, H, W, 3] with flow and mask from ``source``: the mean
    of :func:`flow_warping_errors` over pairs with valid pixels (NaN when none has any).

    The functional form of the ``flow_warping_error`` metric: :class:`FlowWarpingError` accumulates
    the same per-pair values. Raises as :func:`flow_warping_errors`.
    """
    errors = flow_warping_errors(edited, source, flow=flow)
    return float(np.nanmean(errors)) if np.isfinite(errors).any() else float("nan")


def flow_warp_error(edited: np.ndarray, source: np.ndarray | None = None, *, flow: str | FlowFn = "dis") -> float:
    """Deprecated alias of :func:`flow_warping_error` (the metric's name), kept for one release.

    Warns
    -----
    DeprecationWarning
        Always.
    """
    warnings.warn("flow_warp_error is deprecated, use flow_warping_error", DeprecationWarning, stacklevel=2)
    return flow_warping_error(edited, source, flow=flow)


def flow_warp_errors(edited: np.ndarray, source: np.ndarray | None = None, *,
                     flow: str | FlowFn = "dis") -> np.ndarray:
    """Deprecated alias of :func:`flow_warping_errors`, kept for one release.

    Warns
    -----
    DeprecationWarning
        Always.
    """
    warnings.warn("flow_warp_errors is deprecated, use flow_warping_errors", DeprecationWarning, stacklevel=2)
    return flow_warping_errors(edited, source, flow=flow)


# --------------------------------------------------------------------------- metrics
class TemporalFlicker(Metric):
    """VBench-style temporal flicker and its ratio to the source's own flicker."""

    name = "temporal_flicker"
    description = "mean |frame t - frame t+1| (RGB in [0, 1]) and its edited/source ratio"
    outputs = ("temporal_flicker", "temporal_flicker_ratio")
    higher_is_better = False
    min_frames = 2
    OPTIONS: ClassVar[dict[str, Option] | None] = {}

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget per-pair values and the last frames seen."""
        self._pred: list[float] = []
        self._src: list[float] = []
        self._last: tuple[np.ndarray, np.ndarray | None] | None = None
        self._frames = 0

    def update(self, pred: np.ndarray, *, source: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> None:
        """Accumulate the frame differences of a batch of consecutive frames [B, H, W, 3]."""
        p = as_float_images(pred, name="pred")
        s = None if source is None else as_float_images(source, name="source")
        if s is not None:
            check_same_shape(p, s, names=("pred", "source"))
        if len(p) and self._last is not None:
            _check_frame_size(p[0], self._last[0])
        self._frames += len(p)
        for k in range(len(p)):
            cur = (p[k], None if s is None else s[k])
            if self._last is not None:
                self._pred.append(_mean_abs_diff(cur[0], self._last[0]))
                if cur[1] is not None and self._last[1] is not None:
                    self._src.append(_mean_abs_diff(cur[1], self._last[1]))
            self._last = cur
        if self._last is not None:  # the caller may reuse its buffers: keep a copy
            self._last = (self._last[0].copy(), None if self._last[1] is None else self._last[1].copy())

    def compute(self) -> dict[str, MetricValue]:
        """Mean flicker and edited/source ratio (null with a reason when the source is static or the
        sequence has fewer than 2 frames)."""
        p, s = np.asarray(self._pred), np.asarray(self._src)
        variant = "mean abs difference of consecutive frames, RGB [0, 1]"
        if not p.size:
            reason = _too_few_frames(self._frames)
            return {"temporal_flicker": MetricValue(None, reason=reason, variant=variant),
                    "temporal_flicker_ratio": MetricValue(None, reason=reason, variant="ratio")}
        out = {"temporal_flicker": MetricValue.from_number(
            p.mean(), nonfinite_reason="non-finite frame difference", per_frame=finite_or_none(p),
            variant=variant)}
        if s.size and s.size == p.size:
            ratio = p.mean() / s.mean() if s.mean() > 0 else float("nan")
            out["temporal_flicker_ratio"] = MetricValue.from_number(
                ratio, nonfinite_reason="the source sequence is static (its flicker is zero or too small to divide by)",
                variant="edited temporal_flicker / source temporal_flicker")
        else:
            out["temporal_flicker_ratio"] = MetricValue(None, reason="no source sequence", variant="ratio")
        return out


_FLOW_ALLOWED = f"one of {', '.join(map(repr, FLOW_METHODS))} (Python API: also a flow callable)"


def _flow_option(value: Any) -> str | FlowFn:
    """``flow`` as :class:`FlowWarpingError` takes it: a name of :data:`FLOW_METHODS` or a callable."""
    if (isinstance(value, str) and value in FLOW_METHODS) or callable(value):
        return value
    raise ValueError(f"expected {_FLOW_ALLOWED}")


class FlowWarpingError(Metric):
    """Flow warping error with flow and occlusion mask from the source sequence (docs/design.md §5).

    Parameters
    ----------
    flow : {"dis", "farneback", "deepflow"} or callable
        Optical flow ``f(a, b) -> [H, W, 2]`` between two RGB frames.
    """

    name = "flow_warping_error"
    description = "masked flow warping error (flow + occlusion from the source), and edited/source ratio"
    outputs = ("flow_warping_error", "flow_warping_error_ratio")
    higher_is_better = False
    min_frames = 2
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "flow": Option("flow", "custom", "optical flow between neighbouring source frames (OpenCV's)", default="dis",
                       check=_flow_option, allowed=_FLOW_ALLOWED),
    }

    def __init__(self, *, flow: str | FlowFn = "dis"):
        if isinstance(flow, str) and flow not in FLOW_METHODS:
            raise ValueError(f"flow must be one of {sorted(FLOW_METHODS)} or a callable, got {flow!r}")
        self.flow_name = flow if isinstance(flow, str) else getattr(flow, "__name__", "custom")
        self._flow: FlowFn = FLOW_METHODS[flow] if isinstance(flow, str) else flow
        self._cacheable = isinstance(flow, str)
        self.reset()

    def config(self) -> dict[str, Any]:
        """The flow method (changes the numbers)."""
        return {"flow": self.flow_name}

    def skip_reason(self, ctx: Any) -> str | None:
        """Also needs the source sequence."""
        if not ctx.has_source:
            return "needs the source (raw) sequence for flow and occlusion"
        return super().skip_reason(ctx)

    def reset(self) -> None:
        """Forget per-pair errors and the last frames seen."""
        self._pred: list[float] = []
        self._src: list[float] = []
        self._last: tuple[np.ndarray, np.ndarray, bytes] | None = None
        self._frames = 0

    def update(self, pred: np.ndarray, *, source: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> None:
        """Accumulate per-pair warping errors of consecutive frames [B, H, W, 3]."""
        if source is None:
            raise ValueError("flow_warping_error: the source batch is required")
        p, s = as_float_image_pair(pred, source, names=("pred", "source"))
        p, s = p.astype(np.float32, copy=False), s.astype(np.float32, copy=False)
        if len(p) and self._last is not None:
            _check_frame_size(p[0], self._last[0])
        self._frames += len(p)
        keys = [frame_digest(f) for f in s]  # once per frame, not once per pair it belongs to
        frames = [(p[k], s[k], keys[k]) for k in range(len(p))]
        if self._last is not None:
            frames.insert(0, self._last)
        flow = self.flow_name if self._cacheable else self._flow

        def pair_errors(k: int) -> tuple[float, float]:
            (p0, s0, key0), (p1, s1, key1) = frames[k], frames[k + 1]
            pair = source_pair(flow, s0, s1, (key0, key1))
            return warp_error_pair(p0, p1, pair.forward, pair.mask), pair.source_error

        # The pairs are independent: a named flow (OpenCV, which releases the GIL, a new flow object
        # per call) runs them in worker threads; an injected callable one by one.
        pairs = range(len(frames) - 1)
        errors = parallel_map(pair_errors, pairs) if self._cacheable else [pair_errors(k) for k in pairs]
        for e_pred, e_src in errors:
            self._pred.append(e_pred)
            self._src.append(e_src)
        if frames:
            self._last = frames[-1]
        if self._last is not None:  # the caller may reuse its buffers: keep a copy
            self._last = (self._last[0].copy(), self._last[1].copy(), self._last[2])

    def compute(self) -> dict[str, MetricValue]:
        """Mean over frame pairs, and the edited/source ratio."""
        p, s = np.asarray(self._pred), np.asarray(self._src)
        variant = f"E_warp, {self.flow_name} flow + Ruder occlusion mask from source, RGB [0, 1], SSE over channels"
        ratio_variant = "edited E_warp / source E_warp"
        if not p.size:
            reason = _too_few_frames(self._frames)
            return {"flow_warping_error": MetricValue(None, reason=reason, variant=variant),
                    "flow_warping_error_ratio": MetricValue(None, reason=reason, variant=ratio_variant)}
        pm = float(np.nanmean(p)) if p.size and np.isfinite(p).any() else float("nan")
        sm = float(np.nanmean(s)) if s.size and np.isfinite(s).any() else float("nan")
        return {
            "flow_warping_error": MetricValue.from_number(
                pm, nonfinite_reason="no frame pair with valid (non-occluded) pixels",
                per_frame=finite_or_none(p), variant=variant),
            "flow_warping_error_ratio": MetricValue.from_number(
                pm / sm if sm > 0 else float("nan"),
                nonfinite_reason="the source's own warping error is zero or undefined", variant=ratio_variant),
        }
