"""Sem-CS: frequency-weighted IoU between the segmentations of the source frame and the edit.

With the confusion matrix n_ij = number of pixels labelled i in seg(I) (source) and j in seg(Î)
(edit), pixels carrying the ignore label in either map excluded, and t_c = sum_j n_cj::

    fwIoU = sum_c (t_c / sum_k t_k) * n_cc / (t_c + sum_i n_ic - n_cc)

(docs/design.md §5). Classes absent from seg(I) have zero weight. Two numbers are reported: the mean of
per-frame fwIoU and the fwIoU of the confusion matrix summed over all frames ("pooled"); the paper
defines fwIoU per image pair and does not say how it aggregates a sequence, so both are ours.
Label maps can be given directly (:func:`sem_cs`, or :class:`SemanticConsistency` with
``segmenter=None``); otherwise a segmenter callable ``segment(images [B, H, W, 3] float in [0, 1])
-> labels [B, H, W] int`` is injected, or named from the model store (ADE20K SegFormer /
UperNet-ConvNeXt, see :mod:`wcbench.metrics.semantic.segmenter`). No torch is imported here.
"""

from __future__ import annotations

import hashlib
import json
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np

from wcbench.core.models.store import ModelStore, StoreBacked
from wcbench.core.options import Option, Range
from wcbench.metrics.base import (
    Metric,
    MetricContext,
    MetricValue,
    as_float_image_pair,
    finite_or_none,
    python_object_option,
)
from wcbench.metrics.semantic.loading import BACKENDS, load_segmenter
from wcbench.metrics.semantic.segmenter import SPEC_FILE

__all__ = [
    "DEFAULT_SEGMENTER",
    "SemanticConsistency",
    "confusion_matrices",
    "confusion_matrix",
    "fwiou",
    "sem_cs",
]

#: Segmenter of the registered metric. SegFormer-b5 (ADE20K, 51.0 mIoU) is the strongest of the
#: semantic alternatives that runs in seconds per frame on a CPU; the paper's panoptic
#: ConvNeXt-XL has no public semantic checkpoint in these formats (``upernet-convnext-xlarge-ade``
#: is the closest, ~20x slower).
DEFAULT_SEGMENTER = "segformer-b5-ade"
ADE20K_CLASSES = 150

Segmenter = Callable[[np.ndarray], np.ndarray]


def _check_labels(labels0: Any, labels1: Any) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(labels0), np.asarray(labels1)
    for name, x in (("labels0", a), ("labels1", b)):
        if not (np.issubdtype(x.dtype, np.integer) or x.dtype == np.bool_):
            raise ValueError(f"{name}: expected integer label maps, got dtype {x.dtype}")
        if x.ndim not in (2, 3):
            raise ValueError(f"{name}: expected label maps [H, W] or [B, H, W], got shape {x.shape}")
    if a.shape != b.shape:
        raise ValueError(f"labels0 has shape {a.shape} but labels1 has shape {b.shape}")
    return (a[None], b[None]) if a.ndim == 2 else (a, b)


