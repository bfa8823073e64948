"""`--device cuda` without a CUDA device (or without gsplat): one line, exit 2, before any work."""

from __future__ import annotations

import pytest

from wcbench.cli import main

torch = pytest.importorskip("torch")

pytestmark = pytest.mark.model


@pytest.mark.parametrize("argv", [
    ["train", "--scenes", "demo", "--device", "cuda"],
    ["run", "--scenes", "demo", "--method", "weathercity", "--device", "cuda"],
])
def test_cuda_without_a_device_is_refused_in_one_line_before_any_work(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code = main([*argv, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "--device cuda" in err and ("no CUDA device" in err or "gsplat" in err)
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()  # nothing was written: refused before any scene was read


def test_an_unknown_device_is_refused_by_argparse(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--scenes", "demo", "--device", "tpu"])
    assert exc.value.code == 2
