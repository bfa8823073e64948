"""Our CLIP against transformers' CLIPModel with the same random weights, loaded from HF's own files."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
transformers = pytest.importorskip("transformers")

from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from wcbench.metrics.clip.config import CLIP_ARCHS, ClipArch  # noqa: E402
from wcbench.metrics.clip.pytorch.checkpoints import hf_to_openai, read_state_dict  # noqa: E402
from wcbench.metrics.clip.pytorch.convert import build_model  # noqa: E402
from wcbench.metrics.clip.pytorch.model import randomize_  # noqa: E402

#: (pixels [B, 3, S, S] float32, tokens [B, 77] int64) torch tensors.
Inputs = tuple[Any, Any]
#: Required agreement of embeddings (|x| ~ 1): same float32 weights, different attention kernels
#: (HF uses SDPA) and summation order; measured ~1e-6 for ViT-B/32.
HF_TOL = 1e-4


def hf_model(arch: ClipArch, seed: int):  # type: ignore[no-untyped-def]
    common = dict(hidden_act=arch.act, layer_norm_eps=1e-5, projection_dim=arch.embed_dim)
    text = dict(
        vocab_size=arch.vocab_size,
        hidden_size=arch.text_width,
        intermediate_size=4 * arch.text_width,
        num_hidden_layers=arch.text_layers,
        num_attention_heads=arch.text_heads,
        max_position_embeddings=arch.context_length,
        eos_token_id=arch.vocab_size - 1,
        **common,
    )
    vision = dict(
        hidden_size=arch.vision_width,
        intermediate_size=4 * arch.vision_width,
        num_hidden_layers=arch.vision_layers,
        num_attention_heads=arch.vision_heads,
        image_size=arch.image_size,
        patch_size=arch.patch_size,
        **common,
    )
    config = transformers.CLIPConfig(text_config=text, vision_config=vision, projection_dim=arch.embed_dim)
    return randomize_(transformers.CLIPModel(config), seed=seed).eval()


def inputs(arch: ClipArch) -> Inputs:
    g = torch.Generator().manual_seed(0)
    pixels = torch.randn(2, 3, arch.image_size, arch.image_size, generator=g)
    tokens = torch.zeros(2, arch.context_length, dtype=torch.long)
    for r, n in enumerate((5, 30)):
        tokens[r, 0] = 49406
        tokens[r, 1 : n + 1] = torch.randint(1, 49406, (n,), generator=g)
        tokens[r, n + 1] = 49407
    return pixels, tokens


def features(out):  # type: ignore[no-untyped-def]
    # transformers 5 returns a model output with the projected embedding as pooler_output; 4.x a tensor.
    return (out.pooler_output if hasattr(out, "pooler_output") else out).numpy()


def check_against_hf(name: str, tmp_path: Path) -> None:
    arch = CLIP_ARCHS[name]
    hf = hf_model(arch, seed=7)
    hf.save_pretrained(tmp_path)  # the real file format: model.safetensors (+ config.json)
    sd, fmt = read_state_dict(tmp_path / "model.safetensors")
    assert fmt == "transformers"
    ours = build_model(sd, arch)
    pixels, tokens = inputs(arch)
    with torch.no_grad():
        want_img = features(hf.get_image_features(pixel_values=pixels))
        want_txt = features(hf.get_text_features(input_ids=tokens))
        got_img, got_txt = (t.numpy() for t in ours(pixels, tokens))
    np.testing.assert_allclose(got_img, want_img, rtol=0, atol=HF_TOL)
    np.testing.assert_allclose(got_txt, want_txt, rtol=0, atol=HF_TOL)
    assert np.abs(want_img).max() > 0.1  # the comparison is not between near-zero vectors


def test_vit_b32_matches_transformers(tmp_path: Path) -> None:
    check_against_hf("ViT-B/32", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ViT-B/16", "ViT-L/14"])
def test_large_archs_match_transformers(tmp_path: Path, name: str) -> None:
    check_against_hf(name, tmp_path)


def test_hf_pytorch_bin_and_gelu(tmp_path: Path) -> None:
    # A small CLIP with erf-GELU, saved as HF's older pytorch_model.bin.
    arch = ClipArch(
        name="small",
        embed_dim=32,
        image_size=64,
        patch_size=16,
        vision_width=64,
        vision_layers=2,
        vision_heads=2,
        text_width=64,
        text_layers=2,
        text_heads=2,
        act="gelu",
    )
    hf = hf_model(arch, seed=1)
    path = tmp_path / "pytorch_model.bin"
    torch.save(hf.state_dict(), path)
    sd, fmt = read_state_dict(path)
    assert fmt == "transformers"
    ours = build_model(sd, arch)
    pixels, tokens = inputs(arch)
    with torch.no_grad():
        np.testing.assert_allclose(
            ours.encode_image(pixels).numpy(),
            features(hf.get_image_features(pixel_values=pixels)),
            atol=HF_TOL,
        )
        np.testing.assert_allclose(
            ours.encode_text(tokens).numpy(), features(hf.get_text_features(input_ids=tokens)), atol=HF_TOL
        )


def test_unknown_hf_keys_are_named() -> None:
    from wcbench.metrics.clip.pytorch.checkpoints import CheckpointError

    with pytest.raises(CheckpointError, match=r"vision_model\.head\.weight"):
        hf_to_openai(
            {"vision_model.embeddings.class_embedding": np.zeros(4), "vision_model.head.weight": np.zeros(4)}
        )
