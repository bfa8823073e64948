"""SegFormer (MiT-b0..b5 encoder + all-MLP decoder) in compact torch code, for Sem-CS.

Mirrors ``transformers.SegformerForSemanticSegmentation`` at inference: the module and parameter
names are those of the checkpoints on the Hugging Face hub (``segformer.encoder.block.0.0.attention
.self.query.weight`` ...), which ``transformers`` 5 still writes with ``save_pretrained`` and maps
onto its renamed modules (``stages``/``q_proj``) on load; both spellings are accepted here.

Forward: normalised ``pixel_values`` [B, 3, h, w] -> logits [B, num_labels, ceil(h/4), ceil(w/4)]
(the decoder runs at stride 4; upsample to the frame size, then argmax, as
``SegformerImageProcessor.post_process_semantic_segmentation`` does; see
:mod:`wcbench.metrics.semantic.segmenter`).

This module imports torch: the evaluation side reaches it only through the ONNX export.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

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
    "SEGFORMER_CONFIGS",
    "SegFormer",
    "SegFormerConfig",
    "convert_hf_segformer",
    "load_segformer",
    "segformer_config_from_state_dict",
]


@dataclass(frozen=True)
class SegFormerConfig:
    """Architecture of one SegFormer; the defaults are MiT-b0 with an ADE20K head.

    Attributes
    ----------
    hidden_sizes : tuple of int
        Channels of the four encoder stages.
    depths : tuple of int
        Transformer blocks per stage.
    decoder_hidden_size : int
        Channels of the all-MLP decoder (256 for b0/b1, 768 for b2..b5).
    num_labels : int
        Output classes (150 for ADE20K).
    """

    hidden_sizes: tuple[int, int, int, int] = (32, 64, 160, 256)
    depths: tuple[int, int, int, int] = (2, 2, 2, 2)
    decoder_hidden_size: int = 256
    num_labels: int = 150
    num_attention_heads: tuple[int, int, int, int] = (1, 2, 5, 8)
    sr_ratios: tuple[int, int, int, int] = (8, 4, 2, 1)
    patch_sizes: tuple[int, int, int, int] = (7, 3, 3, 3)
    strides: tuple[int, int, int, int] = (4, 2, 2, 2)
    mlp_ratio: int = 4
    num_channels: int = 3


#: The published MiT variants (Xie et al. 2021, Table 6), ADE20K heads.
SEGFORMER_CONFIGS: dict[str, SegFormerConfig] = {
    "b0": SegFormerConfig(),
    "b1": SegFormerConfig(hidden_sizes=(64, 128, 320, 512)),
    "b2": SegFormerConfig(hidden_sizes=(64, 128, 320, 512), depths=(3, 4, 6, 3), decoder_hidden_size=768),
    "b3": SegFormerConfig(hidden_sizes=(64, 128, 320, 512), depths=(3, 4, 18, 3), decoder_hidden_size=768),
    "b4": SegFormerConfig(hidden_sizes=(64, 128, 320, 512), depths=(3, 8, 27, 3), decoder_hidden_size=768),
    "b5": SegFormerConfig(hidden_sizes=(64, 128, 320, 512), depths=(3, 6, 40, 3), decoder_hidden_size=768),
}


class _PatchEmbed(nn.Module):
    """Overlapping patch embedding: strided conv with padding k//2, then LayerNorm over channels."""

    def __init__(self, in_ch: int, out_ch: int, patch: int, stride: int):
        super().__init__()
        self.proj = nn.Conv2d(in_ch, out_ch, kernel_size=patch, stride=stride, padding=patch // 2)
        self.layer_norm = nn.LayerNorm(out_ch)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, int, int]:
        x = self.proj(x)  # [B, C, h, w]
        h, w = x.shape[2], x.shape[3]
        return self.layer_norm(x.flatten(2).transpose(1, 2)), h, w  # [B, h*w, C]


