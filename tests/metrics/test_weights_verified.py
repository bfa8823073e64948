"""Metrics record whether their weights are the published ones (reports flag the numbers if not)."""

from __future__ import annotations

from pathlib import Path

from wcbench.core.models.catalogue import ModelEntry, ModelSource
from wcbench.core.models.store import ModelStore
from wcbench.core.storage import sha256_bytes
from wcbench.metrics.clip.score import ClipScore


def _store(root: Path, pinned: str | None) -> ModelStore:
    entry = ModelEntry(name="clip-x", kind="clip", description="test", file="model.bin",
                       source=ModelSource(kind="url", url="https://example.invalid/model.bin", sha256=pinned))
    return ModelStore(root, registry={"clip-x": entry})


def test_source_verified_follows_the_pinned_hash(tmp_path: Path) -> None:
    weights = tmp_path / "model.bin"
    weights.write_bytes(b"published weights")
    published = _store(tmp_path / "a", sha256_bytes(b"published weights"))
    assert published.source_verified("clip-x") is None  # not installed
    published.import_file("clip-x", weights)
    assert published.source_verified("clip-x") is True
    other = _store(tmp_path / "b", sha256_bytes(b"something else"))
    other.import_file("clip-x", weights, allow_unverified=True)  # e.g. random test weights under the real name
    assert other.source_verified("clip-x") is False
    unpinned = _store(tmp_path / "c", None)
    unpinned.import_file("clip-x", weights)
    assert unpinned.source_verified("clip-x") is False


def test_clip_config_records_it_next_to_the_hash(tmp_path: Path) -> None:
    weights = tmp_path / "model.bin"
    weights.write_bytes(b"random test weights")
    store = _store(tmp_path / "s", sha256_bytes(b"published weights"))
    store.import_file("clip-x", weights, allow_unverified=True)
    cfg = ClipScore(model="clip-x", store=store).config()
    assert cfg["weights_sha256"] == store.sha256("clip-x") and cfg["weights_verified"] is False
