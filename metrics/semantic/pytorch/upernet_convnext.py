"""UperNet with a ConvNeXt backbone (tiny..xlarge) in compact torch code, for Sem-CS.

Mirrors ``transformers.UperNetForSemanticSegmentation`` with a ``ConvNextBackbone`` at inference
(the ``openmmlab/upernet-convnext-*`` ADE20K checkpoints, converted from mmsegmentation). Module
and parameter names are those of the hub checkpoints (``backbone.encoder.stages.0.layers.0.dwconv
.weight``, ``decode_head.psp_modules.0.1.conv.weight`` ...); the auxiliary FCN head only serves
training and its tensors are dropped on load.

Forward: normalised ``pixel_values`` [B, 3, h, w] -> logits [B, num_labels, h, w]: like
``transformers``, the stride-4 head output is upsampled (bilinear, ``align_corners=False``) to the
network input size inside the model; the image processor's post-processing then resizes again to
the frame size (see :mod:`wcbench.metrics.semantic.segmenter`).

This module imports torch: the evaluation side reaches it only through the ONNX export.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from wcbench.metrics.semantic.pytorch.checkpoints import (
    check_variant,
    load_checked_state,
    read_state_dict,
    stage_depths,
)
from wcbench.metrics.semantic.pytorch.convert import convert_checkpoint

__all__ = [
    "CONVNEXT_CONFIGS",
    "UperNetConvNext",
    "UperNetConvNextConfig",
    "convert_hf_upernet_convnext",
    "load_upernet_convnext",
    "upernet_config_from_state_dict",
]


@dataclass(frozen=True)
class UperNetConvNextConfig:
    """Architecture of one UperNet-ConvNeXt; the defaults are ConvNeXt-T with an ADE20K head.

    Attributes
    ----------
    hidden_sizes : tuple of int
        Channels of the four ConvNeXt stages.
    depths : tuple of int
        ConvNeXt blocks per stage.
    channels : int
        UperNet head width (``UperNetConfig.hidden_size``, 512 in every released checkpoint).
    pool_scales : tuple of int
        Pyramid pooling output sizes.
    num_labels : int
        Output classes (150 for ADE20K).
    """

    hidden_sizes: tuple[int, int, int, int] = (96, 192, 384, 768)
    depths: tuple[int, int, int, int] = (3, 3, 9, 3)
    channels: int = 512
    pool_scales: tuple[int, ...] = (1, 2, 3, 6)
    num_labels: int = 150
    num_channels: int = 3
    patch_size: int = 4


#: ConvNeXt variants (Liu et al. 2022) as used by ``openmmlab/upernet-convnext-*``.
CONVNEXT_CONFIGS: dict[str, UperNetConvNextConfig] = {
    "tiny": UperNetConvNextConfig(),
    "small": UperNetConvNextConfig(depths=(3, 3, 27, 3)),
    "base": UperNetConvNextConfig(hidden_sizes=(128, 256, 512, 1024), depths=(3, 3, 27, 3)),
    "large": UperNetConvNextConfig(hidden_sizes=(192, 384, 768, 1536), depths=(3, 3, 27, 3)),
    "xlarge": UperNetConvNextConfig(hidden_sizes=(256, 512, 1024, 2048), depths=(3, 3, 27, 3)),
}


class _LayerNorm2d(nn.LayerNorm):
    """LayerNorm over the channels of [B, C, H, W] (ConvNeXt's ``channels_first``), eps 1e-6."""

    def __init__(self, ch: int):
        super().__init__(ch, eps=1e-6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.permute(0, 2, 3, 1)).permute(0, 3, 1, 2)


class _Embeddings(nn.Module):
    def __init__(self, cfg: UperNetConvNextConfig):
        super().__init__()
        c = cfg.hidden_sizes[0]
        self.patch_embeddings = nn.Conv2d(
            cfg.num_channels, c, kernel_size=cfg.patch_size, stride=cfg.patch_size
        )
        self.layernorm = _LayerNorm2d(c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layernorm(self.patch_embeddings(x))


class _Block(nn.Module):
    """7x7 depthwise conv -> LayerNorm -> Linear(4C) -> exact GELU -> Linear(C) -> layer scale, residual."""

    def __init__(self, dim: int):
        super().__init__()
        self.dwconv = nn.Conv2d(dim, dim, kernel_size=7, padding=3, groups=dim)
        self.layernorm = nn.LayerNorm(dim, eps=1e-6)
        self.pwconv1 = nn.Linear(dim, 4 * dim)
        self.pwconv2 = nn.Linear(4 * dim, dim)
        self.layer_scale_parameter = nn.Parameter(torch.full((dim,), 1e-6))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.dwconv(x).permute(0, 2, 3, 1)  # [B, H, W, C]
        y = self.pwconv2(F.gelu(self.pwconv1(self.layernorm(y))))
        return x + (self.layer_scale_parameter * y).permute(0, 3, 1, 2)


class _Stage(nn.Module):
    def __init__(self, in_ch: int, out_ch: int, depth: int, downsample: bool):
        super().__init__()
        self.downsampling_layer = nn.ModuleList(
            [_LayerNorm2d(in_ch), nn.Conv2d(in_ch, out_ch, kernel_size=2, stride=2)] if downsample else []
        )
        self.layers = nn.ModuleList(_Block(out_ch) for _ in range(depth))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for m in self.downsampling_layer:
            x = m(x)
        for m in self.layers:
            x = m(x)
        return x


class _Encoder(nn.Module):
    def __init__(self, cfg: UperNetConvNextConfig):
        super().__init__()
        ins = (cfg.hidden_sizes[0], *cfg.hidden_sizes[:-1])
        self.stages = nn.ModuleList(
            _Stage(i, o, d, downsample=k > 0)
            for k, (i, o, d) in enumerate(zip(ins, cfg.hidden_sizes, cfg.depths))
        )


class _Backbone(nn.Module):
    def __init__(self, cfg: UperNetConvNextConfig):
        super().__init__()
        self.embeddings = _Embeddings(cfg)
        self.encoder = _Encoder(cfg)
        self.hidden_states_norms = nn.ModuleDict(
            {f"stage{k + 1}": _LayerNorm2d(c) for k, c in enumerate(cfg.hidden_sizes)}
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = self.embeddings(x)
        feats = []
        for k, stage in enumerate(self.encoder.stages):
            x = stage(x)
            feats.append(self.hidden_states_norms[f"stage{k + 1}"](x))  # strides 4, 8, 16, 32
        return feats


class _ConvModule(nn.Module):
    """conv (no bias) -> BatchNorm (running statistics) -> ReLU."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, padding: int = 0):
        super().__init__()
        self.conv = nn.Conv2d(in_ch, out_ch, kernel_size=kernel_size, padding=padding, bias=False)
        self.batch_norm = nn.BatchNorm2d(out_ch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.batch_norm(self.conv(x)))


def _adaptive_avg_pool2d(x: torch.Tensor, size: int) -> torch.Tensor:
    """``F.adaptive_avg_pool2d(x, size)`` as two matmuls, so the ONNX export keeps H and W dynamic.

    The exporter turns adaptive pooling into a fixed AveragePool, impossible when ``size`` does not
    divide the map (3 and 6 do not divide 16). Bin k covers [floor(k n / s), ceil((k + 1) n / s)),
    torch's definition.
    """

    def weights(n: int) -> torch.Tensor:  # [size, n]; n is a traced size during ONNX export
        k = torch.arange(size, device=x.device)
        start, end = (k * n) // size, ((k + 1) * n + size - 1) // size
        j = torch.arange(n, device=x.device)
        m = ((j[None, :] >= start[:, None]) & (j[None, :] < end[:, None])).to(x.dtype)
        return m / m.sum(dim=1, keepdim=True)

    return weights(x.shape[2]) @ x @ weights(x.shape[3]).transpose(0, 1)  # [B, C, size, size]


class _PoolingBlock(nn.Module):
    # the checkpoint names the conv module "1" (index 0 is the parameter-free adaptive pooling)
    def __init__(self, scale: int, in_ch: int, ch: int):
        super().__init__()
        self.scale = scale
        self.add_module("1", _ConvModule(in_ch, ch, kernel_size=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        conv: nn.Module = getattr(self, "1")
        return conv(_adaptive_avg_pool2d(x, self.scale))


class _UperHead(nn.Module):
    """Pyramid pooling on the deepest map + FPN over all four, fused at stride 4."""

    def __init__(self, cfg: UperNetConvNextConfig):
        super().__init__()
        ch, ins = cfg.channels, cfg.hidden_sizes
        self.psp_modules = nn.ModuleList(_PoolingBlock(s, ins[-1], ch) for s in cfg.pool_scales)
        self.bottleneck = _ConvModule(ins[-1] + len(cfg.pool_scales) * ch, ch, kernel_size=3, padding=1)
        self.lateral_convs = nn.ModuleList(_ConvModule(c, ch, kernel_size=1) for c in ins[:-1])
        self.fpn_convs = nn.ModuleList(_ConvModule(ch, ch, kernel_size=3, padding=1) for _ in ins[:-1])
        self.fpn_bottleneck = _ConvModule(len(ins) * ch, ch, kernel_size=3, padding=1)
        self.classifier = nn.Conv2d(ch, cfg.num_labels, kernel_size=1)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        top = feats[-1]
        psp = [top] + [
            F.interpolate(m(top), size=top.shape[2:], mode="bilinear", align_corners=False)
            for m in self.psp_modules
        ]
        laterals = [conv(f) for conv, f in zip(self.lateral_convs, feats)]
        laterals.append(self.bottleneck(torch.cat(psp, dim=1)))
        for i in range(len(laterals) - 1, 0, -1):  # top-down pathway
            laterals[i - 1] = laterals[i - 1] + F.interpolate(
                laterals[i], size=laterals[i - 1].shape[2:], mode="bilinear", align_corners=False
            )
        outs = [conv(x) for conv, x in zip(self.fpn_convs, laterals[:-1])] + [laterals[-1]]
        size = outs[0].shape[2:]
        outs = [outs[0]] + [
            F.interpolate(o, size=size, mode="bilinear", align_corners=False) for o in outs[1:]
        ]
        return self.classifier(self.fpn_bottleneck(torch.cat(outs, dim=1)))


class UperNetConvNext(nn.Module):
    """UperNet-ConvNeXt semantic segmentation network (inference only, no auxiliary head).

    Parameters
    ----------
    cfg : UperNetConvNextConfig
    """

    def __init__(self, cfg: UperNetConvNextConfig = CONVNEXT_CONFIGS["tiny"]):
        super().__init__()
        self.cfg = cfg
        self.backbone = _Backbone(cfg)
        self.decode_head = _UperHead(cfg)

    def forward(self, pixel_values: torch.Tensor) -> torch.Tensor:
        """Logits [B, num_labels, h, w] of normalised ``pixel_values`` [B, 3, h, w]."""
        logits = self.decode_head(self.backbone(pixel_values))
        return F.interpolate(logits, size=pixel_values.shape[2:], mode="bilinear", align_corners=False)


def upernet_config_from_state_dict(state: Mapping[str, torch.Tensor]) -> UperNetConvNextConfig:
    """Infer the architecture from checkpoint tensor shapes.

    Raises
    ------
    ValueError
        When the tensors are not an UperNet checkpoint with a ConvNeXt backbone.
    """
    try:
        hidden = [int(state["backbone.embeddings.patch_embeddings.weight"].shape[0])]
        hidden += [
            int(state[f"backbone.encoder.stages.{i}.downsampling_layer.1.weight"].shape[0]) for i in (1, 2, 3)
        ]
        cls = state["decode_head.classifier.weight"]
        patch = int(state["backbone.embeddings.patch_embeddings.weight"].shape[-1])
    except KeyError as exc:
        raise ValueError(f"not an UperNet-ConvNeXt checkpoint: no tensor {exc}") from None
    depths = stage_depths(state, r"backbone\.encoder\.stages\.{}\.layers\.(\d+)\.")
    n_pool = len({k.split(".")[2] for k in state if k.startswith("decode_head.psp_modules.")})
    if n_pool != 4:
        # the pooling sizes are not stored; every released checkpoint uses (1, 2, 3, 6)
        raise ValueError(
            f"expected 4 pyramid pooling branches (scales 1, 2, 3, 6), the checkpoint has {n_pool}"
        )
    return UperNetConvNextConfig(
        hidden_sizes=tuple(hidden),  # type: ignore[arg-type]
        depths=depths,  # type: ignore[arg-type]
        channels=int(cls.shape[1]),
        num_labels=int(cls.shape[0]),
        patch_size=patch,
    )


def load_upernet_convnext(
    path: str | Path, *, variant: str | None = None, config: UperNetConvNextConfig | None = None
) -> UperNetConvNext:
    """Build an :class:`UperNetConvNext` from a ``transformers`` checkpoint.

    Parameters
    ----------
    path : str or Path
        ``model.safetensors`` or ``pytorch_model.bin`` of an ``UperNetForSemanticSegmentation``
        with a ConvNeXt backbone, or a folder holding one.
    variant : {"tiny", "small", "base", "large", "xlarge"}, optional
        Check the checkpoint against this ConvNeXt variant.
    config : UperNetConvNextConfig, optional
        The architecture. Default: from the tensor shapes, with pyramid pooling scales (1, 2, 3, 6).

    Returns
    -------
    UperNetConvNext
        In eval mode, float32; the auxiliary head's tensors are ignored.

    Raises
    ------
    ValueError
        On a checkpoint of another architecture or variant, or missing/unexpected tensors.
    """
    state = {k: v for k, v in read_state_dict(path).items() if not k.startswith("auxiliary_head.")}
    cfg = config or upernet_config_from_state_dict(state)
    if variant is not None:
        check_variant(path, cfg, CONVNEXT_CONFIGS, variant, "ConvNeXt")
    model = UperNetConvNext(cfg)
    load_checked_state(model, state, path, "UperNet-ConvNeXt")
    return model.eval()


def convert_hf_upernet_convnext(
    sources: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    entry: Any = None,
    *,
    input_size: tuple[int, int] | None = None,
) -> Path:
    """Model-store converter: a hub UperNet-ConvNeXt checkpoint -> ``out_dir/{model.onnx, ...}``.

    Parameters
    ----------
    sources : path-like or a one-element sequence of path-like
        ``model.safetensors`` / ``pytorch_model.bin`` (or a folder) of ``openmmlab/upernet-convnext-*``.
    out_dir : str or Path
        Receives the files of :func:`wcbench.metrics.semantic.pytorch.backend.write_segmenter_dir`.
    entry : ModelEntry, optional
        The model-store entry; ``entry.options["input_size"]`` sets the input size.
    input_size : (int, int), optional
        (height, width) the image processor resizes to. Default 512x512: the hub conversion saved
        ``SegformerImageProcessor()`` defaults for every size (large/xlarge were trained on
        640x640 crops).

    Returns
    -------
    Path
        ``out_dir``.
    """
    return convert_checkpoint(
        sources, out_dir, entry, input_size, load=load_upernet_convnext, configs=CONVNEXT_CONFIGS,
        arch="upernet-convnext", logits_stride=1,
    )
