"""CLIP-S / CLIP-DS on the torch-free side: tiny random-weight ONNX towers from tests/data.

``tests/data/make_tiny_onnx.py`` regenerates the ONNX files; ``test_clip_onnx.py`` checks them
against torch. Here nothing imports torch.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from metric_tester import check_metric
from paths import DATA

from wcbench.core.models.catalogue import ModelEntry, ModelSource
from wcbench.core.models.store import ModelStore
from wcbench.metrics.base import MetricContext
from wcbench.metrics.clip.encoder import ClipEncoder
from wcbench.metrics.clip.onnx_backend import OnnxClipBackend
from wcbench.metrics.clip.score import (
    DEGENERATE_NORM,
    ClipDirectionalScore,
    ClipScore,
    clip_ds,
    clip_ds_per_frame,
    clip_s,
    load_weather_prompts,
)

VISUAL, TEXT = DATA / "clip_tiny_visual.onnx", DATA / "clip_tiny_text.onnx"
#: Cosines of float64-normalised float32 embeddings: float32 rounding only.
COS_TOL = 1e-6


class WordTokenizer:
    """Toy tokenizer for the tiny text tower (vocabulary 512): one id per word, 511 ends a row."""

    def tokenize(self, texts: Sequence[str], *, truncate: bool = True) -> np.ndarray:
        out = np.zeros((len(texts), 77), np.int64)
        for r, text in enumerate(texts):
            words = text.lower().split()
            if len(words) + 2 > 77 and not truncate:
                raise ValueError(f"text needs {len(words) + 2} tokens, more than the context length 77")
            ids = [510, *(1 + sum(map(ord, w)) % 500 for w in words[:75]), 511]
            out[r, : len(ids)] = ids
        return out


class CountingBackend:
    """Wraps a backend and counts the images it is asked to embed."""

    def __init__(self, inner: OnnxClipBackend):
        self.inner = inner
        self.backend = inner.backend
        self.identity = inner.identity
        self.image_size = inner.image_size
        self.images = 0
        self.calls = 0

    def encode_image(self, pixels: np.ndarray) -> np.ndarray:
        self.calls += 1
        self.images += len(pixels)
        return self.inner.encode_image(pixels)

    def encode_text(self, tokens: np.ndarray) -> np.ndarray:
        return self.inner.encode_text(tokens)


@pytest.fixture(scope="module")
def onnx_backend() -> OnnxClipBackend:
    return OnnxClipBackend(VISUAL, TEXT, threads=1)


@pytest.fixture
def counting(onnx_backend: OnnxClipBackend) -> CountingBackend:
    return CountingBackend(onnx_backend)


@pytest.fixture
def encoder(counting: CountingBackend) -> ClipEncoder:
    return ClipEncoder(counting, tokenizer=WordTokenizer(), batch_size=3, name="clip-tiny")


def frames(rng: np.random.Generator, n: int = 4, h: int = 45, w: int = 80) -> np.ndarray:
    return rng.random((n, h, w, 3)).astype(np.float32)


def ctx(weather: str, **kw: object) -> MetricContext:
    return MetricContext(weather=weather, n_frames=4, has_reference=False, **kw)  # type: ignore[arg-type]


# -- the formulas ---------------------------------------------------------------------------


def test_clip_ds_formula_by_hand() -> None:
    f_src = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    f_edit = np.array([[0.6, 0.8, 0.0], [0.0, 1.0, 0.0]])
    direction = np.array([0.0, 2.0, 0.0])
    values, degenerate = clip_ds_per_frame(f_src, f_edit, direction)
    delta = np.array([-0.4, 0.8, 0.0])
    assert values[0] == pytest.approx(delta @ [0, 1, 0] / np.linalg.norm(delta), abs=1e-12)
    assert values[1] == 0.0 and degenerate.tolist() == [False, True]
    with pytest.raises(ValueError, match="text direction is zero"):
        clip_ds_per_frame(f_src, f_edit, np.zeros(3))


def test_clip_s_identical_frames_is_one(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    x = frames(rng)
    m = ClipScore(embedder=encoder)
    m.update(x, source=x)
    out = m.compute()["clip_s"]
    assert out.value == pytest.approx(1.0, abs=COS_TOL)
    assert len(out.per_frame) == 4 and "raw cosine" in out.variant


def test_clip_s_batch_equals_accumulated_and_functional(
    encoder: ClipEncoder, rng: np.random.Generator
) -> None:
    src, edit = frames(rng, 5), frames(rng, 5)
    whole = ClipScore(embedder=encoder)
    whole.update(edit, source=src)
    parts = ClipScore(embedder=encoder)
    for i in range(5):
        parts.update(edit[i], source=src[i])
    a, b = whole.compute()["clip_s"], parts.compute()["clip_s"]
    np.testing.assert_allclose(a.per_frame, b.per_frame, atol=1e-12)
    assert clip_s(src, edit, model=encoder) == pytest.approx(a.value, abs=1e-12)
    assert -1.0 <= a.value <= 1.0 and a.value < 1.0 - 1e-4
    whole.reset()
    assert whole.compute()["clip_s"].value is None


def test_shared_metric_tester(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    src = frames(rng, 4)
    edit = np.clip(src + 0.3 * rng.standard_normal(src.shape), 0, 1)
    out = check_metric(lambda: ClipScore(embedder=encoder), edit, source=src,
                       functional={"clip_s": lambda p, s, r: clip_s(s, p, model=encoder)})
    assert out["clip_s"].value is not None and out["clip_s"].value < 1.0
    functional = {
        "clip_ds": lambda p, s, r: clip_ds(s, p, "rain", model=encoder),
        "clip_ds_directional": lambda p, s, r: clip_ds(s, p, "rain", model=encoder, form="directional"),
    }
    check_metric(lambda: ClipDirectionalScore(weather="rain", embedder=encoder), edit, source=src,
                 functional=functional)


def test_clip_ds_zero_delta_is_zero_with_degenerate_count(
    encoder: ClipEncoder, rng: np.random.Generator
) -> None:
    src = frames(rng, 3)
    edit = src.copy()
    edit[1] = frames(rng, 1)[0]  # one real edit, two unchanged frames
    m = ClipDirectionalScore(weather="rain", embedder=encoder)
    m.update(edit, source=src)
    out = m.compute()
    for name in ("clip_ds", "clip_ds_directional"):
        v = out[name]
        assert v.per_frame[0] == 0.0 and v.per_frame[2] == 0.0 and v.per_frame[1] != 0.0
        assert v.extra["degenerate"] == 2 and v.value is not None and np.isfinite(v.value)
        assert v.extra["target_text"] == load_weather_prompts()["rain"].target
    assert "paper form" in out["clip_ds"].variant
    assert "instruct-pix2pix" in out["clip_ds_directional"].variant
    assert clip_ds(src[0], src[0], "rain", model=encoder) == 0.0


def test_clip_ds_matches_embeddings_by_hand(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    src, edit = frames(rng, 2), frames(rng, 2)
    p = load_weather_prompts()["snow"]
    f0, f1 = encoder.image_embeddings(src), encoder.image_embeddings(edit)
    gt, gs = encoder.text_embeddings([p.target, p.source])
    d = f1 - f0
    paper = (d @ gt) / np.linalg.norm(d, axis=1)
    direc = (d @ (gt - gs)) / (np.linalg.norm(d, axis=1) * np.linalg.norm(gt - gs))
    assert clip_ds(src, edit, "snow", model=encoder) == pytest.approx(paper.mean(), abs=COS_TOL)
    assert clip_ds(src, edit, "snow", model=encoder, form="directional") == pytest.approx(
        direc.mean(), abs=COS_TOL
    )
    with pytest.raises(ValueError, match="form must be one of"):
        clip_ds(src, edit, "snow", model=encoder, form="ip2p")


def test_degenerate_threshold_is_small() -> None:
    # Unit embeddings in float32: a real edit moves them by far more than float32 noise (~1e-7).
    assert 1e-7 < DEGENERATE_NORM <= 1e-5


# -- applicability --------------------------------------------------------------------------


def test_skip_rules(encoder: ClipEncoder) -> None:
    s, ds = ClipScore(embedder=encoder), ClipDirectionalScore(embedder=encoder)
    assert "visibility" in (s.skip_reason(ctx("fog")) or "")
    assert ds.skip_reason(ctx("fog")) is None
    assert "no target text" in (ds.skip_reason(ctx("clear")) or "")
    assert s.skip_reason(ctx("clear")) is None
    assert "source" in (s.skip_reason(ctx("rain", has_source=False)) or "")
    assert "no CLIP-DS texts" in (ds.skip_reason(ctx("sandstorm")) or "")


def test_missing_weights_skip_message(tmp_path: Path) -> None:
    store = ModelStore(tmp_path / "empty")
    reason = ClipScore(store=store).skip_reason(ctx("rain"))
    assert reason == (
        "weights for clip-vit-b32-openai not installed: run `wcbench models pull clip-vit-b32-openai` "
        "or `wcbench models import clip-vit-b32-openai FILE`"
    )
    assert "clip-vit-b32-openai" in (ClipDirectionalScore(store=store).skip_reason(ctx("rain")) or "")


def test_bind_picks_the_weather(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    m = ClipDirectionalScore(embedder=encoder)
    with pytest.raises(ValueError, match="no weather bound"):
        m.update(frames(rng, 1), source=frames(rng, 1))
    m.bind(ctx("fog"))
    m.reset()
    m.update(frames(rng, 1), source=frames(rng, 1))
    assert m.compute()["clip_ds"].extra["weather"] == "fog"
    assert m.config()["texts"]["target"] == load_weather_prompts()["fog"].target
    fixed = ClipDirectionalScore(weather="rain", embedder=encoder)
    fixed.bind(ctx("snow"))
    assert fixed.weather == "rain"


def test_shape_and_source_errors(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    m = ClipScore(embedder=encoder)
    with pytest.raises(
        ValueError, match=r"pred has shape \(2, 45, 80, 3\) but source has shape \(2, 40, 80, 3\)"
    ):
        m.update(frames(rng, 2), source=frames(rng, 2, h=40))
    with pytest.raises(ValueError, match="source frames are required"):
        m.update(frames(rng, 2))


def test_empty_batch_and_bad_options(encoder: ClipEncoder) -> None:
    empty = np.zeros((0, 8, 8, 3), np.float32)
    with pytest.raises(ValueError, match="no score: no frames were scored"):
        clip_s(empty, empty, model=encoder)
    with pytest.raises(ValueError, match="backend must be one of"):
        ClipScore(backend="tensorrt")
    with pytest.raises(ValueError, match="crop must be one of"):
        ClipDirectionalScore(crop="pad")


def test_prompts_file_validation(tmp_path: Path) -> None:
    builtin = load_weather_prompts()
    assert {"rain", "snow", "fog", "clear"} <= set(builtin)
    same = tmp_path / "same.toml"
    same.write_text('[rain]\ntarget = "x y"\nsource = "x y"\n')
    with pytest.raises(ValueError, match=r"\[rain\]: target and source texts must differ"):
        load_weather_prompts(same)
    missing = tmp_path / "missing.toml"
    missing.write_text('[rain]\ntarget = "wet"\n')
    with pytest.raises(ValueError, match="'source' must be a non-empty string"):
        ClipDirectionalScore(prompts=missing)
    custom = tmp_path / "custom.toml"
    custom.write_text('[rain]\ntarget = "rainy street"\nsource = "street"\n')
    m = ClipDirectionalScore(prompts=custom)
    assert m.prompts["rain"].target == "rainy street" and m.config()["prompts_file"] == str(custom)


# -- embedding cache ------------------------------------------------------------------------


def test_second_method_reuses_source_embeddings(
    encoder: ClipEncoder, counting: CountingBackend, rng: np.random.Generator
) -> None:
    src, method_a, method_b = frames(rng, 4), frames(rng, 4), frames(rng, 4)
    ClipScore(embedder=encoder).update(method_a, source=src)
    assert counting.images == 8
    ClipScore(embedder=encoder).update(method_b, source=src)  # a second method, same scene
    assert counting.images == 12  # only method_b's frames
    ClipDirectionalScore(weather="rain", embedder=encoder).update(method_b, source=src)
    assert counting.images == 12  # another metric: nothing re-embedded
    assert counting.calls == 6  # 4 frames in batches of 3 -> 2 calls per new set of frames


def test_uint8_and_float_share_cache_entries(encoder: ClipEncoder, counting: CountingBackend) -> None:
    u8 = np.random.default_rng(3).integers(0, 256, (2, 30, 50, 3), dtype=np.uint8)
    a = encoder.image_embeddings(u8)
    b = encoder.image_embeddings(u8 / 255.0)
    assert counting.images == 2
    np.testing.assert_array_equal(a, b)


def test_duplicate_frames_in_one_batch_embed_once(encoder: ClipEncoder, counting: CountingBackend) -> None:
    x = np.random.default_rng(4).random((1, 30, 50, 3))
    out = encoder.image_embeddings(np.concatenate([x, x, x]))
    assert counting.images == 1 and out.shape == (3, 8)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)


def test_disk_cache_survives_a_new_encoder(onnx_backend: OnnxClipBackend, tmp_path: Path) -> None:
    x = np.random.default_rng(5).random((3, 30, 50, 3))
    first = CountingBackend(onnx_backend)
    a = ClipEncoder(first, cache_dir=tmp_path, name="tiny").image_embeddings(x)
    assert first.images == 3
    files = sorted(tmp_path.rglob("*.npy"))
    assert len(files) == 3 and not list(tmp_path.rglob("*.tmp"))
    second = CountingBackend(onnx_backend)
    enc2 = ClipEncoder(second, cache_dir=tmp_path, name="tiny")
    b = enc2.image_embeddings(x)
    assert second.images == 0 and enc2.image_cache.disk_hits == 3
    np.testing.assert_array_equal(a, b)
    # Another crop is another namespace: no stale reuse.
    third = CountingBackend(onnx_backend)
    ClipEncoder(third, cache_dir=tmp_path, name="tiny", crop="squash").image_embeddings(x)
    assert third.images == 3
    # A damaged file is a miss, recomputed and rewritten.
    files[0].write_bytes(b"garbage")
    fourth = CountingBackend(onnx_backend)
    ClipEncoder(fourth, cache_dir=tmp_path, name="tiny").image_embeddings(x)
    assert fourth.images == 1


def test_config_names_model_and_crop(encoder: ClipEncoder) -> None:
    cfg = ClipScore(embedder=encoder).config()
    assert cfg["model"] == "clip-tiny" and cfg["backend"] == "onnx"
    assert cfg["preprocess"]["crop"] == "center" and cfg["weights"].startswith("onnx:")


def test_text_too_long_is_an_error_naming_the_file(
    encoder: ClipEncoder, tmp_path: Path, rng: np.random.Generator
) -> None:
    long = tmp_path / "long.toml"
    long.write_text('[rain]\ntarget = "' + "rain " * 80 + '"\nsource = "street"\n')
    m = ClipDirectionalScore(weather="rain", prompts=long, embedder=encoder)
    with pytest.raises(ValueError, match=r"long\.toml \[rain\]: text needs 82 tokens"):
        m.update(frames(rng, 1), source=frames(rng, 1))


# -- through the model store, without torch -------------------------------------------------


def install_tiny(sources: Sequence[Path], out_dir: Path, entry: ModelEntry) -> None:
    """A converter for tests: the tiny ONNX pair as an installed CLIP entry."""
    import shutil

    shutil.copyfile(sources[0], out_dir / entry.file)
    shutil.copyfile(VISUAL, out_dir / "visual.onnx")
    shutil.copyfile(TEXT, out_dir / "text.onnx")


def tiny_store(root: Path) -> ModelStore:
    entry = ModelEntry(
        name="clip-tiny",
        kind="clip",
        description="tiny",
        file="model.safetensors",
        source=ModelSource(kind="import"),
        converter=install_tiny,
    )
    return ModelStore(root, registry={"clip-tiny": entry})


def test_store_encoder_end_to_end(tmp_path: Path, rng: np.random.Generator) -> None:
    from wcbench.metrics.clip.encoder import clear_shared_encoders, load_clip_encoder

    store = tiny_store(tmp_path / "store")
    dummy = tmp_path / "weights.bin"
    dummy.write_bytes(b"placeholder")
    assert ClipScore(model="clip-tiny", store=store).skip_reason(ctx("rain")) is not None
    store.import_file("clip-tiny", dummy)
    m = ClipScore(model="clip-tiny", store=store)
    assert m.skip_reason(ctx("rain")) is None
    x = frames(rng, 2)
    m.update(x, source=x)
    assert m.compute()["clip_s"].value == pytest.approx(1.0, abs=COS_TOL)
    assert list((store.cache_dir / "clip-embeddings").rglob("*.npy"))
    enc = load_clip_encoder("clip-tiny", store=store)
    assert enc.config()["weights_sha256"] == store.sha256("clip-tiny")
    clear_shared_encoders()


def test_scoring_side_imports_and_runs_without_torch(tmp_path: Path) -> None:
    code = f"""
import sys
sys.modules["torch"] = None  # any `import torch` now raises ImportError
import numpy as np
from wcbench.metrics.clip.onnx_backend import OnnxClipBackend
from wcbench.metrics.clip.encoder import ClipEncoder
from wcbench.metrics.clip.score import ClipScore, ClipDirectionalScore, clip_s
import wcbench.metrics.clip.pytorch.checkpoints, wcbench.metrics.clip.tokenizer, wcbench.core.models.store
enc = ClipEncoder(OnnxClipBackend({str(VISUAL)!r}, {str(TEXT)!r}), name="tiny")
x = np.random.default_rng(0).random((2, 40, 60, 3))
print(clip_s(x, x, model=enc))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert abs(float(proc.stdout.strip()) - 1.0) < COS_TOL


def test_metric_values_are_json_ready(encoder: ClipEncoder, rng: np.random.Generator) -> None:
    m = ClipDirectionalScore(weather="snow", embedder=encoder)
    m.update(frames(rng, 2), source=frames(rng, 2))
    for v in m.compute().values():
        json.dumps({"value": v.value, "per_frame": v.per_frame, "extra": v.extra, "variant": v.variant})
