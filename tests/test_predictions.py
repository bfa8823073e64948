"""Matching another tool's files to scene frames, and strict image reading."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scene_fixtures import write_prediction_folder

from wcbench.core.errors import InputError
from wcbench.core.image_io import natural_key, read_rgb8, write_mp4
from wcbench.methods import get_method
from wcbench.predictions import match_predictions


def _rgb(path):
    return read_rgb8(path)


def test_default_pattern_any_padding_and_extension(demo_scene, tmp_path):
    root = tmp_path / "p"
    for f in demo_scene.frames:
        (root / "rain").mkdir(parents=True, exist_ok=True)
        img = cv2.imread(str(f.image_path))
        cv2.imwrite(str(root / "rain" / f"{f.index:05d}.jpg"), img)
    seq = match_predictions(demo_scene, "rain", root)
    assert [p.name for p in seq.files] == [f"{k:05d}.jpg" for k in range(len(demo_scene))]
    assert len(list(seq)) == len(demo_scene)


def test_stem_pattern_maps_source_names(demo_scene, tmp_path):
    root = tmp_path / "p"
    (root / "snow").mkdir(parents=True)
    for f in demo_scene.frames:
        cv2.imwrite(str(root / "snow" / f"{f.image_path.stem}.png"), cv2.imread(str(f.image_path)))
    seq = get_method("controlnet").open_predictions(demo_scene, "snow", root)
    assert [p.stem for p in seq.files] == [f.image_path.stem for f in demo_scene.frames]


def test_wildcard_uses_natural_sort(demo_scene, tmp_path):
    root = tmp_path / "p"
    (root / "fog").mkdir(parents=True)
    for f in demo_scene.frames:
        cv2.imwrite(str(root / "fog" / f"frame{f.index + 1}.png"), cv2.imread(str(f.image_path)))
    seq = match_predictions(demo_scene, "fog", root, pattern="{weather}/*")
    assert [p.name for p in seq.files] == [f"frame{k + 1}.png" for k in range(len(demo_scene))]
    assert sorted(["frame10", "frame2"], key=natural_key) == ["frame2", "frame10"]


def test_frame_start_one(demo_scene, tmp_path):
    root = tmp_path / "p"
    (root / "rain").mkdir(parents=True)
    for f in demo_scene.frames:
        cv2.imwrite(str(root / "rain" / f"{f.index + 1:04d}.png"), cv2.imread(str(f.image_path)))
    seq = match_predictions(demo_scene, "rain", root, frame_start=1)
    assert seq.files[0].name == "0001.png"


def test_video_frames_in_order(demo_scene, tmp_path):
    frames = [_rgb(f.image_path) for f in demo_scene.frames]
    write_mp4(tmp_path / "rain" / "blend.mp4", frames)
    seq = get_method("fresco").open_predictions(demo_scene, "rain", tmp_path)
    decoded = list(seq)
    assert len(decoded) == len(frames)
    # mp4v is lossy: frames come back close, in order
    errs = [np.abs(d.astype(float) - f).mean() for d, f in zip(decoded, frames)]
    assert max(errs) < 8.0
    assert np.abs(decoded[0].astype(float) - frames[-1]).mean() > max(errs)


def test_missing_and_extra_frames_are_all_named(demo_scene, tmp_path):
    root = write_prediction_folder(demo_scene, tmp_path / "p", ["rain"])
    (root / "rain" / "003.png").unlink()
    (root / "rain" / "007.png").unlink()
    cv2.imwrite(str(root / "rain" / "012.png"), cv2.imread(str(demo_scene.frames[0].image_path)))
    cv2.imwrite(str(root / "rain" / "notes.png"), cv2.imread(str(demo_scene.frames[0].image_path)))
    with pytest.raises(InputError) as exc:
        match_predictions(demo_scene, "rain", root)
    msg = str(exc.value)
    assert "missing frames [3, 7]" in msg and "012.png" in msg and "notes.png" in msg


def test_wrong_size_needs_resize(demo_scene, tmp_path):
    root = write_prediction_folder(demo_scene, tmp_path / "p", ["rain"],
                                   transform=lambda img, k, w: cv2.resize(img, (160, 90)))
    seq = match_predictions(demo_scene, "rain", root)
    with pytest.raises(InputError, match=r"000\.png: image is 160x90, expected 320x180.*--resize"):
        next(iter(seq))
    resized = next(iter(match_predictions(demo_scene, "rain", root, resize=True)))
    assert resized.shape == (180, 320, 3)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: np.zeros((8, 8), np.uint8), "grayscale"),
        (lambda: np.zeros((8, 8, 3), np.uint16), "16-bit"),
        (lambda: np.zeros((8, 8, 4), np.uint8), "alpha channel"),
    ],
)
def test_strict_image_reading(tmp_path, make, message):
    path = tmp_path / "x.png"
    cv2.imwrite(str(path), make())
    with pytest.raises(InputError, match=message) as exc:
        read_rgb8(path)
    assert str(path) in str(exc.value)


def test_corrupt_image(tmp_path):
    path = tmp_path / "x.png"
    path.write_bytes(b"\x89PNG not really")
    with pytest.raises(InputError, match="cannot decode"):
        read_rgb8(path)


def _copy_frames(scene, folder, name=lambda f: f"{f.index:03d}.png", frames=None):
    folder.mkdir(parents=True, exist_ok=True)
    for f in frames if frames is not None else scene.frames:
        cv2.imwrite(str(folder / name(f)), cv2.imread(str(f.image_path)))


def test_star_and_step_in_folder_names_are_wildcards(demo_scene, tmp_path):
    _copy_frames(demo_scene, tmp_path / "run_7" / "rain" / "ckpt_30000")
    (tmp_path / "run_7" / "rain" / "ckpt_30000_gt").mkdir()  # not digits only: no match
    (tmp_path / "run_*").mkdir()  # a literal star in a name is not what the pattern means
    seq = match_predictions(demo_scene, "rain", tmp_path, pattern="run_*/{weather}/ckpt_{step}/{frame}.png")
    assert seq.location == tmp_path / "run_7" / "rain" / "ckpt_30000" and len(seq) == 12
    _copy_frames(demo_scene, tmp_path / "run_8" / "rain" / "ckpt_100")
    with pytest.raises(InputError, match="matches 2 places") as exc:
        match_predictions(demo_scene, "rain", tmp_path, pattern="run_*/{weather}/ckpt_{step}/{frame}.png")
    assert "run_7" in str(exc.value) and "run_8" in str(exc.value)
    with pytest.raises(InputError, match=r"\{frame\} may only appear in the file name"):
        match_predictions(demo_scene, "rain", tmp_path, pattern="{weather}/{frame}/x.png")


def test_short_sequences_need_a_declaration_and_one_contiguous_run(demo_scene, tmp_path):
    _copy_frames(demo_scene, tmp_path / "rain", frames=demo_scene.frames[:9])
    with pytest.raises(InputError, match=r"missing frames \[9, 10, 11\]"):
        match_predictions(demo_scene, "rain", tmp_path)
    seq = match_predictions(demo_scene, "rain", tmp_path, partial_reason="the tool stops early")
    assert seq.frame_indices == list(range(9)) and seq.missing == [9, 10, 11]
    assert len(list(seq)) == 9
    (tmp_path / "rain" / "004.png").unlink()
    with pytest.raises(InputError, match=r"missing frames \[4\] inside the sequence"):
        match_predictions(demo_scene, "rain", tmp_path, partial_reason="the tool stops early")


def test_ignore_rules_and_weather_names(demo_scene, tmp_path):
    _copy_frames(demo_scene, tmp_path / "smog", name=lambda f: f"{f.index}-rgb.png")
    _copy_frames(demo_scene, tmp_path / "smog", name=lambda f: f"{f.index}-depth.png")
    seq = match_predictions(demo_scene, "fog", tmp_path, pattern="{weather}/{frame}-rgb.png",
                            weather_names={"fog": ["smog"]}, ignore=["*-depth.png"])
    assert len(seq) == 12 and len(seq.ignored) == 12 and seq.location == tmp_path / "smog"


def test_weather_level_may_be_left_out_for_one_weather(demo_scene, tmp_path):
    _copy_frames(demo_scene, tmp_path / "snow")
    with pytest.raises(InputError, match="folder not found for weather 'rain'"):
        match_predictions(demo_scene, "rain", tmp_path, weather_level_optional=True)
    _copy_frames(demo_scene, tmp_path)
    with pytest.raises(InputError, match="folder not found for weather 'rain'"):
        match_predictions(demo_scene, "rain", tmp_path)
    seq = match_predictions(demo_scene, "rain", tmp_path, weather_level_optional=True)
    assert seq.location == tmp_path and seq.layout == "{frame}"


def test_a_frame_selection_reads_only_those_frames(demo_scene, tmp_path):
    root = write_prediction_folder(demo_scene, tmp_path / "p", ["rain"])
    seq = match_predictions(demo_scene, "rain", root, frames=[2, 3, 4, 5])
    assert seq.frame_indices == [2, 3, 4, 5] and [p.name for p in seq.files] == ["002.png", "003.png", "004.png",
                                                                                  "005.png"]
    for k in (0, 1, 8, 11):  # the other frames' files may be absent
        (root / "rain" / f"{k:03d}.png").unlink()
    assert len(list(match_predictions(demo_scene, "rain", root, frames=range(2, 6)))) == 4
    (root / "rain" / "003.png").unlink()
    with pytest.raises(InputError, match=r"missing frames \[3\]"):
        match_predictions(demo_scene, "rain", root, frames=[2, 3, 4, 5])
    with pytest.raises(InputError, match="one contiguous run of frames"):
        match_predictions(demo_scene, "rain", root, frames=[2, 4, 5])
    with pytest.raises(InputError, match=r"frame 12 is beyond the 12 frames \(0-11\) of scene 'demo'"):
        match_predictions(demo_scene, "rain", root, frames=[10, 11, 12])


def test_a_frame_selection_of_a_video(demo_scene, tmp_path):
    frames = [_rgb(f.image_path) for f in demo_scene.frames]
    write_mp4(tmp_path / "rain" / "blend.mp4", frames)
    seq = get_method("fresco").open_predictions(demo_scene, "rain", tmp_path, frames=[3, 4, 5])
    decoded = list(seq)
    assert seq.frame_indices == [3, 4, 5] and len(decoded) == 3
    for d, k in zip(decoded, (3, 4, 5)):  # the selected frames, not the first three
        errs = [np.abs(d.astype(float) - f).mean() for f in frames]
        assert int(np.argmin(errs)) == k


def test_frames_beyond_the_scene_are_left_out_only_under_a_frame_selection(demo_scene, tmp_path):
    """A render of a longer sequence (16 numbered frames for a 12-frame scene): refused, naming
    --frames and --frame-offset; under --frames the scene's frames are read and the others counted."""
    root = write_prediction_folder(demo_scene, tmp_path / "p", ["rain"])
    for k in range(12, 16):
        cv2.imwrite(str(root / "rain" / f"{k:03d}.png"), cv2.imread(str(demo_scene.frames[-1].image_path)))
    with pytest.raises(InputError, match=r"extra files \['012.png', '013.png', '014.png', '015.png'\]: frames "
                                         r"12-15 beyond the scene's frames 0-11") as exc:
        match_predictions(demo_scene, "rain", root)
    assert "--frames 0-11" in str(exc.value) and "--frame-offset N" in str(exc.value)
    seq = match_predictions(demo_scene, "rain", root, frames=range(12))
    assert seq.frame_indices == list(range(12)) and seq.outside_scene == [12, 13, 14, 15]
    assert seq.left_out() == {"outside_scene": {"count": 4, "frames": "12-15"}}
    # shifted by --frame-offset -2 (the tool started two frames before the scene): both ends; scene
    # frames outside the selection are not counted, only frames outside the scene
    seq = match_predictions(demo_scene, "rain", root, frame_offset=-2, frames=range(10))
    assert seq.files[0].name == "002.png" and seq.left_out() == {"outside_scene": {"count": 4,
                                                                                   "frames": "-2 to -1,12-13"}}
    assert match_predictions(demo_scene, "rain", root, frames=range(3, 6)).outside_scene == [12, 13, 14, 15]
    # a sequence of the scene's length records nothing left out
    for k in range(12, 16):
        (root / "rain" / f"{k:03d}.png").unlink()
    assert match_predictions(demo_scene, "rain", root).left_out() == {}


