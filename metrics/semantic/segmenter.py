"""Torch-free segmenters for Sem-CS: HF-style preprocessing, onnxruntime, exact upsample + argmax.

A *segmenter* is any callable ``segment(images [B, H, W, 3] float in [0, 1]) -> labels [B, H, W]
int64``; :class:`OnnxSegmenter` is the one scoring uses. It reproduces the ``transformers``
pipeline of the ADE20K SegFormer and UperNet-ConvNeXt checkpoints:

1. **Preprocess** (``SegformerImageProcessor``, which the hub configs of both families name, PIL
   path): quantise to uint8 (frames come from 8-bit PNGs), resize each frame to the network size
   (512x512 for SegFormer-b0..b4 and every UperNet-ConvNeXt, 640x640 for SegFormer-b5-640;
   *squashed*, the aspect ratio is not kept) with PIL's bilinear filter (antialiased when
   shrinking), scale by 1/255, normalise with the ImageNet mean (0.485, 0.456, 0.406) and std
   (0.229, 0.224, 0.225), HWC -> CHW.
2. **Network** (ONNX): logits [B, 150, h', w'] (stride 4 for SegFormer; UperNet upsamples to the
   network input inside the model, as ``transformers`` does).
3. **Post-process** (``post_process_semantic_segmentation`` with the frame size as target):
   bilinear upsampling of the logits to the frame size (``align_corners=False``), then argmax
   over classes (first maximum on ties). :func:`upsample_argmax` computes the same labels without
   materialising the [150, H, W] upsampled logits (1.5 GB for a 1920x1280 frame).

Converted models live in the model store (``wcbench models pull segformer-b0-ade``); each is a
folder with ``model.onnx`` and ``segmenter.json`` (see :mod:`wcbench.metrics.semantic.pytorch.backend`).
"""

from __future__ import annotations

import json
import os
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.image_io import to_uint8
from wcbench.core.imagenet import IMAGENET_MEAN, IMAGENET_STD

__all__ = [
    "SPEC_FILE",
    "OnnxSegmenter",
    "SegmenterSpec",
    "preprocess",
    "upsample_argmax",
]

#: File name of the spec inside a converted segmenter folder.
SPEC_FILE = "segmenter.json"
_PREPROCESSING = (
    "uint8 quantisation, PIL bilinear resize to input_size (aspect ratio not kept), /255, "
    "ImageNet mean/std; logits upsampled bilinearly (align_corners=False) to the frame size, argmax"
)