def confusion_matrices(
    labels0: np.ndarray, labels1: np.ndarray, *, num_classes: int, ignore_index: int | None = 255
) -> np.ndarray:
    """Per-frame confusion matrices n[b, i, j] = #pixels with labels0 == i and labels1 == j.

    Parameters
    ----------
    labels0, labels1 : ndarray [B, H, W] or [H, W], integer
        Class ids in [0, num_classes), or ``ignore_index``. labels0 is seg(source), labels1 is seg(edit).
    num_classes : int
    ignore_index : int or None
        Pixels with this label in either map are not counted (``None``: count all).

    Returns
    -------
    ndarray [B, num_classes, num_classes], int64

    Raises
    ------
    ValueError
        On non-integer or mismatched label maps, or a label outside [0, num_classes) that is not
        ``ignore_index``.
    """
    a, b = _check_labels(labels0, labels1)
    k = int(num_classes)
    if k < 1:
        raise ValueError(f"num_classes must be >= 1, got {num_classes}")
    n_frames = a.shape[0]
    a2, b2 = a.reshape(n_frames, -1), b.reshape(n_frames, -1)
    valid = None if ignore_index is None else (a2 != ignore_index) & (b2 != ignore_index)
    for name, x in (("labels0", a2), ("labels1", b2)):
        _check_range(x, valid, k=k, ignore_index=ignore_index, name=name)
    # One bincount over (frame, i, j) bins f k^2 + i k + j; ignored pixels go to one extra bin that is
    # dropped (selecting the valid pixels of every array costs several passes over 1080p batches).
    # int32 halves the memory traffic of int64 whenever the bins fit.
    n_bins = n_frames * k * k
    dtype = np.int32 if n_bins < np.iinfo(np.int32).max else np.int64
    idx = a2.astype(dtype)
    idx *= k
    idx += b2.astype(dtype)
    idx += (np.arange(n_frames, dtype=dtype) * (k * k))[:, None]
    if valid is not None:
        idx[~valid] = n_bins  # whatever wrapped-around value an ignored pixel produced, it is replaced
    return np.bincount(idx.ravel(), minlength=n_bins + 1)[:n_bins].reshape(n_frames, k, k)


def _check_range(x: np.ndarray, valid: np.ndarray | None, *, k: int, ignore_index: int | None, name: str) -> None:
    """Raise unless every counted label of ``x`` is in [0, k) (the message names the worst one)."""
    if x.size == 0 or (x.min() >= 0 and x.max() < k):  # the common case: two cheap passes
        return
    bad = (x < 0) | (x >= k)
    if valid is not None:
        bad &= valid
    if bad.any():
        values = x[bad]
        worst = int(values.min()) if values.min() < 0 else int(values.max())
        raise ValueError(f"{name}: label {worst} is outside [0, {k}) and is not the ignore label {ignore_index}")


def confusion_matrix(
    labels0: np.ndarray, labels1: np.ndarray, *, num_classes: int, ignore_index: int | None = 255
) -> np.ndarray:
    """The confusion matrix [num_classes, num_classes] (int64) summed over frames.

    See :func:`confusion_matrices` for the parameters.
    """
    return confusion_matrices(labels0, labels1, num_classes=num_classes, ignore_index=ignore_index).sum(0)


def fwiou(confusion: np.ndarray) -> float:
    """Frequency-weighted IoU of a confusion matrix (rows: reference labels, columns: compared labels).

    Parameters
    ----------
    confusion : ndarray [K, K]
        Pixel counts.

    Returns
    -------
    float
        In [0, 1]; NaN when the matrix is empty (every pixel ignored).

    Raises
    ------
    ValueError
        On a matrix that is not square.
    """
    n = np.asarray(confusion, np.float64)
    if n.ndim != 2 or n.shape[0] != n.shape[1]:
        raise ValueError(f"confusion: expected a square matrix [K, K], got shape {n.shape}")
    t = n.sum(1)
    total = t.sum()
    if total <= 0:
        return float("nan")
    diag = np.diag(n)
    union = t + n.sum(0) - diag
    present = t > 0  # union >= t > 0 there; absent classes have zero weight
    # divide by the total last: identical maps then give exactly 1.0 (integer sums are exact)
    return float(np.sum(t[present] * diag[present] / union[present]) / total)