class _SelfAttention(nn.Module):
    """Efficient self-attention: keys/values from a sequence reduced by a strided conv (ratio sr)."""

    def __init__(self, dim: int, heads: int, sr: int):
        super().__init__()
        self.heads, self.sr_ratio = heads, sr
        self.query = nn.Linear(dim, dim)
        self.key = nn.Linear(dim, dim)
        self.value = nn.Linear(dim, dim)
        if sr > 1:
            self.sr = nn.Conv2d(dim, dim, kernel_size=sr, stride=sr)
            self.layer_norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        b, n, c = x.shape
        d = c // self.heads
        q = self.query(x).reshape(b, n, self.heads, d).transpose(1, 2)  # [B, heads, N, d]
        kv = x
        if self.sr_ratio > 1:
            kv = x.transpose(1, 2).reshape(b, c, h, w)
            kv = self.layer_norm(self.sr(kv).reshape(b, c, -1).transpose(1, 2))
        k = self.key(kv).reshape(b, -1, self.heads, d).transpose(1, 2)
        v = self.value(kv).reshape(b, -1, self.heads, d).transpose(1, 2)
        att = torch.softmax((q @ k.transpose(-1, -2)) * (d**-0.5), dim=-1)  # [B, heads, N, N']
        return (att @ v).transpose(1, 2).reshape(b, n, c)


class _Dense(nn.Module):
    def __init__(self, dim_in: int, dim_out: int):
        super().__init__()
        self.dense = nn.Linear(dim_in, dim_out)


class _Proj(nn.Module):
    def __init__(self, dim_in: int, dim_out: int):
        super().__init__()
        self.proj = nn.Linear(dim_in, dim_out)


