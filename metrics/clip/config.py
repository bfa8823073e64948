"""CLIP architecture descriptions (torch-free).

A :class:`ClipArch` fixes every shape of a CLIP model: the ViT image tower, the causal text
transformer and the joint embedding. The numbers of the three OpenAI ViTs are those of OpenAI's
released checkpoints (and of open_clip's ``model_configs/ViT-*.json``, which a test compares when
the open_clip wheel can be fetched).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

#: Per-channel RGB mean and std CLIP was trained with (OpenAI's ``clip/clip.py``), for [0, 1] inputs.
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)

#: Token ids of the special tokens of CLIP's BPE vocabulary.
SOT_TOKEN = 49406
EOT_TOKEN = 49407

_ACTS = ("quick_gelu", "gelu")


@dataclass(frozen=True)
class ClipArch:
    """Shapes of a CLIP ViT model.

    Attributes
    ----------
    name : str
        ``"ViT-B/32"``, ``"ViT-B/16"``, ``"ViT-L/14"`` or a free name for test models.
    embed_dim : int
        Size E of the joint image/text embedding.
    image_size, patch_size : int
        Input side S in pixels (square) and ViT patch side P; S must be a multiple of P.
    vision_width, vision_layers, vision_heads : int
        Image transformer width, depth and attention heads.
    text_width, text_layers, text_heads : int
        Text transformer width, depth and attention heads.
    context_length : int
        Token sequence length L (77 for every released CLIP).
    vocab_size : int
        Token vocabulary size (49408 for CLIP's BPE).
    act : str
        MLP activation: ``"quick_gelu"`` (x * sigmoid(1.702 x), OpenAI's weights) or ``"gelu"``
        (erf GELU, most open_clip LAION/DataComp weights). Using the wrong one still runs but gives
        wrong embeddings, so it is part of the architecture.
    """

    name: str
    embed_dim: int
    image_size: int
    patch_size: int
    vision_width: int
    vision_layers: int
    vision_heads: int
    text_width: int
    text_layers: int
    text_heads: int
    context_length: int = 77
    vocab_size: int = 49408
    act: str = "quick_gelu"

    def __post_init__(self) -> None:
        if self.image_size % self.patch_size:
            raise ValueError(
                f"image_size {self.image_size} is not a multiple of patch_size {self.patch_size}"
            )
        if self.vision_width % self.vision_heads or self.text_width % self.text_heads:
            raise ValueError(f"{self.name}: widths must be multiples of their head counts")
        if self.act not in _ACTS:
            raise ValueError(f"act must be one of {_ACTS}, got {self.act!r}")

    @property
    def grid(self) -> int:
        """Patches per image side, S / P."""
        return self.image_size // self.patch_size

    def with_act(self, act: str) -> ClipArch:
        """The same shapes with another MLP activation."""
        return ClipArch(**{**asdict(self), "act": act})

    def to_json(self) -> str:
        """Canonical JSON text (stored in our safetensors metadata)."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ClipArch:
        """Inverse of :meth:`to_json`."""
        data: dict[str, Any] = json.loads(text)
        return cls(**data)


def _vit(name: str, embed: int, patch: int, vw: int, vl: int, tw: int) -> ClipArch:
    # OpenAI fixes 64-dimensional attention heads in both towers and 12 text layers.
    return ClipArch(
        name=name,
        embed_dim=embed,
        image_size=224,
        patch_size=patch,
        vision_width=vw,
        vision_layers=vl,
        vision_heads=vw // 64,
        text_width=tw,
        text_layers=12,
        text_heads=tw // 64,
    )


#: The released OpenAI ViT architectures (QuickGELU; use :meth:`ClipArch.with_act` for GELU weights).
CLIP_ARCHS: dict[str, ClipArch] = {
    "ViT-B/32": _vit("ViT-B/32", 512, 32, 768, 12, 512),
    "ViT-B/16": _vit("ViT-B/16", 512, 16, 768, 12, 512),
    "ViT-L/14": _vit("ViT-L/14", 768, 14, 1024, 24, 768),
}


def get_arch(name: str, *, act: str | None = None) -> ClipArch:
    """Look up a released architecture by OpenAI (``ViT-B/32``) or open_clip (``ViT-B-32``) name.

    Parameters
    ----------
    name : str
        Architecture name.
    act : str, optional
        Override the activation (``"gelu"`` for open_clip's LAION weights).

    Raises
    ------
    ValueError
        If the name is unknown (the message lists the known ones).
    """
    key = name.replace("-32", "/32").replace("-16", "/16").replace("-14", "/14")
    if key not in CLIP_ARCHS:
        raise ValueError(f"unknown CLIP architecture {name!r}; known: {', '.join(CLIP_ARCHS)}")
    arch = CLIP_ARCHS[key]
    return arch.with_act(act) if act is not None else arch