def sem_cs(
    labels0: np.ndarray,
    labels1: np.ndarray,
    *,
    num_classes: int,
    ignore_index: int | None = 255,
    reduction: str = "mean",
) -> float | np.ndarray:
    """Sem-CS (fwIoU) between label maps of the source (``labels0``) and the edit (``labels1``).

    Parameters
    ----------
    labels0, labels1 : ndarray [H, W] or [B, H, W], integer
        seg(source) and seg(edit).
    num_classes : int
        150 for ADE20K segmenters.
    ignore_index : int or None
        Label excluded from the counts in both maps.
    reduction : {"mean", "pooled", "none"}
        ``"mean"``: mean of per-frame fwIoU over frames with counted pixels; ``"pooled"``: fwIoU
        of the summed confusion matrix (the paper names neither aggregation: docs/design.md §5);
        ``"none"``: per-frame values [B].

    Returns
    -------
    float or ndarray [B]
        NaN where no pixel was counted.
    """
    if reduction not in ("mean", "pooled", "none"):
        raise ValueError(f"reduction must be 'mean', 'pooled' or 'none', got {reduction!r}")
    cms = confusion_matrices(labels0, labels1, num_classes=num_classes, ignore_index=ignore_index)
    if reduction == "pooled":
        return fwiou(cms.sum(0))
    per = np.array([fwiou(c) for c in cms])
    if reduction == "none":
        return per
    finite = per[np.isfinite(per)]
    return float(finite.mean()) if finite.size else float("nan")


_SEGMENTER_ALLOWED = ("a segmenter of the catalogue (`wcbench models list`), e.g. segformer-b0-ade "
                      "(Python API: also a segmenter callable)")


def _segmenter_option(value: Any) -> str | Segmenter:
    """A ``segmenter`` option's value: a name (whether the catalogue has it is
    :meth:`SemanticConsistency.check_options`'s) or a callable. ``None`` (label maps given directly)
    is the Python API's alone: an evaluation gives frames."""
    if (isinstance(value, str) and value) or callable(value):
        return value
    raise ValueError(f"expected {_SEGMENTER_ALLOWED}")


