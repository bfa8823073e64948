"""Read CLIP checkpoints in their real formats and convert them to ours.

Formats read (detected from the file, not its name):

- OpenAI ``.pt`` as released: a TorchScript archive (``torch.jit.load``; its state dict carries
  three extra scalars ``input_resolution``, ``context_length``, ``vocab_size`` and float16 weights).
  Loading one runs the code it holds, so it is read only when the caller trusts it
  (``trust_torchscript=True``, ``--trust-torchscript``; docs/design.md §6) and refused otherwise,
  recognised from its zip listing without unpickling anything;
- OpenAI/open_clip plain state dicts (``torch.load(weights_only=True)``), optionally wrapped as
  ``{"state_dict": ...}`` with DDP's ``module.`` prefix (open_clip training checkpoints), or as
  safetensors (``open_clip_model.safetensors``). open_clip's ``CLIP`` class keeps OpenAI's key
  names, so both share one path;
- Hugging Face ``transformers`` ``CLIPModel`` weights (``model.safetensors`` or
  ``pytorch_model.bin``), renamed by :func:`hf_to_openai`.

Ours: safetensors with OpenAI key names in float32 and the architecture as JSON metadata.
Safetensors files are read without torch; ``.pt``/``.bin`` files need torch.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.models.torchscript import check_torchscript
from wcbench.core.storage import atomic_path
from wcbench.metrics.clip.config import ClipArch

StateDict = dict[str, np.ndarray]

#: safetensors metadata keys of our files.
META_FORMAT, META_ARCH, META_SOURCE = "format", "wcbench.clip_arch", "wcbench.source_format"
FORMAT_TAG = "wcbench-clip-v1"
# Entries of real checkpoints that are not weights: OpenAI's TorchScript scalars and old open_clip
# versions' persistent causal-mask buffers.
_NON_WEIGHTS = ("input_resolution", "context_length", "vocab_size", "attn_mask")


class CheckpointError(ValueError):
    """A checkpoint is not a CLIP of the expected format or architecture."""


def expected_shapes(arch: ClipArch) -> dict[str, tuple[int, ...]]:
    """Every weight of :class:`~wcbench.metrics.clip.pytorch.model.ClipModel` and its shape (torch-free).

    Parameters
    ----------
    arch : ClipArch

    Returns
    -------
    dict
        OpenAI key name -> shape; ``logit_scale`` is a scalar ``()``.
    """

    def blocks(prefix: str, width: int, layers: int) -> dict[str, tuple[int, ...]]:
        out: dict[str, tuple[int, ...]] = {}
        for i in range(layers):
            p = f"{prefix}transformer.resblocks.{i}."
            out.update(
                {
                    p + "ln_1.weight": (width,),
                    p + "ln_1.bias": (width,),
                    p + "attn.in_proj_weight": (3 * width, width),
                    p + "attn.in_proj_bias": (3 * width,),
                    p + "attn.out_proj.weight": (width, width),
                    p + "attn.out_proj.bias": (width,),
                    p + "ln_2.weight": (width,),
                    p + "ln_2.bias": (width,),
                    p + "mlp.c_fc.weight": (4 * width, width),
                    p + "mlp.c_fc.bias": (4 * width,),
                    p + "mlp.c_proj.weight": (width, 4 * width),
                    p + "mlp.c_proj.bias": (width,),
                }
            )
        return out

    vw, tw = arch.vision_width, arch.text_width
    shapes: dict[str, tuple[int, ...]] = {
        "visual.class_embedding": (vw,),
        "visual.positional_embedding": (arch.grid**2 + 1, vw),
        "visual.conv1.weight": (vw, 3, arch.patch_size, arch.patch_size),
        "visual.ln_pre.weight": (vw,),
        "visual.ln_pre.bias": (vw,),
        "visual.ln_post.weight": (vw,),
        "visual.ln_post.bias": (vw,),
        "visual.proj": (vw, arch.embed_dim),
        "token_embedding.weight": (arch.vocab_size, tw),
        "positional_embedding": (arch.context_length, tw),
        "ln_final.weight": (tw,),
        "ln_final.bias": (tw,),
        "text_projection": (tw, arch.embed_dim),
        "logit_scale": (),
    }
    shapes.update(blocks("visual.", vw, arch.vision_layers))
    shapes.update(blocks("", tw, arch.text_layers))
    return shapes


def infer_arch(sd: Mapping[str, np.ndarray], *, act: str = "quick_gelu", name: str = "") -> ClipArch:
    """Architecture of an OpenAI-keyed state dict, from its shapes (as OpenAI's ``build_model``).

    Heads are width / 64 in both towers, as in every released CLIP.

    Raises
    ------
    CheckpointError
        If a key needed to infer the shapes is missing (e.g. a ResNet CLIP).
    """
    try:
        vw, _, patch, _ = sd["visual.conv1.weight"].shape
        n_pos = sd["visual.positional_embedding"].shape[0]
        embed = sd["text_projection"].shape[1]
        ctx, tw = sd["positional_embedding"].shape
        vocab = sd["token_embedding.weight"].shape[0]
    except KeyError as exc:
        raise CheckpointError(f"not a CLIP ViT state dict: no {exc.args[0]!r}") from None
    grid = round((n_pos - 1) ** 0.5)

    def count(prefix: str) -> int:  # number of distinct block indices under prefix
        return len({k[len(prefix) :].split(".")[0] for k in sd if k.startswith(prefix)})

    return ClipArch(
        name=name or f"ViT-{vw}/{patch}",
        embed_dim=int(embed),
        image_size=int(grid * patch),
        patch_size=int(patch),
        vision_width=int(vw),
        vision_layers=count("visual.transformer.resblocks."),
        vision_heads=max(1, int(vw) // 64),
        text_width=int(tw),
        text_layers=count("transformer.resblocks."),
        text_heads=max(1, int(tw) // 64),
        context_length=int(ctx),
        vocab_size=int(vocab),
        act=act,
    )


def check_state_dict(sd: Mapping[str, np.ndarray], arch: ClipArch) -> None:
    """Raise :class:`CheckpointError` unless ``sd`` has exactly ``arch``'s keys and shapes.

    The message names missing and unexpected keys and the first shape mismatches.
    """
    want = expected_shapes(arch)
    missing = sorted(set(want) - set(sd))
    extra = sorted(set(sd) - set(want))
    wrong = [
        f"{k}: {tuple(sd[k].shape)} != {want[k]}"
        for k in sorted(set(want) & set(sd))
        if tuple(sd[k].shape) != want[k]
    ]
    if missing or extra or wrong:
        parts = []
        if missing:
            parts.append(f"missing {len(missing)} keys (e.g. {missing[:3]})")
        if extra:
            parts.append(f"unexpected {len(extra)} keys (e.g. {extra[:3]})")
        if wrong:
            parts.append(f"shape mismatch: {'; '.join(wrong[:3])}")
        raise CheckpointError(f"checkpoint does not match CLIP {arch.name}: " + ", ".join(parts))


_HF_LAYER = re.compile(r"^(vision_model|text_model)\.encoder\.layers\.(\d+)\.(.+)$")
_HF_LAYER_RENAME = {
    "self_attn.out_proj.weight": "attn.out_proj.weight",
    "self_attn.out_proj.bias": "attn.out_proj.bias",
    "layer_norm1.weight": "ln_1.weight",
    "layer_norm1.bias": "ln_1.bias",
    "layer_norm2.weight": "ln_2.weight",
    "layer_norm2.bias": "ln_2.bias",
    "mlp.fc1.weight": "mlp.c_fc.weight",
    "mlp.fc1.bias": "mlp.c_fc.bias",
    "mlp.fc2.weight": "mlp.c_proj.weight",
    "mlp.fc2.bias": "mlp.c_proj.bias",
}
_HF_RENAME = {
    "vision_model.embeddings.class_embedding": "visual.class_embedding",
    "vision_model.embeddings.patch_embedding.weight": "visual.conv1.weight",
    "vision_model.embeddings.position_embedding.weight": "visual.positional_embedding",
    "vision_model.pre_layrnorm.weight": "visual.ln_pre.weight",  # sic: HF's spelling
    "vision_model.pre_layrnorm.bias": "visual.ln_pre.bias",
    "vision_model.post_layernorm.weight": "visual.ln_post.weight",
    "vision_model.post_layernorm.bias": "visual.ln_post.bias",
    "text_model.embeddings.token_embedding.weight": "token_embedding.weight",
    "text_model.embeddings.position_embedding.weight": "positional_embedding",
    "text_model.final_layer_norm.weight": "ln_final.weight",
    "text_model.final_layer_norm.bias": "ln_final.bias",
    "logit_scale": "logit_scale",
}
# HF Linear projections are [out, in]; OpenAI keeps them as [in, out] matrices used as x @ proj.
_HF_TRANSPOSED = {"visual_projection.weight": "visual.proj", "text_projection.weight": "text_projection"}


def is_hf_state_dict(keys: Sequence[str] | Mapping[str, Any]) -> bool:
    """Whether keys are Hugging Face ``CLIPModel``'s (``vision_model.*``, ``text_model.*``)."""
    return any(k.startswith("vision_model.embeddings.") for k in keys)


def hf_to_openai(sd: Mapping[str, np.ndarray]) -> StateDict:
    """Rename a Hugging Face ``CLIPModel`` state dict to OpenAI keys.

    q/k/v projections are stacked into ``in_proj_weight``/``in_proj_bias`` (that order), and the two
    projection Linears are transposed. ``position_ids`` buffers are dropped.

    Raises
    ------
    CheckpointError
        On keys this mapping does not know (e.g. a ``CLIPVisionModelWithProjection`` or another model).
    """
    out: StateDict = {}
    qkv: dict[str, dict[str, np.ndarray]] = {}
    unknown = []
    for key, value in sd.items():
        key = key.removeprefix("model.")  # some re-exports nest CLIPModel under "model."
        if key.endswith("position_ids"):
            continue
        m = _HF_LAYER.match(key)
        if m:
            tower, idx, rest = m.groups()
            prefix = f"{'visual.' if tower == 'vision_model' else ''}transformer.resblocks.{idx}."
            if rest in _HF_LAYER_RENAME:
                out[prefix + _HF_LAYER_RENAME[rest]] = value
            elif rest.startswith("self_attn.") and rest.split(".")[1] in ("q_proj", "k_proj", "v_proj"):
                _, proj, kind = rest.split(".")
                qkv.setdefault(prefix + f"attn.in_proj_{kind}", {})[proj] = value
            else:
                unknown.append(key)
        elif key in _HF_RENAME:
            out[_HF_RENAME[key]] = value
        elif key in _HF_TRANSPOSED:
            out[_HF_TRANSPOSED[key]] = np.ascontiguousarray(np.asarray(value).T)
        else:
            unknown.append(key)
    if unknown:
        raise CheckpointError(f"unknown Hugging Face CLIP keys: {sorted(unknown)[:5]}")
    for dst, parts in qkv.items():
        if set(parts) != {"q_proj", "k_proj", "v_proj"}:
            raise CheckpointError(f"{dst}: incomplete q/k/v projections ({sorted(parts)})")
        out[dst] = np.concatenate([parts["q_proj"], parts["k_proj"], parts["v_proj"]], axis=0)
    return out


def _clean_openai(sd: Mapping[str, Any]) -> dict[str, Any]:
    """Unwrap open_clip training checkpoints and drop non-weight entries."""
    if "state_dict" in sd and isinstance(sd["state_dict"], Mapping):
        sd = sd["state_dict"]
    keys = list(sd)
    if keys and all(k.startswith("module.") for k in keys):
        sd = {k[len("module.") :]: v for k, v in sd.items()}
    return {k: v for k, v in sd.items() if k not in _NON_WEIGHTS and not k.endswith(".attn_mask")}


def _to_numpy(t: Any) -> np.ndarray:
    # float32 everywhere: OpenAI's archives hold float16 weights, some hubs bfloat16 (no numpy dtype).
    return t.detach().to(device="cpu").float().numpy().copy()


def _read_safetensors(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as fh:
        meta = fh.metadata() or {}
        try:
            tensors = {k: fh.get_tensor(k) for k in fh.keys()}
        except (TypeError, ValueError):
            tensors = {}
    if not tensors:  # bfloat16 has no numpy dtype: read through torch
        from safetensors.torch import load_file

        tensors = {k: _to_numpy(v) for k, v in load_file(str(path)).items()}
    return tensors, dict(meta)


def read_state_dict(path: str | os.PathLike[str], *, trust_torchscript: bool = False) -> tuple[StateDict, str]:
    """Read any supported CLIP checkpoint as a float32 numpy state dict with OpenAI keys.

    Parameters
    ----------
    path : path-like
        The checkpoint.
    trust_torchscript : bool
        Load a TorchScript archive (OpenAI's released ``.pt``) with ``torch.jit.load``, which runs
        the code it holds: only for a file from a trusted source. A file the model store was told
        to trust for the install running is trusted too
        (:func:`~wcbench.core.models.store.check_torchscript`). Other ``.pt``/``.bin`` files are
        read with ``torch.load(weights_only=True)``.

    Returns
    -------
    state_dict : dict of str -> ndarray float32
        OpenAI key names (see :func:`expected_shapes`).
    source_format : str
        ``"wcbench"``, ``"openai-torchscript"``, ``"openai/open_clip state dict"`` or
        ``"transformers"``.

    Raises
    ------
    CheckpointError
        If the file is none of these formats.
    wcbench.core.models.store.UntrustedTorchScriptError
        (an ``InputError``) If the file is a TorchScript archive nobody trusted; it is not loaded.
    """
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(16)
    raw: Mapping[str, Any]
    if len(head) >= 9 and head[8:9] == b"{":  # safetensors: u64 header length, then JSON
        raw, meta = _read_safetensors(path)
        if meta.get(META_FORMAT) == FORMAT_TAG:
            return {k: np.asarray(v, np.float32) for k, v in raw.items()}, "wcbench"
        fmt = "safetensors"
    else:
        # Decided from the zip listing before torch sees the file: nothing is unpickled or run.
        torchscript = check_torchscript(path, trusted=trust_torchscript)
        try:
            import torch
        except ImportError as exc:
            raise CheckpointError(
                f"{path}: reading .pt/.bin checkpoints needs torch (pip install 'wcbench[model]')"
            ) from exc
        if torchscript:
            raw = {
                k: _to_numpy(v) for k, v in torch.jit.load(str(path), map_location="cpu").state_dict().items()
            }
            fmt = "openai-torchscript"
        else:
            try:
                obj = torch.load(str(path), map_location="cpu", weights_only=True)
            except Exception as exc:  # torch raises a zoo of types on foreign files
                # torch's own text advises weights_only=False (arbitrary code execution): not shown.
                raise CheckpointError(
                    f"{path}: not a torch checkpoint wcbench reads ({type(exc).__name__}); expected an "
                    "OpenAI .pt, an open_clip or Hugging Face state dict, or a safetensors file"
                ) from exc
            if not isinstance(obj, Mapping):
                raise CheckpointError(f"{path}: expected a state dict, got {type(obj).__name__}")
            obj = _clean_openai(obj)
            raw = {k: _to_numpy(v) for k, v in obj.items() if isinstance(v, torch.Tensor)}
            fmt = "torch"
    if is_hf_state_dict(raw):
        return {k: v.astype(np.float32) for k, v in hf_to_openai(raw).items()}, "transformers"
    sd = {k: np.asarray(v, np.float32) for k, v in _clean_openai(raw).items()}
    if "logit_scale" in sd:
        sd["logit_scale"] = sd["logit_scale"].reshape(())
    if fmt == "openai-torchscript":
        return sd, fmt
    return sd, "openai/open_clip state dict"


def save_clip_safetensors(
    path: str | os.PathLike[str], sd: Mapping[str, np.ndarray], arch: ClipArch, *, source_format: str = ""
) -> None:
    """Write our format atomically: float32 OpenAI-keyed tensors, ``arch`` in the metadata.

    Raises
    ------
    CheckpointError
        If ``sd`` does not match ``arch`` (checked first, so nothing is written).
    """
    from safetensors.numpy import save_file

    check_state_dict(sd, arch)
    tensors = {k: np.array(v, np.float32, order="C") for k, v in sd.items()}  # keeps 0-d arrays 0-d
    meta = {META_FORMAT: FORMAT_TAG, META_ARCH: arch.to_json(), META_SOURCE: source_format}
    with atomic_path(path, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata=meta)


def load_clip_safetensors(path: str | os.PathLike[str]) -> tuple[StateDict, ClipArch]:
    """Read our format (torch-free).

    Raises
    ------
    CheckpointError
        If the file is not ours or does not match its recorded architecture.
    """
    tensors, meta = _read_safetensors(Path(path))
    if meta.get(META_FORMAT) != FORMAT_TAG or META_ARCH not in meta:
        raise CheckpointError(f"{path}: not a wcbench CLIP safetensors file (use read_state_dict for others)")
    arch = ClipArch.from_json(meta[META_ARCH])
    sd = {k: np.asarray(v, np.float32) for k, v in tensors.items()}
    check_state_dict(sd, arch)
    return sd, arch