@dataclass(frozen=True)
class SegmenterSpec:
    """What a converted segmenter needs besides its network, stored as ``segmenter.json``.

    Attributes
    ----------
    arch : str
        ``"segformer"`` or ``"upernet-convnext"``.
    variant : str
        ``"b0"``..``"b5"``, ``"tiny"``..``"xlarge"`` or ``"custom"``.
    num_classes : int
        150 for ADE20K.
    input_size : (int, int)
        (height, width) every frame is resized to before the network.
    logits_stride : int
        Network output stride relative to ``input_size`` (4 for SegFormer, 1 for UperNet).
    mean, std : (float, float, float)
        Normalisation of RGB in [0, 1].
    """

    arch: str
    variant: str
    num_classes: int = 150
    input_size: tuple[int, int] = (512, 512)
    logits_stride: int = 1
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    preprocessing: str = field(default=_PREPROCESSING)
    #: The network's architecture settings (hidden sizes, depths, heads...), for the torch backend.
    architecture: dict[str, Any] = field(default_factory=dict, compare=False)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict (lists for tuples)."""
        return {
            "arch": self.arch,
            "variant": self.variant,
            "num_classes": self.num_classes,
            "input_size": list(self.input_size),
            "logits_stride": self.logits_stride,
            "mean": list(self.mean),
            "std": list(self.std),
            "preprocessing": self.preprocessing,
            "architecture": dict(self.architecture),
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SegmenterSpec:
        """Inverse of :meth:`to_json` (extra keys such as file hashes are ignored)."""
        return cls(
            arch=str(d["arch"]),
            variant=str(d["variant"]),
            num_classes=int(d["num_classes"]),
            input_size=(int(d["input_size"][0]), int(d["input_size"][1])),
            logits_stride=int(d.get("logits_stride", 1)),
            mean=tuple(float(v) for v in d.get("mean", IMAGENET_MEAN)),  # type: ignore[arg-type]
            std=tuple(float(v) for v in d.get("std", IMAGENET_STD)),  # type: ignore[arg-type]
            preprocessing=str(d.get("preprocessing", _PREPROCESSING)),
            architecture=dict(d.get("architecture", {})),
        )

    @classmethod
    def from_file(cls, path: str | os.PathLike[str]) -> SegmenterSpec:
        """Read a ``segmenter.json``.

        Raises
        ------
        ValueError
            On a file that is not a segmenter spec (names the file and the missing key).
        """
        try:
            return cls.from_json(json.loads(Path(path).read_text(encoding="utf-8")))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: not a segmenter spec ({exc!r})") from exc


def preprocess(
    images: np.ndarray,
    *,
    size: tuple[int, int],
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> np.ndarray:
    """Frames -> normalised network input, as ``SegformerImageProcessor`` (PIL backend) does.

    Parameters
    ----------
    images : ndarray [B, H, W, 3] or [H, W, 3]
        RGB, float in [0, 1] or uint8.
    size : (int, int)
        (height, width) of the network input.
    mean, std : 3 floats
        Normalisation applied to RGB in [0, 1].

    Returns
    -------
    ndarray [B, 3, height, width], float32

    Raises
    ------
    ValueError
        On a shape other than [B, H, W, 3] / [H, W, 3].
    """
    from PIL import Image

    a = np.asarray(images)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"images: expected [B, H, W, 3] or [H, W, 3], got shape {a.shape}")
    # the processor resizes 8-bit PIL images; our frames were 8-bit PNGs, so this is lossless for them
    a = to_uint8(a)
    h, w = int(size[0]), int(size[1])
    out = np.empty((a.shape[0], h, w, 3), np.float32)
    for b in range(a.shape[0]):
        out[b] = np.asarray(Image.fromarray(a[b]).resize((w, h), Image.Resampling.BILINEAR), np.float32)
    out *= np.float32(1.0 / 255.0)
    out -= np.asarray(mean, np.float32)
    out /= np.asarray(std, np.float32)
    return np.ascontiguousarray(out.transpose(0, 3, 1, 2))


def _linear_taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source indices i0, i1 [n_out] and weight of i1 [n_out] of torch's bilinear, align_corners=False."""
    scale = np.float32(n_in / n_out)
    src = np.maximum((np.arange(n_out, dtype=np.float32) + np.float32(0.5)) * scale - np.float32(0.5), 0)
    i0 = np.minimum(src.astype(np.int64), n_in - 1)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, (src - i0).astype(np.float32)


#: Boundary cells with at most this many candidate classes take the pruned path.
_MAX_CANDIDATES = 16


def _blend_argmax(
    lb: np.ndarray, r: np.ndarray, c: np.ndarray, taps: tuple[np.ndarray, ...], classes: np.ndarray | None
) -> np.ndarray:
    """Argmax over ``classes`` [n, K] (all classes when None) of the bilinear blend at pixels (r, c)."""
    y0, y1, wy, x0, x1, wx = taps
    fy, fx = wy[r, None], wx[c, None]
    if classes is None:
        v00, v01, v10, v11 = lb[y0[r], x0[c]], lb[y0[r], x1[c]], lb[y1[r], x0[c]], lb[y1[r], x1[c]]
    else:
        ry0, ry1, cx0, cx1 = y0[r, None], y1[r, None], x0[c, None], x1[c, None]
        v00, v01, v10, v11 = (
            lb[ry0, cx0, classes],
            lb[ry0, cx1, classes],
            lb[ry1, cx0, classes],
            lb[ry1, cx1, classes],
        )
    # same association as torch's CPU kernel: a row blend of two column blends
    best = ((1 - fy) * ((1 - fx) * v00 + fx * v01) + fy * ((1 - fx) * v10 + fx * v11)).argmax(-1)
    return best if classes is None else classes[np.arange(len(best)), best]


