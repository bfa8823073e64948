"""ONNX export of the metrics' torch networks (CLIP towers, segmenters, LPIPS): one opset, one way.

Needs torch (the ``[model]`` extra); the scoring side runs the exported graphs with onnxruntime.
Uses torch's TorchScript-based exporter (``dynamo=False``): it needs no extra package, and every
network here is a plain static graph. Files are written atomically.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence

import torch

from wcbench.core.storage import atomic_path

#: Opset 17 has LayerNormalization as one op (faster in onnxruntime than its decomposition) and is
#: run by onnxruntime >= 1.17.
ONNX_OPSET = 17


def export_onnx(
    module: torch.nn.Module,
    example_inputs: tuple[torch.Tensor, ...],
    path: str | os.PathLike[str],
    *,
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_axes: Mapping[str, Mapping[int, str]],
    opset: int = ONNX_OPSET,
) -> None:
    """Trace ``module`` on ``example_inputs`` and write the graph to ``path`` (atomically).

    Parameters
    ----------
    module : torch.nn.Module
        In eval mode, float32.
    example_inputs : tuple of Tensor
        Tracing inputs; pass distinct tensors (the tracer fuses one tensor passed twice).
    path : path-like
        Output ``.onnx`` file.
    input_names, output_names : sequence of str
        Graph input and output names.
    dynamic_axes : mapping
        ``{name: {axis: label}}`` of the axes left symbolic (batch, height, width...).
    opset : int
        ONNX opset version.
    """
    with atomic_path(path, suffix=".onnx") as tmp, torch.no_grad(), warnings.catch_warnings():
        # the legacy exporter announces its own deprecation, and tracing notes constant shapes
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        warnings.filterwarnings("ignore", category=UserWarning, module=r"torch\.onnx")
        torch.onnx.export(
            module,
            example_inputs,
            str(tmp),
            dynamo=False,
            input_names=list(input_names),
            output_names=list(output_names),
            dynamic_axes={k: dict(v) for k, v in dynamic_axes.items()},
            opset_version=opset,
            do_constant_folding=True,
        )