def test_a_video_longer_than_the_scene_under_a_frame_selection(demo_scene, tmp_path):
    frames = [_rgb(f.image_path) for f in demo_scene.frames]
    write_mp4(tmp_path / "rain.mp4", [*frames, *frames[:3]])
    with pytest.raises(InputError, match="video frames 12-14 fall outside the scene: pass --frames 0-11"):
        match_predictions(demo_scene, "rain", tmp_path, pattern="{weather}.mp4")
    seq = match_predictions(demo_scene, "rain", tmp_path, pattern="{weather}.mp4", frames=range(12))
    assert seq.n_frames == 12 and len(list(seq)) == 12
    assert seq.left_out() == {"outside_scene": {"count": 3, "frames": "12-14"}}


def test_the_highest_step_is_read(demo_scene, tmp_path):
    """{step} folders side by side are a run's evaluations at several steps: the highest (by number)
    is read and the others named; under a * level that differs, the places stay ambiguous."""
    for step in (900, 1000, 20):
        _copy_frames(demo_scene, tmp_path / "run" / "rain" / f"ckpt_{step}")
    seq = match_predictions(demo_scene, "rain", tmp_path, pattern="run/{weather}/ckpt_{step}/{frame}.png")
    assert seq.location.name == "ckpt_1000"
    assert seq.passed_over == ["run/rain/ckpt_20", "run/rain/ckpt_900"]
    frames = [_rgb(f.image_path) for f in demo_scene.frames]
    write_mp4(tmp_path / "vid" / "rain_7.mp4", frames)
    write_mp4(tmp_path / "vid" / "rain_12.mp4", frames[:5])
    seq = match_predictions(demo_scene, "rain", tmp_path / "vid", pattern="{weather}_{step}.mp4",
                            partial_reason="test")
    assert seq.location.name == "rain_12.mp4" and seq.passed_over == ["rain_7.mp4"]