class SemanticConsistency(StoreBacked, Metric):
    """Sem-CS between the source frames and the edit: per-frame mean and pooled fwIoU.

    Parameters
    ----------
    segmenter : str, callable or None
        A model-store name (default :data:`DEFAULT_SEGMENTER`, loaded on first use), a callable
        ``segment(images [B, H, W, 3] float in [0, 1]) -> labels [B, H, W] int``, or ``None``:
        then :meth:`update` takes label maps [B, H, W] (``pred`` = seg(edit), ``source`` = seg(source)).
    num_classes : int
        Classes of the segmenter (150 for ADE20K).
    ignore_index : int or None
        Label excluded from the counts (255, ADE20K's "other" after label reduction).
    backend : {"onnx", "torch"}
        How a named segmenter runs.
    store : ModelStore, optional
        Where a named segmenter's weights are looked up (default ``ModelStore()``).
    segmenter_name : str, optional
        Name recorded for an injected callable (default: its ``name`` attribute or type name).
    source_cache : int
        Segmentations of this many distinct source frames are kept (keyed by a sha256 of the frame;
        uint8 when the classes fit, 2.5 MB per 1920x1280 frame), so scoring several weathers or
        methods against one source with the same metric object segments it once.
    """

    name = "sem_cs"
    description = "Sem-CS: fwIoU between ADE20K segmentations of the source and the edited frame"
    outputs = ("sem_cs", "sem_cs_pooled")
    higher_is_better = True
    compares_content = True
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "segmenter": Option("segmenter", "custom", "ADE20K segmenter of the model store that segments source "
                            "and edit", default=DEFAULT_SEGMENTER, check=_segmenter_option, allowed=_SEGMENTER_ALLOWED),
        "num_classes": Option("num_classes", "int", "classes of the segmenter (150 for ADE20K)",
                              default=ADE20K_CLASSES, range=Range(1)),
        "ignore_index": Option("ignore_index", "int", "label left out of the counts in both maps (ADE20K's "
                               "'other'); null: none", default=255, range=Range(0), nullable=True),
        "backend": Option("backend", "str", "how a named segmenter runs: onnx (onnxruntime), torch (needs the "
                          "[model] extra)", default="onnx", choices=BACKENDS),
        "store": python_object_option("store", "model store the weights are read from (default $WCBENCH_MODELS)",
                                      accepts=lambda v: isinstance(v, ModelStore), what="a ModelStore"),
        "segmenter_name": Option("segmenter_name", "str", "name recorded for an injected segmenter callable; "
                                 "null: its name attribute", nullable=True),
        "source_cache": Option("source_cache", "int", "segmentations of this many distinct source frames kept "
                               "(a source scored for several weathers is segmented once)", default=32,
                               range=Range(0)),
    }

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """A ``segmenter`` named is an entry of the catalogue (of ``store`` when one is given)."""
        if isinstance(options.get("segmenter"), str):
            cls.check_model_option("segmenter", options["segmenter"], options.get("store"),
                                   example="segformer-b0-ade")

    def __init__(
        self,
        segmenter: str | Segmenter | None = DEFAULT_SEGMENTER,
        *,
        num_classes: int = ADE20K_CLASSES,
        ignore_index: int | None = 255,
        backend: str = "onnx",
        store: Any = None,
        segmenter_name: str | None = None,
        source_cache: int = 32,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
        self.num_classes, self.ignore_index, self.backend = int(num_classes), ignore_index, backend
        self._store = store
        self._model_name: str | None = segmenter if isinstance(segmenter, str) else None
        self._segment: Segmenter | None = None if isinstance(segmenter, str) else segmenter
        if segmenter is None:
            self.segmenter_name = "label maps given directly"
        elif isinstance(segmenter, str):
            self.segmenter_name = segmenter
        else:
            self.segmenter_name = segmenter_name or str(getattr(segmenter, "name", type(segmenter).__name__))
        self._cache_size = int(source_cache)
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self.reset()

    @property
    def labels_mode(self) -> bool:
        """True when :meth:`update` takes label maps instead of images."""
        return self._model_name is None and self._segment is None

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """The base rules (fog, frame count), then: the named segmenter's weights are missing."""
        reason = super().skip_reason(ctx)
        if reason is not None or self._model_name is None or self._segment is not None:
            return reason
        store = self.store
        missing = store.missing_reason(self._model_name)
        if missing is None:
            return None
        hint = store.entry(self._model_name).source.hint
        return f"{missing} {hint}; converting needs the [model] extra (torch), scoring does not"

    def required_models(self) -> tuple[str, ...]:
        """The segmenter's entry when it is named (none for an injected one or the lidar labels)."""
        return (self._model_name,) if self._model_name is not None and self._segment is None else ()

    def _segmenter(self) -> Segmenter:
        if self._segment is None:
            assert self._model_name is not None  # labels mode never segments
            self._segment = load_segmenter(self._model_name, backend=self.backend, store=self.store)
        return self._segment

    def _named_model_record(self) -> dict[str, Any]:
        """The converted model's spec and file hashes, read without loading the network."""
        if self._model_name is None:
            return {}
        try:
            store = self.store
            if not store.available(self._model_name):
                return {}
            with open(store.dir(self._model_name) / SPEC_FILE, encoding="utf-8") as fh:
                record = dict(json.load(fh))
            record["weights_verified"] = store.source_verified(self._model_name)
            return record
        except (OSError, ValueError):
            return {}

    def config(self) -> dict[str, Any]:
        """Segmenter (name, backend, spec and file hashes when known), class count, ignore label."""
        cfg: dict[str, Any] = {
            "segmenter": self.segmenter_name,
            "num_classes": self.num_classes,
            "ignore_index": self.ignore_index,
        }
        if self._model_name is not None:
            cfg["backend"] = self.backend
            cfg["model"] = self._named_model_record()
        elif self._segment is not None and callable(getattr(self._segment, "config", None)):
            cfg["model"] = self._segment.config()  # type: ignore[attr-defined]
        return cfg

    def reset(self) -> None:
        """Forget the per-frame values and the pooled confusion matrix (the source cache stays)."""
        self._per_frame: list[float] = []
        self._pooled = np.zeros((self.num_classes, self.num_classes), np.int64)

    def update_labels(self, labels_edit: np.ndarray, labels_source: np.ndarray) -> None:
        """Accumulate label maps [B, H, W] (or [H, W]) of the edit and of its source frames."""
        cms = confusion_matrices(
            labels_source, labels_edit, num_classes=self.num_classes, ignore_index=self.ignore_index
        )
        self._per_frame.extend(fwiou(c) for c in cms)
        self._pooled += cms.sum(0)

    def _segment_checked(self, images: np.ndarray, *, name: str) -> np.ndarray:
        labels = np.asarray(self._segmenter()(images))
        if labels.shape != images.shape[:3]:
            raise ValueError(
                f"segmenter {self.segmenter_name!r} returned labels of shape {labels.shape} "
                f"for {name} images of shape {images.shape}; expected {images.shape[:3]}"
            )
        return labels

    def _segment_source(self, source: np.ndarray) -> np.ndarray:
        out = []
        for frame in source:
            key = (
                hashlib.sha256(np.ascontiguousarray(frame).tobytes()).hexdigest()
                + str(frame.shape)
                + str(frame.dtype)
            )
            if key in self._cache:
                self._cache.move_to_end(key)
                out.append(self._cache[key])
                continue
            lab = self._segment_checked(frame[None], name="source")[0]
            if self._cache_size > 0:
                small = lab.size and 0 <= lab.min() and lab.max() < 256
                self._cache[key] = lab.astype(np.uint8) if small else lab
                while len(self._cache) > self._cache_size:
                    self._cache.popitem(last=False)
            out.append(lab)
        return np.stack(out)

    def update(
        self,
        pred: np.ndarray,
        *,
        source: np.ndarray | None = None,
        reference: np.ndarray | None = None,
    ) -> None:
        """Accumulate a batch: edited frames ``pred`` against their ``source`` frames.

        Parameters
        ----------
        pred : ndarray [B, H, W, 3] float in [0, 1], or [B, H, W] int labels in labels mode
        source : ndarray, same layout as ``pred``
            Required.
        reference : ignored
        """
        if source is None:
            raise ValueError("sem_cs: the source frames are required")
        if self.labels_mode:
            self.update_labels(pred, source)
            return
        p, s = as_float_image_pair(pred, source, names=("pred", "source"))
        self.update_labels(self._segment_checked(p, name="pred"), self._segment_source(s))

    def _variant(self, form: str) -> str:
        how = (
            "label maps given directly"
            if self.labels_mode
            else f"segmenter {self.segmenter_name}" + (f" ({self.backend})" if self._model_name else "")
        )
        labels = f"{self.num_classes} classes, ignore label {self.ignore_index}"
        return f"{form}, fwIoU(seg(source), seg(edit)); {how}; {labels}"

    def __getstate__(self) -> dict[str, Any]:
        # an onnxruntime session does not pickle; a named segmenter is reloaded on demand
        state = self.__dict__.copy()
        if self._model_name is not None:
            state["_segment"] = None
        state["_cache"] = OrderedDict()  # a cache, not state: not worth pickling
        return state

    def compute(self) -> dict[str, MetricValue]:
        """``sem_cs``: mean of per-frame fwIoU; ``sem_cs_pooled``: fwIoU of the summed matrix."""
        per = np.asarray(self._per_frame, np.float64)
        finite = per[np.isfinite(per)]
        empty = int(per.size - finite.size)
        extra = {
            "frames": int(per.size),
            "frames_without_counted_pixels": empty,
            "pixels": int(self._pooled.sum()),
        }
        mean = float(finite.mean()) if finite.size else float("nan")
        why = "no frames" if per.size == 0 else "every pixel carried the ignore label"
        return {
            "sem_cs": MetricValue.from_number(
                mean,
                nonfinite_reason=why,
                per_frame=finite_or_none(per),
                variant=self._variant("mean over frames"),
                extra=extra,
            ),
            "sem_cs_pooled": MetricValue.from_number(
                fwiou(self._pooled),
                nonfinite_reason=why,
                variant=self._variant("pooled confusion matrix over frames"),
                extra=extra,
            ),
        }