def upsample_argmax(logits: np.ndarray, size: tuple[int, int], *, chunk: int = 1 << 14) -> np.ndarray:
    """``argmax_c bilinear_upsample(logits)[c]`` without materialising the upsampled logits.

    Equals ``torch.nn.functional.interpolate(logits, size, mode="bilinear", align_corners=False)
    .argmax(1)`` (up to float rounding on near-ties; the first class wins exact ties). Each output
    pixel blends the four logit vectors at the corners of its low-resolution cell with convex
    weights, so:

    - where the corners share one argmax, every blend has that argmax (no arithmetic at all);
    - elsewhere (class boundaries) only classes whose best corner value reaches the cell's
      ``max_c min_corners`` can win; the blend is computed for those candidates (all classes when a
      cell has more than 16).

    Parameters
    ----------
    logits : ndarray [B, C, h, w]
    size : (int, int)
        Output (H, W).
    chunk : int
        Boundary pixels blended at once (bounds memory at about 8 * chunk * C floats).

    Returns
    -------
    ndarray [B, H, W], int64

    Raises
    ------
    ValueError
        On logits that are not 4-D.
    """
    lg = np.asarray(logits)
    if lg.ndim != 4:
        raise ValueError(f"logits: expected [B, C, h, w], got shape {lg.shape}")
    n_b, _, h, w = lg.shape
    y0, y1, wy = _linear_taps(h, int(size[0]))
    x0, x1, wx = _linear_taps(w, int(size[1]))
    taps = (y0, y1, wy, x0, x1, wx)
    out = np.empty((n_b, int(size[0]), int(size[1])), np.int64)
    for b in range(n_b):
        lb = np.ascontiguousarray(lg[b].transpose(1, 2, 0), dtype=np.float32)  # [h, w, C]
        am = lb.argmax(-1)  # [h, w]
        lab = am[y0][:, x0]
        agree = (lab == am[y0][:, x1]) & (lab == am[y1][:, x0]) & (lab == am[y1][:, x1])
        rows, cols = np.nonzero(~agree)
        if rows.size:
            # a cell is named by its top-left corner (the other corners are +1, clamped)
            cells, pix_cell = np.unique(y0[rows] * w + x0[cols], return_inverse=True)
            cy, cx = cells // w, cells % w
            cy1, cx1 = np.minimum(cy + 1, h - 1), np.minimum(cx + 1, w - 1)
            corners = np.stack([lb[cy, cx], lb[cy, cx1], lb[cy1, cx], lb[cy1, cx1]])  # [4, U, C]
            upper = corners.max(0)  # no blend of class c exceeds its best corner
            lower = corners.min(0).max(-1)  # some class reaches this everywhere in the cell
            n_cand = (upper >= lower[:, None]).sum(-1)  # [U]
            k = int(min(n_cand.max(), _MAX_CANDIDATES))
            # top-k by upper bound holds every candidate of cells with n_cand <= k; ascending class
            # order inside keeps torch's first-maximum rule on exact ties
            cand = np.sort(np.argsort(-upper, axis=1, kind="stable")[:, :k], axis=1)
            pruned = n_cand[pix_cell] <= k
            for s in range(0, rows.size, chunk):
                r, c, p, pc = (
                    rows[s : s + chunk],
                    cols[s : s + chunk],
                    pruned[s : s + chunk],
                    pix_cell[s : s + chunk],
                )
                if p.any():
                    lab[r[p], c[p]] = _blend_argmax(lb, r[p], c[p], taps, cand[pc[p]])
                if not p.all():
                    lab[r[~p], c[~p]] = _blend_argmax(lb, r[~p], c[~p], taps, None)
        out[b] = lab
    return out


