"""One render route: ``wcbench render`` and ``wcbench run`` go through the same units of work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.methods import get_method, method_options


def test_render_and_run_give_identical_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("numba")
    run_out, render_out = tmp_path / "run", tmp_path / "render"
    assert main(["run", "--method", "lidar-init", "--scenes", "demo", "--out", str(run_out), "--weathers", "rain",
                 "--metrics", "temporal_flicker", "--no-progress"]) == 0
    # no size given to either: the method's own size (lidar-init: a quarter of the scene's)
    assert main(["render", "--scenes", "demo", "--weathers", "rain", "--out", str(render_out),
                 "--no-video", "--no-progress"]) == 0
    capsys.readouterr()
    a = run_out / "lidar-init" / "demo" / "rain"
    b = render_out / "lidar-init" / "demo" / "rain"
    frames = sorted(p.name for p in a.glob("*.png"))
    assert len(frames) == 12 and frames == sorted(p.name for p in b.glob("*.png"))
    for name in frames:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    info_a, info_b = (json.loads((d / "info.json").read_text()) for d in (a, b))
    # same settings, recorded the same way (the key covers method, weather, seed, size and sources)
    assert info_a["key"] == info_b["key"] and info_a["parameters"] == info_b["parameters"]
    assert info_a["timings"]["resolution"] == [80, 45]


def test_render_refuses_a_method_without_physics_weather(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["render", "--method", "filter2d", "--scenes", "demo", "--weathers", "rain", "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "method 'filter2d' takes no option physics" in err
    assert not any(tmp_path.iterdir())


def test_method_options_are_checked_before_construction() -> None:
    pytest.importorskip("torch")  # lidar-init is a reference-model method
    assert {"physics", "size", "scale", "voxel_m", "init_frames"} <= set(method_options("lidar-init"))
    assert method_options("identity") == []
    with pytest.raises(InputError, match="takes no option voxel"):
        get_method("filter2d", voxel=0.1)


def test_run_sizes_a_two_dimensional_method_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--weathers", "rain", "--scale", "0.5",
                 "--frames", "0-3", "--metrics", "temporal_flicker", "--out", str(out), "--no-progress"]) == 0
    info = json.loads((out / "filter2d" / "demo" / "rain" / "info.json").read_text())
    assert info["size"] == [160, 90] and [f["index"] for f in info["frames"]] == [0, 1, 2, 3]
    doc = json.loads((out / "results.json").read_text())
    # rendered at 160x90, scored at the scene's working size like every other method of the scene
    [record] = doc["working_size"]
    assert (record["predictions"], record["to"], record["predictions_resized"]) == ([160, 90], [320, 180], True)
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--width", "100",
                 "--out", str(tmp_path / "x")]) == 2
    assert "--width and --height go together" in capsys.readouterr().err
