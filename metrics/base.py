"""The metric interface: update/compute on sufficient statistics (torchmetrics style).

A metric sees a scene's frames in order, a batch at a time, as float RGB arrays in [0, 1]:

    metric.reset()
    for batch in frames:                      # consecutive frames, in order
        metric.update(pred[B,H,W,3], source=..., reference=...)
    values = metric.compute()                 # {output name: MetricValue}

``update`` only accumulates sufficient statistics (sums, confusion matrices, per-frame values,
the last frame for temporal metrics), so one ``update`` with all frames equals many small ones.
Whether a metric applies at all (needs a reference the scene lacks, weather where it is
meaningless, missing model weights) is asked first with :meth:`Metric.skip_reason`; a metric that
does not apply is recorded as skipped with that reason, never as a number.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from wcbench.core.options import Option

#: Weathers whose visibility loss invalidates content-consistency metrics (paper's rule, docs/design.md §5).
CONTENT_INVALID_WEATHERS = frozenset({"fog"})


@dataclass(frozen=True)
class MetricContext:
    """What a (scene, weather) offers a metric, known before any frame is read.

    Attributes
    ----------
    weather : str
        ``"clear"``, ``"rain"``, ``"snow"`` or ``"fog"``.
    n_frames : int
    has_reference : bool
        A ground-truth sequence exists for this weather.
    has_source : bool
        The raw (unedited) frames exist.
    method_info : dict or None
        The method's ``info.json`` (timings, parameters), if any.
    fps_override : float or None
        A frame rate given by the user (``--fps``).
    """

    weather: str
    n_frames: int
    has_reference: bool
    has_source: bool = True
    method_info: dict[str, Any] | None = None
    fps_override: float | None = None


@dataclass
class MetricValue:
    """One number a metric reports, with its raw per-frame values.

    Attributes
    ----------
    value : float or None
        The aggregate; ``None`` when it is not a finite number, with ``reason`` saying why.
    per_frame : list of float or None
        Raw per-frame (or per-frame-pair) values, non-finite ones as ``None``.
    variant : str
        Which definition produced the number (e.g. ``"mean of per-frame PSNR, data_range=1"``).
    reason : str or None
        Why ``value`` is ``None``.
    extra : dict
        Counts and side facts (``degenerate`` frames...).
    """

    value: float | None
    per_frame: list[float | None] = field(default_factory=list)
    variant: str = ""
    reason: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_number(cls, value: float, *, nonfinite_reason: str, **kw: Any) -> MetricValue:
        """Build from a float; a NaN/Inf becomes ``None`` with ``nonfinite_reason``."""
        value = float(value)
        if math.isfinite(value):
            return cls(value=value, **kw)
        return cls(value=None, reason=f"{nonfinite_reason} (value was {value})", **kw)


def finite_or_none(values: Any) -> list[float | None]:
    """Per-frame values as a JSON-friendly list (non-finite -> ``None``)."""
    return [float(v) if math.isfinite(float(v)) else None for v in np.asarray(values, float).ravel()]


def as_float_images(x: Any, *, name: str) -> np.ndarray:
    """Check and return images as a float array [B, H, W, C] in [0, 1].

    Accepts [H, W, C] (one frame) or [B, H, W, C]; float16/32/64 are kept (computation is done in
    float64 where sums run long), uint8 is divided by 255.

    Raises
    ------
    ValueError
        On a wrong rank, a channel count other than 3, an image without pixels (H or W = 0), or
        float values outside [0, 1].
    """
    a = np.asarray(x)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"{name}: expected images [B, H, W, 3] or [H, W, 3], got shape {a.shape}")
    if a.shape[1] == 0 or a.shape[2] == 0:  # every per-pixel mean would be 0 / 0
        raise ValueError(f"{name}: images must be at least 1 x 1 px, got {a.shape[1]} x {a.shape[2]}")
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name}: expected uint8 or float images, got dtype {a.dtype}")
    # NaN makes min/max NaN and fails both comparisons, +-inf fails the range: two passes, no mask
    if a.size and not (a.min() >= 0.0 and a.max() <= 1.0):
        raise ValueError(f"{name}: float images must be finite and in [0, 1]")
    return a


def python_object_option(name: str, doc: str, *, accepts: Callable[[Any], bool], what: str) -> Option:
    """An option only Python callers give (an injected model, a model store): ``None`` (the metric's
    own) or ``what``, which no value of the command line is.

    Parameters
    ----------
    name, doc : str
        The option's keyword and meaning.
    accepts : callable
        ``accepts(value)`` is true for the objects the option takes (``callable``, an ``isinstance``).
    what : str
        Those objects in words (``"a ModelStore"``), for the listing and the errors.
    """
    allowed = f"{what} (Python API only)"

    def check(value: Any) -> Any:
        if not accepts(value):
            raise ValueError(f"expected {allowed} or null")
        return value

    return Option(name, "custom", doc, default=None, nullable=True, check=check, allowed=allowed)


def check_same_shape(a: np.ndarray, b: np.ndarray, *, names: tuple[str, str]) -> None:
    """Raise ``ValueError`` naming both shapes if they differ."""
    if a.shape != b.shape:
        raise ValueError(f"{names[0]} has shape {a.shape} but {names[1]} has shape {b.shape}")


def as_float_image_pair(a: Any, b: Any, *, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray]:
    """Two image batches compared frame by frame: :func:`as_float_images` of each, of one shape.

    Parameters
    ----------
    a, b : array-like [H, W, 3] or [B, H, W, 3]
        Float RGB in [0, 1] or uint8.
    names : (str, str)
        Names of ``a`` and ``b`` in the messages.

    Returns
    -------
    a, b : ndarray [B, H, W, 3]
        As :func:`as_float_images` returns them.

    Raises
    ------
    ValueError
        As :func:`as_float_images`, or when the shapes differ (:func:`check_same_shape`).
    """
    fa, fb = as_float_images(a, name=names[0]), as_float_images(b, name=names[1])
    check_same_shape(fa, fb, names=names)
    return fa, fb


def check_min_side(images: np.ndarray, min_side: int, *, name: str) -> None:
    """Raise ``ValueError`` if frames of ``images`` [B, H, W, C] (B >= 1) are under ``min_side`` px
    on a side (a metric's window or network needs it); an empty batch passes."""
    if len(images) and min(images.shape[1:3]) < min_side:
        raise ValueError(f"{name}: images must be at least {min_side} px on each side, "
                         f"got {images.shape[1]} x {images.shape[2]} px")


def identical_frames(pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Which frames of ``pred`` equal their ``reference`` exactly, element for element.

    A full-reference metric knows its value on such a pair exactly (PSNR +inf, SSIM 1, LPIPS 0),
    so it need not compute it: a method that passes a frame through unchanged (every method's
    ``clear`` frames that are the raw ones) is scored without the work.

    Parameters
    ----------
    pred, reference : ndarray [B, H, W, C]
        Of one shape (checked by the caller).

    Returns
    -------
    ndarray [B] bool
    """
    return np.fromiter((np.array_equal(p, r) for p, r in zip(pred, reference)), bool, len(pred))


def frame_values_skipping_identical(values: Callable[[np.ndarray, np.ndarray], Any], pred: np.ndarray,
                                    reference: np.ndarray, identical_value: float | None, *,
                                    name: str) -> np.ndarray:
    """``values(pred, reference)`` [B] float64, computed only for the frames that differ from their
    reference; the others get ``identical_value`` (``None``: every frame is computed).

    Raises
    ------
    ValueError
        ``values`` returned another count than the frames it was given (``name`` says whose).
    """
    differ = np.ones(len(pred), bool) if identical_value is None else ~identical_frames(pred, reference)
    out = np.full(len(pred), np.nan if identical_value is None else identical_value, np.float64)
    if differ.any():
        computed = np.asarray(values(pred[differ], reference[differ]), np.float64).reshape(-1)
        if computed.shape[0] != int(differ.sum()):
            raise ValueError(f"{name}: {computed.shape[0]} values returned for {int(differ.sum())} frames")
        out[differ] = computed
    return out


#: Margin (px) of the crop around an edited region, and its smallest side (LPIPS's backbones and
#: SSIM's window need some context around a small object).
REGION_PAD_PX, REGION_MIN_SIDE_PX = 8, 64


def region_box(mask: np.ndarray) -> tuple[slice, slice] | None:
    """Rows and columns of the crop around a region ``mask`` [H, W] (bool): its bounding box grown
    by :data:`REGION_PAD_PX`, then to :data:`REGION_MIN_SIDE_PX` a side where the image allows,
    within the image; ``None`` for an empty mask."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not rows.size:
        return None

    def span(first: int, last: int, size: int) -> slice:
        lo, hi = max(first - REGION_PAD_PX, 0), min(last + 1 + REGION_PAD_PX, size)
        need = min(REGION_MIN_SIDE_PX, size)
        if hi - lo < need:  # grown about its centre, shifted back inside the image
            lo = min(max(lo - (need - (hi - lo)) // 2, 0), size - need)
            hi = lo + need
        return slice(lo, hi)

    return span(int(rows[0]), int(rows[-1]), mask.shape[0]), span(int(cols[0]), int(cols[-1]), mask.shape[1])


class Metric(ABC):
    """Base class of every wcbench metric.

    Subclasses set the class attributes and implement :meth:`reset`, :meth:`update` and
    :meth:`compute`; heavy models are passed to ``__init__`` so tests can inject small ones.
    """

    #: Registry name, e.g. ``"psnr"``.
    name: ClassVar[str]
    #: One line for ``wcbench metrics list``.
    description: ClassVar[str]
    #: Names of the :class:`MetricValue` outputs :meth:`compute` returns.
    outputs: ClassVar[tuple[str, ...]]
    higher_is_better: ClassVar[bool]
    #: Needs a ground-truth sequence (PSNR, SSIM, LPIPS).
    needs_reference: ClassVar[bool] = False
    #: Compares the edit's content with the source frame (CLIP-S, Sem-CS): skipped in fog.
    compares_content: ClassVar[bool] = False
    #: Needs at least this many frames (temporal metrics need 2).
    min_frames: ClassVar[int] = 1
    #: Reads the frames (FPS does not): scored at the metric working resolution.
    reads_frames: ClassVar[bool] = True
    #: The keyword options of the constructor (name -> :class:`~wcbench.core.options.Option`: type,
    #: range or choices, default, meaning), declared beside it and checked before any work
    #: (:func:`~wcbench.metrics.registry.validate_metric_options`; docs/guide.md, "Metric options");
    #: ``None``: undeclared (a plugin's metric), its keywords then take any value.
    OPTIONS: ClassVar[dict[str, Option] | None] = None

    @classmethod  # noqa: B027 - an optional hook
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """The rules no single option's schema states: between options, or against files (a model of
        the catalogue, a weather of a prompts file). ``options`` are the ones given, each already
        checked against :attr:`OPTIONS`. Reads files, writes nothing; by default there are none.

        Raises
        ------
        OptionError
            Whose ``path`` is the option at fault and whose message says what is allowed (the
            caller adds the metric, the option and the value).
        """

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """Why this metric cannot run on ``ctx`` (``None``: it can)."""
        if self.needs_reference and not ctx.has_reference:
            return f"no ground-truth {ctx.weather} sequence for this scene"
        if self.compares_content and ctx.weather in CONTENT_INVALID_WEATHERS:
            return f"{ctx.weather}: visibility loss invalidates content metrics (paper's rule)"
        if ctx.n_frames < self.min_frames:
            return f"needs at least {self.min_frames} frames, the sequence has {ctx.n_frames}"
        return None

    def bind(self, ctx: MetricContext) -> None:  # noqa: B027 - optional hook
        """Called with the context before :meth:`reset`; metrics that need it keep it."""

    def config(self) -> dict[str, Any]:
        """Settings that change the numbers (part of the cache key and of results.json)."""
        return {}

    def required_models(self) -> tuple[str, ...]:
        """Model-store entries this metric reads its weights from (``()``: none, or injected).

        A run fetches the missing ones before it starts (:mod:`wcbench.core.models.fetch`); the
        metric still says "skipped" with the reason where they stay missing.
        """
        return ()

    def requires(self) -> tuple[str, ...]:
        """What scoring needs besides the evaluation side: ``("torch",)`` for a torch backend.

        A distributed run sends the units to workers that declare these resources, so a metric
        is never skipped on one worker and computed on another.
        """
        return ("torch",) if self.config().get("backend") == "torch" else ()

    @abstractmethod
    def reset(self) -> None:
        """Forget all accumulated statistics."""

    @abstractmethod
    def update(
        self,
        pred: np.ndarray,
        *,
        source: np.ndarray | None = None,
        reference: np.ndarray | None = None,
    ) -> None:
        """Accumulate a batch of consecutive frames.

        The caller may reuse the arrays after the call: keep copies of anything retained.

        Parameters
        ----------
        pred : ndarray [B, H, W, 3]
            The method's frames, float RGB in [0, 1].
        source : ndarray [B, H, W, 3], optional
            The raw frames the edit started from.
        reference : ndarray [B, H, W, 3], optional
            Ground truth for this weather.
        """

    @abstractmethod
    def compute(self) -> dict[str, MetricValue]:
        """The metric's outputs over everything seen since :meth:`reset`."""

    #: How :meth:`update_region` scores an edited region (appended to the variant of its outputs).
    region_variant: ClassVar[str] = (
        f"on the edited region: each frame cropped to its mask's bounding box grown by {REGION_PAD_PX} px "
        f"(at least {REGION_MIN_SIDE_PX} px a side), the prediction replaced by the truth outside the mask; "
        "frames with an empty mask left out")

    def update_region(self, pred: np.ndarray, *, source: np.ndarray | None = None, reference: np.ndarray,
                      mask: np.ndarray) -> None:
        """Accumulate a batch scored only on an edited region (reference metrics; docs/design.md §3).

        The default crops each frame around its region and shows the metric the prediction there
        and the truth elsewhere (:data:`region_variant`); a metric with an exact masked form
        overrides it.

        Parameters
        ----------
        pred, reference : ndarray [B, H, W, 3]
            Float RGB in [0, 1]; ``source`` as :meth:`update`.
        mask : ndarray [B, H, W] bool
            The edited region of each frame.
        """
        for b in range(len(pred)):
            box = region_box(mask[b])
            if box is None:
                continue
            ys, xs = box
            inside = mask[b][ys, xs, None]
            p = np.where(inside, pred[b][ys, xs], reference[b][ys, xs])
            self.update(p[None], source=None if source is None else source[b][ys, xs][None],
                        reference=np.ascontiguousarray(reference[b][ys, xs][None]))


class PerFrameReferenceMetric(Metric):
    """A metric that scores each frame against its ground truth and reports the mean over frames.

    Subclasses set ``name``, ``description``, ``outputs`` (one name), ``higher_is_better``,
    ``variant``, ``identical_value`` and :meth:`frame_values`.

    Parameters
    ----------
    skip_identical : bool
        Give a frame equal to its reference ``identical_value`` without computing it
        (:func:`identical_frames`); off only to measure what that saves.
    """

    needs_reference = True
    #: Which definition produced the number (recorded in results).
    variant: ClassVar[str] = ""
    #: Why the mean may be non-finite (e.g. PSNR of identical frames).
    nonfinite_reason: ClassVar[str] = "non-finite per-frame value"
    #: The exact value of a frame against itself; ``None``: always computed.
    identical_value: ClassVar[float | None] = None
    #: Smallest frame side the metric takes (checked before any frame is skipped as identical).
    min_side: ClassVar[int] = 1
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "skip_identical": Option("skip_identical", "bool", "give a frame equal to its reference its exact value "
                                 "without computing it (off only to measure what that saves)", default=True),
    }

    def __init__(self, *, skip_identical: bool = True) -> None:
        self.skip_identical = bool(skip_identical)
        self.reset()

    @abstractmethod
    def frame_values(self, pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Per-frame values [B] of ``pred`` against ``reference`` (both [B, H, W, 3] in [0, 1])."""

    def reset(self) -> None:
        """Forget the per-frame values."""
        self._values: list[float] = []

    def update(self, pred: np.ndarray, *, source: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> None:
        """Score a batch [B, H, W, 3] against ``reference`` (required)."""
        if reference is None:
            raise ValueError(f"{self.name}: a reference batch is required")
        p, r = as_float_image_pair(pred, reference, names=("pred", "reference"))
        check_min_side(p, self.min_side, name=self.name)
        self._values.extend(frame_values_skipping_identical(
            self.frame_values, p, r, self.identical_value if self.skip_identical else None, name=self.name).tolist())

    def compute(self) -> dict[str, MetricValue]:
        """Mean over frames (null with a reason when non-finite or when no frame was seen)."""
        v = np.asarray(self._values, np.float64)
        if not v.size:
            return {self.outputs[0]: MetricValue(None, reason="no frames", variant=self.variant)}
        return {self.outputs[0]: MetricValue.from_number(
            float(v.mean()), nonfinite_reason=self.nonfinite_reason, per_frame=finite_or_none(v),
            variant=self.variant)}