class LogitsSegmenter(ABC):
    """Labels from a backend's logits, one frame at a time (shared by the ONNX and torch backends)."""

    @abstractmethod
    def logits(self, images: np.ndarray) -> np.ndarray:
        """Network logits [B, C, h', w'] (float32) of images [B, H, W, 3] in [0, 1]."""

    def __call__(self, images: np.ndarray) -> np.ndarray:
        """Per-pixel ADE20K labels [B, H, W] int64 of images [B, H, W, 3] in [0, 1]."""
        imgs = np.asarray(images)
        if imgs.ndim != 4 or imgs.shape[-1] != 3:
            raise ValueError(f"images: expected [B, H, W, 3], got shape {imgs.shape}")
        out = np.empty(imgs.shape[:3], np.int64)
        for b in range(imgs.shape[0]):  # one frame at a time bounds the logits' memory
            out[b] = upsample_argmax(self.logits(imgs[b : b + 1]), imgs.shape[1:3])[0]
        return out


class OnnxSegmenter(LogitsSegmenter):
    """``segment(images [B, H, W, 3] in [0, 1]) -> labels [B, H, W] int64`` with onnxruntime.

    Parameters
    ----------
    model_dir : str or path-like
        A converted segmenter folder (``model.onnx`` + ``segmenter.json``).
    name : str, optional
        Recorded in :meth:`config` (default: the folder name).
    threads : int, optional
        onnxruntime intra-op threads (default: onnxruntime's choice, all cores).
    weights_verified : bool
        Whether the folder's weights came from a file matching a pinned sha256 (the model store's
        ``source_verified``; :func:`~wcbench.metrics.semantic.loading.load_segmenter` passes it).
        A folder outside the store is unverified. Recorded in :meth:`config`, so every Sem-CS
        number made with unverified weights says so (docs/design.md §6).

    Raises
    ------
    FileNotFoundError
        When ``model.onnx`` or ``segmenter.json`` is missing.
    """

    def __init__(
        self,
        model_dir: str | os.PathLike[str],
        *,
        name: str | None = None,
        threads: int | None = None,
        weights_verified: bool = False,
    ):
        import onnxruntime as ort

        d = Path(model_dir)
        for f in ("model.onnx", SPEC_FILE):
            if not (d / f).is_file():
                raise FileNotFoundError(f"{d}: converted segmenter folder lacks {f}")
        self.spec = SegmenterSpec.from_file(d / SPEC_FILE)
        self.name = name or d.name
        self.model_dir = d
        self.weights_verified = bool(weights_verified)
        opts = ort.SessionOptions()
        if threads is not None:
            opts.intra_op_num_threads = int(threads)
        self.session = ort.InferenceSession(str(d / "model.onnx"), opts, providers=["CPUExecutionProvider"])
        record = json.loads((d / SPEC_FILE).read_text(encoding="utf-8"))
        self._onnx_sha256 = record.get("files", {}).get("model.onnx")

    def logits(self, images: np.ndarray) -> np.ndarray:
        """Network logits [B, C, h', w'] (float32) of images [B, H, W, 3] in [0, 1]."""
        x = preprocess(images, size=self.spec.input_size, mean=self.spec.mean, std=self.spec.std)
        return self.session.run(["logits"], {"pixel_values": x})[0]

    def config(self) -> dict[str, Any]:
        """What produced the labels (recorded with every Sem-CS number)."""
        return {
            "segmenter": self.name,
            "backend": "onnxruntime",
            "onnx_sha256": self._onnx_sha256,
            "weights_verified": self.weights_verified,
            **self.spec.to_json(),
        }
