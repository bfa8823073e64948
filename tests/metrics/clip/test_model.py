"""The torch CLIP and its checkpoint loaders, each on a file written in its real format."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

import importlib.util  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from paths import DATA  # noqa: E402

from wcbench.core.errors import InputError  # noqa: E402
from wcbench.core.models.catalogue import ModelEntry, ModelSource  # noqa: E402
from wcbench.core.models.store import ModelStore  # noqa: E402
from wcbench.core.models.store_errors import ModelStoreError, UntrustedTorchScriptError  # noqa: E402
from wcbench.metrics.clip.config import CLIP_ARCHS, ClipArch, get_arch  # noqa: E402
from wcbench.metrics.clip.encoder import ClipEncoder  # noqa: E402
from wcbench.metrics.clip.pytorch.backend import TorchClipBackend  # noqa: E402
from wcbench.metrics.clip.pytorch.checkpoints import (  # noqa: E402
    CheckpointError,
    check_state_dict,
    expected_shapes,
    infer_arch,
    load_clip_safetensors,
    read_state_dict,
    save_clip_safetensors,
)
from wcbench.metrics.clip.pytorch.convert import build_model, load_clip_model  # noqa: E402
from wcbench.metrics.clip.pytorch.model import ClipModel  # noqa: E402

#: (pixels [B, 3, S, S] float32, tokens [B, 77] int64) torch tensors.
Inputs = tuple[Any, Any]
#: Same weights, same float32 arithmetic up to op order: rounding only.
SAME_TOL = 1e-5


def _tiny_module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("make_tiny_onnx", DATA / "make_tiny_onnx.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


TINY = _tiny_module()


@pytest.fixture(scope="module")
def tiny() -> ClipModel:
    return TINY.tiny_model()


@pytest.fixture(scope="module")
def inputs() -> Inputs:
    g = torch.Generator().manual_seed(1)
    pixels = torch.randn(3, 3, 32, 32, generator=g)
    tokens = torch.zeros(3, 77, dtype=torch.long)
    for r, n in enumerate((3, 10, 40)):
        tokens[r, :n] = torch.randint(1, 500, (n,), generator=g)
        tokens[r, n] = 511  # end-of-text: the largest id
    return pixels, tokens


def outputs(model: ClipModel, inputs: Inputs) -> tuple[np.ndarray, np.ndarray]:
    with torch.no_grad():
        img, txt = model(*inputs)
    return img.numpy(), txt.numpy()


def assert_same_outputs(a: ClipModel, b: ClipModel, inputs: Inputs, tol: float) -> None:
    for x, y in zip(outputs(a, inputs), outputs(b, inputs)):
        np.testing.assert_allclose(x, y, rtol=0, atol=tol)


def state_dict_np(model: ClipModel) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy().copy() for k, v in model.state_dict().items()}


# -- architecture ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(CLIP_ARCHS))
def test_expected_shapes_match_the_module(name: str) -> None:
    arch = CLIP_ARCHS[name]
    with torch.device("meta"):  # shapes only, no memory
        model = ClipModel(arch)
    assert {k: tuple(v.shape) for k, v in model.state_dict().items()} == expected_shapes(arch)
    n_params = sum(p.numel() for p in model.parameters())
    # Parameter counts of OpenAI's released models (logit_scale included).
    assert n_params == {"ViT-B/32": 151_277_313, "ViT-B/16": 149_620_737, "ViT-L/14": 427_616_513}[name]


def test_arch_lookup_and_inference(tiny: ClipModel) -> None:
    assert get_arch("ViT-B-32") == CLIP_ARCHS["ViT-B/32"]
    assert get_arch("ViT-L/14", act="gelu").act == "gelu"
    with pytest.raises(ValueError, match="known: ViT-B/32"):
        get_arch("RN50")
    inferred = infer_arch(state_dict_np(tiny), name="tiny")
    assert inferred.vision_layers == 1 and inferred.image_size == 32 and inferred.vocab_size == 512
    with torch.device("meta"):
        b32 = ClipModel(CLIP_ARCHS["ViT-B/32"]).state_dict()
    assert infer_arch(b32, name="ViT-B/32") == CLIP_ARCHS["ViT-B/32"]
    assert ClipArch.from_json(CLIP_ARCHS["ViT-L/14"].to_json()) == CLIP_ARCHS["ViT-L/14"]


def test_activation_matters(tiny: ClipModel, inputs: Inputs) -> None:
    gelu = build_model(state_dict_np(tiny), tiny.arch.with_act("gelu"))
    diff = np.abs(outputs(gelu, inputs)[0] - outputs(tiny, inputs)[0]).max()
    assert diff > 1e-3  # a wrong activation is not a rounding error: it is part of the architecture


def test_text_features_ignore_padding(tiny: ClipModel, inputs: Inputs) -> None:
    _, tokens = inputs
    noisy = tokens.clone()
    noisy[0, 5:] = 7  # garbage after the end token (id 511 stays the row maximum)
    with torch.no_grad():
        a, b = tiny.encode_text(tokens), tiny.encode_text(noisy)
    torch.testing.assert_close(a[0], b[0], rtol=0, atol=1e-6)  # causal mask: later tokens are invisible


def test_shape_errors(tiny: ClipModel) -> None:
    with pytest.raises(ValueError, match=r"expected \[B, 3, 32, 32\], got \(1, 3, 64, 64\)"):
        tiny.encode_image(torch.zeros(1, 3, 64, 64))
    with pytest.raises(ValueError, match=r"expected \[B, 77\], got \(1, 10\)"):
        tiny.encode_text(torch.zeros(1, 10, dtype=torch.long))


# -- loaders, one real format each ----------------------------------------------------------


def test_openai_torchscript_archive(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    # OpenAI's released .pt files are TorchScript archives with float16 matrices and three scalar
    # entries in the state dict; we write one the same way.
    src = TINY.tiny_model()
    for name, value in (("input_resolution", 32), ("context_length", 77), ("vocab_size", 512)):
        src.register_buffer(name, torch.tensor(value))
    traced = torch.jit.trace(src, inputs, check_trace=False)
    with torch.no_grad():
        for name, p in traced.named_parameters():
            if p.ndim >= 2 or name.endswith("proj") or (name.endswith(".bias") and "ln" not in name):
                p.data = p.data.half()  # as OpenAI's convert_weights
    path = tmp_path / "ViT-tiny.pt"
    traced.save(str(path))
    with pytest.raises(UntrustedTorchScriptError, match="--trust-torchscript"):
        read_state_dict(path)  # loading runs the archive's code: only when the caller trusts it
    sd, fmt = read_state_dict(path, trust_torchscript=True)
    assert fmt == "openai-torchscript" and "input_resolution" not in sd
    assert all(v.dtype == np.float32 for v in sd.values())
    # The reference: the same weights rounded through float16.
    ref = TINY.tiny_model()
    with torch.no_grad():
        for name, p in traced.named_parameters():
            if p.dtype == torch.float16:
                dict(ref.named_parameters())[name].data = p.data.float()
    assert_same_outputs(build_model(sd, tiny.arch), ref, inputs, SAME_TOL)


class _MarkerOnLoad(torch.nn.Module):
    """A TorchScript module whose ``__setstate__`` (run by ``torch.jit.load``) writes a file."""

    def __init__(self, marker: str) -> None:
        super().__init__()
        self.marker = marker
        self.weight = torch.nn.Parameter(torch.ones(2))

    @torch.jit.export
    def __getstate__(self) -> tuple[str, bool, torch.Tensor]:
        return (self.marker, self.training, self.weight)

    @torch.jit.export
    def __setstate__(self, state: tuple[str, bool, torch.Tensor]) -> None:
        self.marker = state[0]
        self.training = state[1]
        self.weight = state[2]
        torch.save(torch.ones(1), self.marker)  # code from the data file, run at load time

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.weight


def test_torchscript_archive_is_never_loaded_without_the_flag(tmp_path: Path) -> None:
    marker = tmp_path / "code-ran.marker"
    path = tmp_path / "ViT-B-32.pt"
    torch.jit.script(_MarkerOnLoad(str(marker))).save(str(path))
    assert not marker.exists()
    with pytest.raises(InputError) as info:
        read_state_dict(path)
    msg = str(info.value)
    assert str(path) in msg and "--trust-torchscript" in msg and "trusted source" in msg and "state dict" in msg
    assert not marker.exists()  # refused from the zip listing: the archive was never loaded
    # The same through the model store: refused before the converter, nothing installed.
    store = ModelStore(tmp_path / "store", registry={"clip-tiny": tiny_entry(arch="ViT-B/32")})
    with pytest.raises(UntrustedTorchScriptError, match="--trust-torchscript"):
        store.import_file("clip-tiny", path)
    assert not marker.exists() and not store.available("clip-tiny")
    assert not (tmp_path / "store" / "clip-tiny").exists()
    # The fixture is live: trusting the file loads it, and that runs its code.
    read_state_dict(path, trust_torchscript=True)
    assert marker.exists()


def test_openai_plain_state_dict(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    path = tmp_path / "clip.pt"
    torch.save(tiny.state_dict(), path)
    sd, fmt = read_state_dict(path)
    assert fmt == "openai/open_clip state dict"
    assert_same_outputs(build_model(sd, tiny.arch), tiny, inputs, 0.0)


def test_open_clip_training_checkpoint(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    # open_clip's training loop saves {"epoch", "name", "state_dict" (DDP "module." keys), "optimizer"};
    # old versions also kept the causal mask as a persistent buffer.
    sd = {f"module.{k}": v for k, v in tiny.state_dict().items()}
    sd["module.attn_mask"] = tiny.attn_mask.clone()
    path = tmp_path / "epoch_32.pt"
    torch.save(
        {"epoch": 32, "name": "run", "state_dict": sd, "optimizer": {"state": {}, "param_groups": []}}, path
    )
    loaded, fmt = read_state_dict(path)
    assert fmt == "openai/open_clip state dict"
    assert_same_outputs(build_model(loaded, tiny.arch), tiny, inputs, 0.0)


def test_open_clip_safetensors(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    from safetensors.torch import save_file

    path = tmp_path / "open_clip_model.safetensors"
    save_file({k: v.contiguous() for k, v in tiny.state_dict().items()}, str(path))
    loaded, fmt = read_state_dict(path)
    assert fmt == "openai/open_clip state dict"
    assert_same_outputs(build_model(loaded, tiny.arch), tiny, inputs, 0.0)


def test_our_safetensors_round_trip(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    path = tmp_path / "model.safetensors"
    save_clip_safetensors(path, state_dict_np(tiny), tiny.arch, source_format="test")
    _, arch = load_clip_safetensors(path)
    assert arch == tiny.arch and read_state_dict(path)[1] == "wcbench"
    assert_same_outputs(load_clip_model(path), tiny, inputs, 0.0)
    with pytest.raises(CheckpointError, match="not a wcbench CLIP"):
        other = tmp_path / "other.safetensors"
        from safetensors.numpy import save_file

        save_file({"x": np.zeros(2, np.float32)}, str(other))
        load_clip_safetensors(other)


def test_mismatch_names_keys_and_shapes(tiny: ClipModel) -> None:
    sd = state_dict_np(tiny)
    with pytest.raises(
        CheckpointError,
        match=r"ViT-B/32: missing 264 keys .*shape mismatch: ln_final.bias: \(16,\) != \(512,\)",
    ):
        check_state_dict(sd, CLIP_ARCHS["ViT-B/32"])
    del sd["ln_final.bias"]
    sd["extra.weight"] = np.zeros(1, np.float32)
    with pytest.raises(
        CheckpointError, match=r"missing 1 keys \(e.g. \['ln_final.bias'\]\), unexpected 1 keys"
    ):
        check_state_dict(sd, tiny.arch)


def test_foreign_files_are_rejected(tmp_path: Path) -> None:
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"this is not a checkpoint")
    with pytest.raises(CheckpointError, match="not a torch checkpoint"):
        read_state_dict(junk)
    lst = tmp_path / "list.pt"
    torch.save([1, 2], lst)
    with pytest.raises(CheckpointError, match="expected a state dict"):
        read_state_dict(lst)
    with pytest.raises(CheckpointError, match="not a CLIP ViT state dict"):
        infer_arch({"visual.layer1.0.conv1.weight": np.zeros((64, 3, 3, 3))})


# -- the store converter --------------------------------------------------------------------


def tiny_entry(**options: object) -> ModelEntry:
    return ModelEntry(
        name="clip-tiny",
        kind="clip",
        description="toy",
        file="model.safetensors",
        source=ModelSource(kind="import"),
        converter="wcbench.metrics.clip.pytorch.convert:convert_clip",
        options=options,
    )


def test_import_converts_and_exports_onnx(tiny: ClipModel, inputs: Inputs, tmp_path: Path) -> None:
    from dataclasses import asdict

    ckpt = tmp_path / "tiny.pt"
    torch.save(tiny.state_dict(), ckpt)
    store = ModelStore(tmp_path / "store", registry={"clip-tiny": tiny_entry(arch=asdict(TINY.tiny_arch()))})
    store.import_file("clip-tiny", ckpt)
    man = store.manifest("clip-tiny")
    assert man is not None and set(man["files"]) == {"model.safetensors", "visual.onnx", "text.onnx"}
    # intact, but an import-only entry pins no sha256: verify and every result say so
    assert store.verify()[0].status == "unverified"
    from wcbench.metrics.clip.encoder import load_clip_encoder
    from wcbench.metrics.clip.score import ClipScore

    x = np.random.default_rng(0).random((2, 40, 60, 3))
    encoder = load_clip_encoder("clip-tiny", store=store, disk_cache=False)
    assert encoder.config()["weights_verified"] is False
    assert ClipScore(model="clip-tiny", store=store).config()["weights_verified"] is False
    onnx_emb = encoder.image_embeddings(x)
    torch_emb = load_clip_encoder(
        "clip-tiny", store=store, backend="torch", disk_cache=False
    ).image_embeddings(x)
    np.testing.assert_allclose(onnx_emb, torch_emb, atol=SAME_TOL)
    # Importing into an entry of another architecture fails and installs nothing new.
    wrong = ModelStore(tmp_path / "store2", registry={"clip-tiny": tiny_entry(arch="ViT-B/32")})
    with pytest.raises(ModelStoreError, match="does not match CLIP ViT-B/32"):
        wrong.import_file("clip-tiny", ckpt)
    assert not wrong.available("clip-tiny")


def test_torch_backend_in_an_encoder(tiny: ClipModel) -> None:
    enc = ClipEncoder(TorchClipBackend(tiny, identity="tiny"), name="tiny")
    x = np.random.default_rng(0).random((2, 40, 60, 3))
    out = enc.image_embeddings(x)
    assert out.shape == (2, 8) and enc.config()["backend"] == "torch"
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
