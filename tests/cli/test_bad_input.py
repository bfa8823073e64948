"""Every kind of bad input: exit code 2, a message naming the file and what was expected,
and nothing written or lost."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
from scene_fixtures import write_matrix, write_prediction_folder

from wcbench.cli import main
from wcbench.core.image_io import read_rgb8, write_mp4


@pytest.fixture
def preds(demo_scene, tmp_path):
    return write_prediction_folder(demo_scene, tmp_path / "preds", ["rain", "snow"])


def _evaluate(capsys, *, predictions, out, extra=(), method="folder", scenes="demo"):
    code = main(["evaluate", "--method", method, "--scenes", scenes, "--predictions", str(predictions),
                 "--out", str(out), "--metrics", "temporal_flicker", *extra])
    return code, capsys.readouterr().err


def _assert_refused(code, err, out, *needles):
    assert code == 2, err
    for n in needles:
        assert n in err, f"{n!r} not in {err!r}"
    assert not out.exists(), "bad input must not create the output folder"


def test_unknown_method_suggests(capsys, preds, tmp_path):
    with pytest.raises(SystemExit) as exc:  # refused as the argument is parsed
        _evaluate(capsys, predictions=preds, out=tmp_path / "o", method="contrlnet")
    _assert_refused(exc.value.code, capsys.readouterr().err, tmp_path / "o", "unknown method 'contrlnet'",
                    "Did you mean 'controlnet'")


def test_unknown_scene_set_suggests(capsys, preds, tmp_path):
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", scenes="waymo5")
    _assert_refused(code, err, tmp_path / "o", "unknown scene set 'waymo5'", "Did you mean 'waymo_5'")


def test_unknown_metric_suggests(capsys, preds, tmp_path):
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", extra=["--metrics", "ssmi"])
    _assert_refused(code, err, tmp_path / "o", "unknown metric 'ssmi'", "Did you mean 'ssim'")


def test_missing_data_root_lists_expected_files(capsys, preds, tmp_path):
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", scenes="waymo_5")
    _assert_refused(code, err, tmp_path / "o", "--data-root", "WCBENCH_DATA", "waymo/processed/training/788/images")
    code = main(["evaluate", "--method", "folder", "--scenes", "waymo_5", "--data-root", str(tmp_path / "none"),
                 "--predictions", str(preds), "--out", str(tmp_path / "o")])
    _assert_refused(code, capsys.readouterr().err, tmp_path / "o", str(tmp_path / "none"), "does not exist")


def test_missing_frame(capsys, preds, tmp_path):
    (preds / "rain" / "004.png").unlink()
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(preds / "rain"), "missing frames [4]")


def test_extra_frame(capsys, preds, tmp_path):
    shutil.copy(preds / "rain" / "000.png", preds / "rain" / "012.png")
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(preds / "rain"), "extra files ['012.png']")


def test_mismatched_frame_counts_across_weathers(capsys, preds, tmp_path):
    (preds / "snow" / "011.png").unlink()
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", "frame counts differ across weathers", "rain: 12 frames found",
                    "snow:", "missing frames [11]")


def test_corrupt_image(capsys, preds, tmp_path):
    (preds / "rain" / "006.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(preds / "rain" / "006.png"), "cannot decode")


def test_wrong_image_size(capsys, preds, tmp_path):
    p = preds / "snow" / "002.png"
    cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p)), (100, 60)))
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(p), "100x60, expected 320x180", "--resize")


@pytest.mark.parametrize(("kind", "needle"), [("gray", "grayscale"), ("16bit", "16-bit"), ("rgba", "alpha")])
def test_wrong_image_format(capsys, preds, tmp_path, kind, needle):
    p = preds / "rain" / "001.png"
    img = cv2.imread(str(p))
    if kind == "gray":
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif kind == "16bit":
        img = img.astype(np.uint16) * 257
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    cv2.imwrite(str(p), img)
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(p), needle, "expected an 8-bit RGB image")


@pytest.mark.parametrize("what", ["pose", "intrinsics"])
def test_non_finite_pose_or_intrinsics(capsys, demo_scene, preds, tmp_path, what):
    scene_dir = shutil.copytree(demo_scene.root, tmp_path / "scene")
    if what == "pose":
        bad = scene_dir / "extrinsics" / "003_0.txt"
        m = np.loadtxt(bad)
        m[1, 3] = np.nan
        write_matrix(bad, m)
    else:
        bad = scene_dir / "intrinsics" / "0.txt"
        bad.write_text("200 inf 160 90 0 0 0 0 0\n")
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", scenes=str(scene_dir))
    _assert_refused(code, err, tmp_path / "o", str(bad), "non-finite")


def test_empty_predictions_folder(capsys, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    code, err = _evaluate(capsys, predictions=empty, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(empty), "empty")
    (empty / "rain").mkdir()
    code, err = _evaluate(capsys, predictions=empty, out=tmp_path / "o")
    _assert_refused(code, err, tmp_path / "o", str(empty / "rain"), "no image files")


def test_unreadable_video(capsys, demo_scene, tmp_path):
    root = tmp_path / "fresco"
    (root / "rain").mkdir(parents=True)
    (root / "rain" / "blend.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 truncated")
    code, err = _evaluate(capsys, predictions=root, out=tmp_path / "o", method="fresco")
    _assert_refused(code, err, tmp_path / "o", str(root / "rain" / "blend.mp4"), "video")


def test_video_with_wrong_frame_count(capsys, demo_scene, tmp_path):
    """A short video is an error unless the reader declares that its tool can end early (FRESCO
    does: see test_tool_layouts); a video longer than the scene is an error for every reader."""
    root = tmp_path / "videos"
    frames = [read_rgb8(f.image_path) for f in demo_scene.frames]
    write_mp4(root / "rain" / "blend.mp4", frames[:7])
    code, err = _evaluate(capsys, predictions=root, out=tmp_path / "o", extra=["--pattern", "{weather}/blend.mp4"])
    _assert_refused(code, err, tmp_path / "o", str(root / "rain" / "blend.mp4"), "7 frames, expected 12")
    write_mp4(root / "rain" / "blend.mp4", [*frames, frames[-1]])
    code, err = _evaluate(capsys, predictions=root, out=tmp_path / "o", method="fresco")
    _assert_refused(code, err, tmp_path / "o", str(root / "rain" / "blend.mp4"), "13 frames, expected 12",
                    "video frames 12 fall outside the scene")


def test_results_from_another_schema_version(capsys, preds, tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    old = {"kind": "wcbench-results", "schema_version": 0, "results": {}}
    (out / "results.json").write_text(json.dumps(old))
    code, err = _evaluate(capsys, predictions=preds, out=out)
    assert code == 2 and str(out / "results.json") in err and "schema version 0" in err
    assert json.loads((out / "results.json").read_text()) == old
    assert sorted(p.name for p in out.iterdir()) == ["results.json"]


def test_unsupported_weather_for_reader(capsys, preds, tmp_path):
    code = main(["evaluate", "--method", "controlnet", "--scenes", "demo", "--predictions", str(preds),
                 "--out", str(tmp_path / "o"), "--weathers", "clear"])
    _assert_refused(code, capsys.readouterr().err, tmp_path / "o", "does not support weather 'clear'")


def test_run_refuses_a_reader(capsys, tmp_path):
    code = main(["run", "--method", "controlnet", "--scenes", "demo", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "output reader" in err and "wcbench evaluate --method controlnet" in err


def test_metric_options_are_checked(capsys, preds, tmp_path):
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o",
                          extra=["--metric-option", "temporal_flicker.colour=1"])
    _assert_refused(code, err, tmp_path / "o",
                    "metric option temporal_flicker.colour=1: metric 'temporal_flicker' takes no option colour")
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", extra=["--metric-option", "ssim.x=1"])
    _assert_refused(code, err, tmp_path / "o", "options given for metrics that are not computed: ssim")
    code, err = _evaluate(capsys, predictions=preds, out=tmp_path / "o", extra=["--metric-option", "oops"])
    _assert_refused(code, err, tmp_path / "o", "expected METRIC.KEY=VALUE")


def test_metric_option_reaches_the_metric(preds, tmp_path):
    out = tmp_path / "o"
    assert main(["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds), "--out", str(out),
                 "--metrics", "flow_warping_error", "--metric-option", "flow_warping_error.flow=farneback"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["config"]["metric_config"]["flow_warping_error"]["config"] == {"flow": "farneback"}
    assert "farneback" in doc["results"]["demo"]["rain"]["flow_warping_error"]["variant"]


def test_an_unknown_method_is_reported_before_a_missing_out(capsys):
    # the method name is checked as it is parsed: a typo is the first thing the user hears of
    with pytest.raises(SystemExit) as exc:
        main(["run", "--method", "contrlnet", "--scenes", "demo"])
    last = capsys.readouterr().err.strip().splitlines()[-1]  # the error line, under the usage
    assert exc.value.code == 2
    assert "unknown method 'contrlnet'" in last and "Did you mean 'controlnet'" in last


def _damage(path, how):
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    else:  # one byte flipped in the middle (inside the compressed data)
        flipped = bytearray(data)
        flipped[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(flipped))


@pytest.mark.parametrize("how", ["truncated", "flipped"])
def test_damaged_png_gives_one_message_and_no_library_chatter(capfd, preds, tmp_path, how):
    """libpng prints its own complaint to the terminal (fd 2) when OpenCV decodes a damaged PNG: the
    file is refused from its chunks first, so the user sees wcbench's one message only."""
    p = preds / "rain" / "005.png"
    _damage(p, how)
    code = main(["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                 "--out", str(tmp_path / "o"), "--metrics", "temporal_flicker"])
    err = capfd.readouterr().err
    _assert_refused(code, err, tmp_path / "o", str(p), "truncated PNG" if how == "truncated" else "CRC error")
    assert "libpng" not in err and "WARN" not in err
    assert err.startswith("wcbench evaluate: error:"), err  # nothing printed before wcbench's message


@pytest.mark.parametrize("how", ["truncated", "garbage"])
def test_damaged_mp4_gives_one_message_and_no_ffmpeg_chatter(capfd, demo_scene, tmp_path, how):
    root = tmp_path / "videos"
    video = root / "rain" / "blend.mp4"
    write_mp4(video, [read_rgb8(f.image_path) for f in demo_scene.frames])
    if how == "truncated":
        _damage(video, how)
    else:
        video.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    code = main(["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(root),
                 "--out", str(tmp_path / "o"), "--metrics", "temporal_flicker", "--pattern", "{weather}/blend.mp4"])
    err = capfd.readouterr().err
    _assert_refused(code, err, tmp_path / "o", str(video), "damaged or truncated video")
    assert "moov" not in err.replace("no moov index", "") and "[mov," not in err
    assert err.startswith("wcbench evaluate: error:"), err  # nothing printed before wcbench's message
