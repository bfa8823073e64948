"""A compact CLIP ViT in torch (needs the ``[model]`` extra).

Parameter names follow OpenAI's ``clip/model.py`` (which open_clip keeps for its ``CLIP`` class),
so an OpenAI or open_clip state dict loads with no renaming and our safetensors files use the same
keys. The forward pass is written out (no ``nn.MultiheadAttention``) so that the ONNX export is a
plain graph of MatMul/Softmax/LayerNormalization.

Embeddings returned here are *not* L2-normalised; the scoring side normalises them.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from wcbench.metrics.clip.config import ClipArch


class QuickGELU(nn.Module):
    """x * sigmoid(1.702 x): the GELU approximation OpenAI trained CLIP with."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(1.702 * x)


class _Mlp(nn.Module):
    def __init__(self, width: int, act: str):
        super().__init__()
        self.c_fc = nn.Linear(width, 4 * width)
        self.gelu: nn.Module = QuickGELU() if act == "quick_gelu" else nn.GELU()
        self.c_proj = nn.Linear(4 * width, width)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.c_proj(self.gelu(self.c_fc(x)))


class SelfAttention(nn.Module):
    """Multi-head self-attention with ``nn.MultiheadAttention``'s parameter layout.

    Parameters ``in_proj_weight`` [3W, W] and ``in_proj_bias`` [3W] stack the q, k, v projections in
    that order, so OpenAI/open_clip weights load unchanged.
    """

    def __init__(self, width: int, heads: int):
        super().__init__()
        self.heads = heads
        self.in_proj_weight = nn.Parameter(torch.empty(3 * width, width))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * width))
        self.out_proj = nn.Linear(width, width)
        nn.init.xavier_uniform_(self.in_proj_weight)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """x: [B, N, W]; mask: [N, N] additive (0 or -inf) or None -> [B, N, W]."""
        b, n, w = x.shape
        d = w // self.heads
        qkv = F.linear(x, self.in_proj_weight, self.in_proj_bias)  # [B, N, 3W]
        qkv = qkv.reshape(b, n, 3, self.heads, d).permute(2, 0, 3, 1, 4)  # [3, B, H, N, d]
        q, k, v = qkv[0], qkv[1], qkv[2]
        logits = (q * (1.0 / math.sqrt(d))) @ k.transpose(-1, -2)  # [B, H, N, N]
        if mask is not None:
            logits = logits + mask
        out = logits.softmax(dim=-1) @ v  # [B, H, N, d]
        return self.out_proj(out.transpose(1, 2).reshape(b, n, w))


class ResidualAttentionBlock(nn.Module):
    """Pre-LN transformer block: x + attn(ln_1(x)), then x + mlp(ln_2(x))."""

    def __init__(self, width: int, heads: int, act: str):
        super().__init__()
        self.ln_1 = nn.LayerNorm(width)
        self.attn = SelfAttention(width, heads)
        self.ln_2 = nn.LayerNorm(width)
        self.mlp = _Mlp(width, act)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x), mask)
        return x + self.mlp(self.ln_2(x))


class Transformer(nn.Module):
    """A stack of :class:`ResidualAttentionBlock` (``resblocks.{i}``)."""

    def __init__(self, width: int, layers: int, heads: int, act: str):
        super().__init__()
        self.resblocks = nn.ModuleList([ResidualAttentionBlock(width, heads, act) for _ in range(layers)])

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        for block in self.resblocks:
            x = block(x, mask)
        return x


class VisionTransformer(nn.Module):
    """CLIP's image tower (the ``visual.*`` parameters)."""

    def __init__(self, arch: ClipArch):
        super().__init__()
        w = arch.vision_width
        scale = w**-0.5
        self.conv1 = nn.Conv2d(3, w, kernel_size=arch.patch_size, stride=arch.patch_size, bias=False)
        self.class_embedding = nn.Parameter(scale * torch.randn(w))
        self.positional_embedding = nn.Parameter(scale * torch.randn(arch.grid**2 + 1, w))
        self.ln_pre = nn.LayerNorm(w)
        self.transformer = Transformer(w, arch.vision_layers, arch.vision_heads, arch.act)
        self.ln_post = nn.LayerNorm(w)
        self.proj = nn.Parameter(scale * torch.randn(w, arch.embed_dim))

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        """pixels: [B, 3, S, S] normalised -> image embeddings [B, E]."""
        x = self.conv1(pixels)  # [B, W, G, G]
        x = x.flatten(2).transpose(1, 2)  # [B, G*G, W]
        cls = self.class_embedding.to(x.dtype).expand(x.shape[0], 1, -1)
        x = torch.cat([cls, x], dim=1) + self.positional_embedding
        x = self.transformer(self.ln_pre(x))
        return self.ln_post(x[:, 0, :]) @ self.proj


