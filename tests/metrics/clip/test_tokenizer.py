"""CLIP's BPE tokenizer against the ids the released CLIP produces, and our architecture table
against open_clip's model configs (torch-free).

Both come from the pinned open-clip-torch wheel (``pip download``, a package registry), fetched
into pytest's cache once; without a reachable registry the tests skip.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from registry import registry_unreachable

from wcbench.core.models.store import ModelStore
from wcbench.core.models.store_errors import ModelStoreError
from wcbench.core.storage import sha256_file
from wcbench.metrics.clip.config import CLIP_ARCHS
from wcbench.metrics.clip.score import DEFAULT_PROMPTS, load_weather_prompts
from wcbench.metrics.clip.tokenizer import VOCAB_ENTRY, ClipTokenizer, clean_text, split_words


def _cache_dir(request: pytest.FixtureRequest, name: str) -> Path:
    """pytest's cache folder ``name`` (kept between runs), or a session temp folder without it."""
    cache = getattr(request.config, "cache", None)
    if cache is not None:
        return Path(cache.mkdir(name))
    return Path(request.getfixturevalue("tmp_path_factory").mktemp(name))


@pytest.fixture(scope="session")
def vocab_path(request: pytest.FixtureRequest) -> Path:
    """CLIP's vocabulary file, pulled once into pytest's cache (skip when no registry is reachable)."""
    store = ModelStore(_cache_dir(request, "wcbench-clip-vocab"))
    if not store.available(VOCAB_ENTRY):
        try:
            store.pull(VOCAB_ENTRY)
        except ModelStoreError as exc:
            registry_unreachable(f"CLIP vocabulary not fetchable here: {exc}")
    return store.path(VOCAB_ENTRY)


@pytest.fixture(scope="session")
def tok(vocab_path: Path) -> ClipTokenizer:
    return ClipTokenizer(vocab_path)


def test_known_ids(tok: ClipTokenizer) -> None:
    # The ids OpenAI's clip.tokenize and open_clip give for this text (the CLIP README example).
    row = tok.tokenize("a photo of a cat")[0]
    assert row[:7].tolist() == [49406, 320, 1125, 539, 320, 2368, 49407]
    assert not row[7:].any() and row.shape == (77,) and row.dtype == np.int64
    assert tok.vocab_size == 49408


@pytest.mark.parametrize(
    "text",
    [
        "a photo of a cat",
        "A Driving photo of a city street in HEAVY rain, with a wet road!",
        "snow-covered cars at 8:30 am; visibility 50 m",
        "café naïve 东京 ½",
    ],
)
def test_round_trip(tok: ClipTokenizer, text: str) -> None:
    ids = tok.encode(text)
    decoded = tok.decode(ids)
    # Decoding gives the cleaned, lower-cased text with pieces joined by spaces; its re-encoding
    # is the same ids.
    assert decoded.replace(" ", "") == clean_text(text).replace(" ", "")
    assert tok.encode(decoded) == ids


def test_truncation(tok: ClipTokenizer) -> None:
    long = " ".join(["rain"] * 100)
    row = tok.tokenize(long)[0]
    assert row.shape == (77,)
    assert row[0] == 49406 and row[-1] == 49407
    assert set(row[1:-1].tolist()) == {tok.encode("rain")[0]}
    with pytest.raises(ValueError, match="more than the context length 77"):
        tok.tokenize(long, truncate=False)
    exact = " ".join(["rain"] * 75)  # 75 + start + end = 77: fits
    assert tok.tokenize(exact, truncate=False)[0, -1] == 49407


def test_batch_rows(tok: ClipTokenizer) -> None:
    rows = tok.tokenize(["rain", "heavy snow"])
    assert rows.shape == (2, 77)
    assert (rows.argmax(axis=1) == [2, 3]).all()  # end token is the row maximum


def test_split_matches_openai_regex() -> None:
    regex = pytest.importorskip("regex")
    pat = regex.compile(
        r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+""",
        regex.IGNORECASE,
    )
    for text in [
        "it's 2024, we'll see!!! <|endoftext|>x",
        "e\u0301 ab_c 3.14 ...'s ½ ²",
        "東京タワー   rain\tfog",
    ]:
        cleaned = clean_text(text)
        assert split_words(cleaned) == pat.findall(cleaned)


def test_builtin_prompts_are_short(tok: ClipTokenizer) -> None:
    # "well under 77 tokens": leave room so that nothing is ever cut.
    for p in load_weather_prompts(DEFAULT_PROMPTS).values():
        assert tok.count_tokens(p.target) <= 40
        assert tok.count_tokens(p.source) <= 40


def test_matches_transformers_tokenizer(tok: ClipTokenizer, tmp_path: Path, vocab_path: Path) -> None:
    transformers = pytest.importorskip("transformers")
    import gzip
    import json

    # Build Hugging Face's vocab.json / merges.txt from the same BPE file.
    (tmp_path / "vocab.json").write_text(json.dumps(tok.encoder), encoding="utf-8")
    with gzip.open(vocab_path, "rt", encoding="utf-8") as fh:
        merges = fh.read().split("\n")[1 : 49152 - 256 - 2 + 1]
    lines = ["#version: 0.2", *merges]  # HF's header line; the vocabulary file has its own
    (tmp_path / "merges.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    hf = transformers.CLIPTokenizer(str(tmp_path / "vocab.json"), str(tmp_path / "merges.txt"))
    for text in [
        "a photo of a cat",
        "A driving photo of a city street in heavy rain, with a wet road!",
        "snow-covered cars at 8:30 am; visibility 50 m",
    ]:
        assert hf(text)["input_ids"] == [49406, *tok.encode(text), 49407]


def test_archs_match_open_clip_model_configs(request: pytest.FixtureRequest) -> None:
    folder = _cache_dir(request, "wcbench-open-clip-wheel")
    source = ModelStore(folder / "unused").entry(VOCAB_ENTRY).source
    wheels = sorted(folder.glob("open_clip_torch-3.3.0-*.whl"))
    if not wheels:
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--only-binary=:all:",
            str(source.requirement),
            "-d",
            str(folder),
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wheels = sorted(folder.glob("open_clip_torch-3.3.0-*.whl"))
        if proc.returncode != 0 or not wheels:
            registry_unreachable(f"open-clip-torch wheel not fetchable here: {proc.stderr.strip()[-200:]}")
    assert sha256_file(wheels[0]) == source.dist_sha256
    with zipfile.ZipFile(wheels[0]) as zf:
        for name, arch in CLIP_ARCHS.items():
            cfg = json.loads(zf.read(f"open_clip/model_configs/{name.replace('/', '-')}.json"))
            v, t = cfg["vision_cfg"], cfg["text_cfg"]
            assert (cfg["embed_dim"], v["image_size"], v["layers"], v["width"], v["patch_size"]) == (
                arch.embed_dim,
                arch.image_size,
                arch.vision_layers,
                arch.vision_width,
                arch.patch_size,
            )
            assert (t["context_length"], t["vocab_size"], t["width"], t["heads"], t["layers"]) == (
                arch.context_length,
                arch.vocab_size,
                arch.text_width,
                arch.text_heads,
                arch.text_layers,
            )
            assert arch.vision_width // v.get("head_width", 64) == arch.vision_heads
