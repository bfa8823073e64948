"""``wcbench render``: a thin front of the units of work ``run`` uses; options, frames and bad input."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from paths import PANDASET

pytest.importorskip("torch")


UP = np.array([0.0, -1.0, 0.0])  # camera at the origin with OpenCV axes: world up is -y


def _args(out: Path, **kw: object) -> argparse.Namespace:
    from wcbench.cli import render

    parser = argparse.ArgumentParser()
    render.add_arguments(parser)
    argv = ["--scenes", str(PANDASET), "--out", str(out)]
    for key, value in kw.items():
        flag = "--" + key.replace("_", "-")
        argv += [flag] if value is True else [flag, str(value)]
    return parser.parse_args(argv)


def test_cli_render_smoke_on_pandaset(tmp_path: Path) -> None:
    if not (PANDASET / "images").is_dir():
        pytest.skip(f"real scene not present at {PANDASET}")
    from wcbench.cli import render
    from wcbench.core.errors import ResultsExistError
    from wcbench.core.storage import sha256_file

    # Frames 16 and 17 have no lidar sweep: the scene comes from the sweeps of 15 and 19.
    common = {
        "weathers": "rain",
        "preset": "heavy",
        "frames": "16-17",
        "width": 96,
        "height": 54,
        "init_frames": "15,19",
        "seed": 3,
    }
    assert render.run(_args(tmp_path, **common)) == 0
    folder = tmp_path / "lidar-init" / "pandaset_002" / "rain"
    info = json.loads((folder / "info.json").read_text())
    assert [f["file"] for f in info["frames"]] == ["016.png", "017.png"]
    for f in info["frames"]:
        assert sha256_file(folder / f["file"]) == f["sha256"]
        assert f["info"]["particles_in_view"] > 0
    assert (
        info["method"] == "lidar-init"
        and info["weather"] == "rain"
        and info["timings"]["resolution"] == [96, 54]
    )
    assert info["parameters"]["renderer"]["particles"]["capped"] is True
    assert (tmp_path / "lidar-init" / "pandaset_002" / "rain.mp4").stat().st_size > 0
    # Same settings: up to date; a damaged frame is re-rendered identically (pure function of the seed).
    assert render.run(_args(tmp_path, **common)) == 0
    (folder / "016.png").write_bytes(b"torn")
    assert render.run(_args(tmp_path, **common)) == 0
    assert sha256_file(folder / "016.png") == info["frames"][0]["sha256"]
    # Other settings: refused unless --overwrite.
    with pytest.raises(ResultsExistError):
        render.run(_args(tmp_path, **{**common, "preset": "light"}))
    # Frame 17 alone is frame 17 of the sequence.
    assert render.run(_args(tmp_path / "alone", **{**common, "frames": "17"})) == 0
    alone = json.loads((tmp_path / "alone/lidar-init/pandaset_002/rain/info.json").read_text())
    assert alone["frames"][0]["sha256"] == info["frames"][1]["sha256"]


def test_cli_parses_frames_and_rejects_bad_input() -> None:
    from wcbench.cli.common import parse_frame_spec
    from wcbench.cli.render import _weather, parse_frames
    from wcbench.core.errors import InputError

    assert parse_frames(tuple(parse_frame_spec("0-2,7")), 10) == [0, 1, 2, 7]
    assert parse_frames(None, 3) == [0, 1, 2]
    for bad in ("5-2", "x", ","):
        with pytest.raises(InputError):
            parse_frame_spec(bad)
    with pytest.raises(InputError, match=r"frame 12 is beyond the 10 frames \(0-9\) of the scene"):
        parse_frames((12,), 10)
    parser = argparse.ArgumentParser()
    from wcbench.cli import render

    render.add_arguments(parser)
    args = parser.parse_args(["--scenes", "x", "--out", "y", "--weathers", "snow", "--wind", "4,20,30"])
    w = _weather(args, "snow")
    assert (w.wind.speed_m_s, w.wind.tilt_deg, w.wind.azimuth_deg) == (4.0, 20.0, 30.0)
    args = parser.parse_args(["--scenes", "x", "--out", "y", "--weathers", "snow", "--wind", "4,20"])
    with pytest.raises(InputError, match="--wind"):
        _weather(args, "snow")
    args = parser.parse_args(["--scenes", "x", "--out", "y", "--weathers", "fog", "--visibility", "-3"])
    with pytest.raises(InputError, match="visibility_m"):
        _weather(args, "fog")


@pytest.mark.parametrize("name", ["physics", "weathers"])  # weathers: the old name of physics
def test_method_option_that_render_sets_itself_is_refused_by_name(tmp_path, capsys, name):
    from wcbench.cli import main

    code = main(["render", "--scenes", "demo", "--weathers", "rain", "--out", str(tmp_path), "--no-progress",
                 "--method-option", f"{name}={{}}"])
    assert code == 2
    # named as given, in one line (no deprecation line before the refusal)
    assert capsys.readouterr().err.strip().endswith(f"--method-option {name}: set by render's own options "
                                                    "(--weathers/--preset..., --voxel, --init-frames)")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("method", ["lidar-init", "weathercity"])
def test_weather_options_with_clear_alone_are_refused_naming_them(tmp_path, capsys, method):
    """``--weathers clear`` has no physics weather: the weather options the user gave are named, not
    an option the user never gave (the ``physics`` dict render would build from them)."""
    from wcbench.cli import main

    code = main(["render", "--method", method, "--scenes", "demo", "--weathers", "clear", "--preset", "heavy",
                 "--fog-mode", "postprocess", "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.endswith("--preset, --fog-mode: --weathers clear has no weather to set; the weather options "
                        "apply to rain, snow and fog"), err
    assert "physics" not in err and "weathers[" not in err
    assert not (tmp_path / "o").exists()


def test_a_render_of_some_frames_is_evaluated_as_is(tmp_path: Path, capsys) -> None:
    from wcbench.cli import main

    out = tmp_path / "renders"
    assert main(["render", "--scenes", "demo", "--weathers", "fog", "--visibility", "40", "--frames", "2-5",
                 "--scale", "0.5", "--no-video", "--out", str(out)]) == 0
    results = tmp_path / "results"
    # no --frames and no --resize: the render's info.json says which frames and what size
    assert main(["evaluate", "--method", "lidar-init", "--scenes", "demo", "--predictions", str(out / "lidar-init"),
                 "--metrics", "temporal_flicker", "--out", str(results)]) == 0
    doc = json.loads((results / "results.json").read_text())
    [scene] = doc["results"]
    assert doc["inputs"]["scenes"][scene]["fog"]["frames"] == [2, 3, 4, 5]
    assert len(doc["results"][scene]["fog"]["temporal_flicker"]["per_frame"]) == 3
    # the render's 160x90 frames are scored at the scene's working size, as every method's are
    assert (doc["working_size"][0]["predictions"], doc["working_size"][0]["to"]) == ([160, 90], [320, 180])
    # and run takes the same --frames
    assert main(["run", "--method", "identity", "--scenes", "demo", "--frames", "0-3", "--weathers", "clear",
                 "--metrics", "psnr", "--out", str(tmp_path / "run")]) == 0
    run = json.loads((tmp_path / "run" / "results.json").read_text())
    assert run["config"]["frames"] == [0, 1, 2, 3]
    assert len(run["results"][scene]["clear"]["psnr"]["per_frame"]) == 4
    assert main(["run", "--method", "identity", "--scenes", "demo", "--frames", "0,2", "--out",
                 str(tmp_path / "bad")]) == 2
    assert "one contiguous run of frames" in capsys.readouterr().err


@pytest.mark.parametrize("offline", [False, True])
def test_render_fetches_the_weights_its_method_trains_with_before_the_first_unit(tmp_path, monkeypatch, offline):
    # `render --method weathercity` trains the scene's model as `run` does: without the content loss's
    # VGG16 fetched first, a fresh machine's render would train (and cache) another model than run's
    if not (PANDASET / "images").is_dir():
        pytest.skip(f"real scene not present at {PANDASET}")
    import wcbench.core.models.fetch as fetch
    import wcbench.units as units
    from wcbench.cli import render

    monkeypatch.delenv(fetch.OFFLINE_ENV, raising=False)  # --offline alone decides
    events: list[tuple[str, object]] = []
    monkeypatch.setattr(fetch, "fetch_missing",
                        lambda names, *, offline: events.append(("fetch", (sorted(names), offline))) or {})

    class Unit:  # stands in for the unit of work: no training, only the order of things
        def __init__(self, method, scene, weather, root):
            self.root, self.weather = root, weather

        def render(self, settings):
            events.append(("unit", self.weather))
            return {"status": "rendered", "frames": [0], "timings": {"median_frame_ms": 1.0}}

    monkeypatch.setattr(units, "WorkUnit", Unit)
    args = _args(tmp_path, weathers="rain", method="weathercity", **({"offline": True} if offline else {}))
    args.weathers = ["rain", "snow"]
    assert render.run(args) == 0
    assert events == [("fetch", (["vgg16"], offline)), ("unit", "rain"), ("unit", "snow")]
    # a method that reads no weights fetches nothing
    events.clear()
    assert render.run(_args(tmp_path / "plain", weathers="rain")) == 0
    assert events == [("unit", "rain")]