class ClipModel(nn.Module):
    """CLIP ViT with OpenAI's parameter names.

    Parameters
    ----------
    arch : ClipArch
        The shapes; see :data:`wcbench.metrics.clip.config.CLIP_ARCHS`.
    """

    def __init__(self, arch: ClipArch):
        super().__init__()
        self.arch = arch
        self.visual = VisionTransformer(arch)
        self.token_embedding = nn.Embedding(arch.vocab_size, arch.text_width)
        self.positional_embedding = nn.Parameter(torch.empty(arch.context_length, arch.text_width))
        self.transformer = Transformer(arch.text_width, arch.text_layers, arch.text_heads, arch.act)
        self.ln_final = nn.LayerNorm(arch.text_width)
        self.text_projection = nn.Parameter(torch.empty(arch.text_width, arch.embed_dim))
        self.logit_scale = nn.Parameter(torch.tensor(math.log(1 / 0.07)))
        # Causal mask, a buffer so that the ONNX export stores it as a constant; not persistent so
        # state dicts keep OpenAI's key set.
        mask = torch.full((arch.context_length, arch.context_length), float("-inf")).triu_(1)
        self.register_buffer("attn_mask", mask, persistent=False)
        nn.init.normal_(self.token_embedding.weight, std=0.02)
        nn.init.normal_(self.positional_embedding, std=0.01)
        nn.init.normal_(self.text_projection, std=arch.text_width**-0.5)

    def encode_image(self, pixels: torch.Tensor) -> torch.Tensor:
        """Image embeddings.

        Parameters
        ----------
        pixels : Tensor [B, 3, S, S] float32
            Preprocessed images (CLIP mean/std normalised), S = ``arch.image_size``.

        Returns
        -------
        Tensor [B, E]
            Unnormalised embeddings.
        """
        s = self.arch.image_size
        if pixels.ndim != 4 or tuple(pixels.shape[1:]) != (3, s, s):
            raise ValueError(f"pixels: expected [B, 3, {s}, {s}], got {tuple(pixels.shape)}")
        return self.visual(pixels)

    def encode_text(self, tokens: torch.Tensor) -> torch.Tensor:
        """Text embeddings, taken at the end-of-text token (the largest id in each row).

        Parameters
        ----------
        tokens : Tensor [B, L] int64
            Token ids from :func:`wcbench.metrics.clip.tokenizer.ClipTokenizer.tokenize`,
            L = ``arch.context_length``, zero-padded after the end-of-text token.

        Returns
        -------
        Tensor [B, E]
            Unnormalised embeddings.
        """
        if tokens.ndim != 2 or tokens.shape[1] != self.arch.context_length:
            raise ValueError(f"tokens: expected [B, {self.arch.context_length}], got {tuple(tokens.shape)}")
        x = self.token_embedding(tokens) + self.positional_embedding  # [B, L, W]
        x = self.ln_final(self.transformer(x, self.attn_mask))
        # End-of-text is the largest id of the vocabulary, so argmax finds it (OpenAI's rule).
        eot = x[torch.arange(x.shape[0]), tokens.argmax(dim=-1)]  # [B, W]
        return eot @ self.text_projection

    def forward(self, pixels: torch.Tensor, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(encode_image(pixels), encode_text(tokens))``."""
        return self.encode_image(pixels), self.encode_text(tokens)


class ImageTower(nn.Module):
    """``model.encode_image`` as a module's forward (what the ONNX export traces)."""

    def __init__(self, model: ClipModel):
        super().__init__()
        self.model = model

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        return self.model.visual(pixels)


class TextTower(nn.Module):
    """``model.encode_text`` as a module's forward (what the ONNX export traces)."""

    def __init__(self, model: ClipModel):
        super().__init__()
        self.model = model

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        return self.model.encode_text(tokens)


def randomize_(model: nn.Module, *, seed: int = 0, std: float = 0.02) -> nn.Module:
    """Overwrite every parameter with seeded random values (for tests and benchmarks).

    Unlike the usual initialisation, LayerNorm scales and all biases are random too, so a mistake
    in mapping any single tensor between formats shows up in the outputs.

    Parameters
    ----------
    model : nn.Module
        Any module; changed in place and returned.
    seed : int
        Seed of a private generator (the global torch RNG is untouched).
    std : float
        Standard deviation of weights and biases; LayerNorm scales are 1 + N(0, 0.1).
    """
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in sorted(model.named_parameters()):
            noise = torch.randn(p.shape, generator=gen, dtype=torch.float32)
            is_norm_scale = name.endswith(".weight") and p.ndim == 1
            if "logit_scale" in name:
                p.copy_(torch.tensor(math.log(100.0)).reshape(p.shape))
            elif is_norm_scale:
                p.copy_(1.0 + 0.1 * noise)
            else:
                p.copy_(std * noise)
    return model