class _AttentionBlock(nn.Module):
    def __init__(self, dim: int, heads: int, sr: int):
        super().__init__()
        self.self = _SelfAttention(dim, heads, sr)
        self.output = _Dense(dim, dim)

    def forward(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        return self.output.dense(self.self(x, h, w))


class _DWConv(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.dwconv = nn.Conv2d(dim, dim, 3, 1, 1, groups=dim)

    def forward(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        b, _, c = x.shape
        return self.dwconv(x.transpose(1, 2).reshape(b, c, h, w)).flatten(2).transpose(1, 2)


class _MixFFN(nn.Module):
    """fc -> 3x3 depthwise conv (implicit position) -> exact GELU -> fc."""

    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.dense1 = nn.Linear(dim, hidden)
        self.dwconv = _DWConv(hidden)
        self.dense2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        return self.dense2(F.gelu(self.dwconv(self.dense1(x), h, w)))


class _Layer(nn.Module):
    def __init__(self, dim: int, heads: int, sr: int, mlp_ratio: int):
        super().__init__()
        self.layer_norm_1 = nn.LayerNorm(dim)
        self.attention = _AttentionBlock(dim, heads, sr)
        self.layer_norm_2 = nn.LayerNorm(dim)
        self.mlp = _MixFFN(dim, dim * mlp_ratio)

    def forward(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        x = x + self.attention(self.layer_norm_1(x), h, w)
        return x + self.mlp(self.layer_norm_2(x), h, w)


class _Encoder(nn.Module):
    def __init__(self, cfg: SegFormerConfig):
        super().__init__()
        ins = (cfg.num_channels, *cfg.hidden_sizes[:-1])
        self.patch_embeddings = nn.ModuleList(
            _PatchEmbed(i, o, p, s) for i, o, p, s in zip(ins, cfg.hidden_sizes, cfg.patch_sizes, cfg.strides)
        )
        self.block = nn.ModuleList(
            nn.ModuleList(_Layer(dim, heads, sr, cfg.mlp_ratio) for _ in range(depth))
            for dim, heads, sr, depth in zip(
                cfg.hidden_sizes, cfg.num_attention_heads, cfg.sr_ratios, cfg.depths
            )
        )
        self.layer_norm = nn.ModuleList(nn.LayerNorm(c) for c in cfg.hidden_sizes)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for embed, blocks, norm in zip(self.patch_embeddings, self.block, self.layer_norm):
            x, h, w = embed(x)
            for blk in cast(nn.ModuleList, blocks):
                x = blk(x, h, w)
            x = norm(x).reshape(x.shape[0], h, w, -1).permute(0, 3, 1, 2).contiguous()  # [B, C, h, w]
            feats.append(x)
        return feats


class _DecodeHead(nn.Module):
    """All-MLP decoder: per-stage linear to D channels, upsample to stride 4, fuse, classify."""

    def __init__(self, cfg: SegFormerConfig):
        super().__init__()
        d = cfg.decoder_hidden_size
        self.linear_c = nn.ModuleList(_Proj(c, d) for c in cfg.hidden_sizes)
        self.linear_fuse = nn.Conv2d(d * len(cfg.hidden_sizes), d, kernel_size=1, bias=False)
        self.batch_norm = nn.BatchNorm2d(d)
        self.classifier = nn.Conv2d(d, cfg.num_labels, kernel_size=1)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        size = feats[0].shape[2:]
        outs = []
        for f, mod in zip(feats, cast(list[_Proj], list(self.linear_c))):
            b, _, h, w = f.shape
            y = mod.proj(f.flatten(2).transpose(1, 2)).transpose(1, 2).reshape(b, -1, h, w)
            outs.append(F.interpolate(y, size=size, mode="bilinear", align_corners=False))
        # transformers concatenates the stages deepest first; the fuse weights expect that order
        x = torch.relu(self.batch_norm(self.linear_fuse(torch.cat(outs[::-1], dim=1))))
        return self.classifier(x)


class _Body(nn.Module):
    def __init__(self, cfg: SegFormerConfig):
        super().__init__()
        self.encoder = _Encoder(cfg)


class SegFormer(nn.Module):
    """SegFormer semantic segmentation network (inference only: no dropout, no drop-path).

    Parameters
    ----------
    cfg : SegFormerConfig
    """

    def __init__(self, cfg: SegFormerConfig = SEGFORMER_CONFIGS["b0"]):
        super().__init__()
        self.cfg = cfg
        self.segformer = _Body(cfg)
        self.decode_head = _DecodeHead(cfg)

    def forward(self, pixel_values: torch.Tensor) -> torch.Tensor:
        """Logits [B, num_labels, ceil(h/4), ceil(w/4)] of normalised ``pixel_values`` [B, 3, h, w]."""
        return self.decode_head(self.segformer.encoder(pixel_values))


# transformers 5 module names -> hub checkpoint names (inverse of its load-time WeightRenaming)
_V5_TO_HUB = [
    (r"segformer\.stages\.(\d+)\.patch_embeddings\.", r"segformer.encoder.patch_embeddings.\1."),
    (r"segformer\.stages\.(\d+)\.blocks\.", r"segformer.encoder.block.\1."),
    (r"segformer\.stages\.(\d+)\.layer_norm\.", r"segformer.encoder.layer_norm.\1."),
    (r"attention\.q_proj\.", "attention.self.query."),
    (r"attention\.k_proj\.", "attention.self.key."),
    (r"attention\.v_proj\.", "attention.self.value."),
    (r"attention\.sequence_reduction\.sequence_reduction\.", "attention.self.sr."),
    (r"attention\.sequence_reduction\.layer_norm\.", "attention.self.layer_norm."),
    (r"attention\.o_proj\.", "attention.output.dense."),
    (r"mlp\.fc1\.", "mlp.dense1."),
    (r"mlp\.fc2\.", "mlp.dense2."),
    (r"\.layernorm_before\.", ".layer_norm_1."),
    (r"\.layernorm_after\.", ".layer_norm_2."),
    (r"decode_head\.linear_projections\.", "decode_head.linear_c."),
]


def _hub_key(key: str) -> str:
    for pat, rep in _V5_TO_HUB:
        key = re.sub(pat, rep, key)
    return key


def segformer_config_from_state_dict(state: Mapping[str, torch.Tensor]) -> SegFormerConfig:
    """Infer the architecture from checkpoint tensor shapes (hub or ``transformers`` 5 key names).

    Raises
    ------
    ValueError
        When the tensors are not a SegFormer semantic-segmentation checkpoint.
    """
    keys = {_hub_key(k): v for k, v in state.items()}
    try:
        hidden = tuple(
            int(keys[f"segformer.encoder.patch_embeddings.{i}.proj.weight"].shape[0]) for i in range(4)
        )
        num_labels = int(keys["decode_head.classifier.weight"].shape[0])
        dec = int(keys["decode_head.linear_fuse.weight"].shape[0])
    except KeyError as exc:
        raise ValueError(f"not a SegformerForSemanticSegmentation checkpoint: no tensor {exc}") from None
    depths = stage_depths(keys, r"segformer\.encoder\.block\.{}\.(\d+)\.")
    base = SegFormerConfig()
    return SegFormerConfig(
        hidden_sizes=hidden,  # type: ignore[arg-type]
        depths=depths,  # type: ignore[arg-type]
        decoder_hidden_size=dec,
        num_labels=num_labels,
        num_attention_heads=base.num_attention_heads,
    )


def _hf_config_overrides(path: str | Path) -> dict[str, Any]:
    """Head counts etc. from a ``save_pretrained`` folder's config.json (not stored in the tensors)."""
    cfg_file = Path(path) / "config.json"
    if not cfg_file.is_file():
        return {}
    data = json.loads(cfg_file.read_text(encoding="utf-8"))
    if data.get("model_type") != "segformer":
        return {}
    out: dict[str, Any] = {}
    for key in ("num_attention_heads", "sr_ratios", "patch_sizes", "strides"):
        if key in data:
            out[key] = tuple(int(v) for v in data[key])
    if "mlp_ratios" in data and len(set(data["mlp_ratios"])) == 1:
        out["mlp_ratio"] = int(data["mlp_ratios"][0])
    return out


def load_segformer(
    path: str | Path, *, variant: str | None = None, config: SegFormerConfig | None = None
) -> SegFormer:
    """Build a :class:`SegFormer` from a ``transformers`` checkpoint.

    Parameters
    ----------
    path : str or Path
        ``model.safetensors`` or ``pytorch_model.bin`` of a ``SegformerForSemanticSegmentation``,
        or a folder holding one (``save_pretrained`` layout).
    variant : {"b0", ..., "b5"}, optional
        Check the checkpoint against this MiT variant.
    config : SegFormerConfig, optional
        The architecture. Default: widths, depths and classes from the tensor shapes; head counts,
        reduction ratios and patch sizes from the folder's ``config.json`` when there is one, else
        those of every released MiT variant.

    Returns
    -------
    SegFormer
        In eval mode, float32.

    Raises
    ------
    ValueError
        On a checkpoint of another architecture or variant, or missing/unexpected tensors.
    """
    state = read_state_dict(path)
    cfg = config or dataclasses.replace(segformer_config_from_state_dict(state), **_hf_config_overrides(path))
    if variant is not None:
        check_variant(path, cfg, SEGFORMER_CONFIGS, variant, "SegFormer")
    model = SegFormer(cfg)
    load_checked_state(model, {_hub_key(k): v for k, v in state.items()}, path, "SegFormer")
    return model.eval()


def convert_hf_segformer(
    sources: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    entry: Any = None,
    *,
    input_size: tuple[int, int] | None = None,
) -> Path:
    """Model-store converter: a hub SegFormer checkpoint -> ``out_dir/{model.onnx, ...}``.

    Parameters
    ----------
    sources : path-like or a one-element sequence of path-like
        ``model.safetensors`` / ``pytorch_model.bin`` (or a ``save_pretrained`` folder) of an
        ADE20K SegFormer; the model store passes a list.
    out_dir : str or Path
        Receives the files of :func:`wcbench.metrics.semantic.pytorch.backend.write_segmenter_dir`.
    entry : ModelEntry, optional
        The model-store entry; ``entry.options["input_size"]`` sets the input size.
    input_size : (int, int), optional
        (height, width) the image processor resizes to: 512x512 (default) for b0..b4, 640x640 for
        b5-640.

    Returns
    -------
    Path
        ``out_dir``.
    """
    return convert_checkpoint(
        sources, out_dir, entry, input_size, load=load_segformer, configs=SEGFORMER_CONFIGS, arch="segformer",
        logits_stride=4,
    )
