"""The hostile-file suite: damaged images, videos, JSON and scene files, and bad CLI values.

Every case must end with exit status 2 and one ``error:`` message naming what was wrong (no
traceback), and must leave the output folder as it was (design §9). The damaged files are made
here (tests/support/hostile_files.py); the count of cases is printed at the end of the run.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from hostile_files import encoded, jpeg_declaring, png_declaring, real_png_bomb, truncated, write

from wcbench.cli import main
from wcbench.core.image_io import write_mp4
from wcbench.scenes.sets import resolve_scenes

Mutation = Callable[[Path], None]
WEATHERS = ("clear", "rain")


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``scene/`` (a copy of the demo scene), ``preds/<weather>/NNN.png`` and ``video/<weather>.mp4``."""
    root = tmp_path_factory.mktemp("hostile-base")
    shutil.copytree(resolve_scenes("demo")[0].path, root / "scene")
    frames = sorted((root / "scene" / "images").glob("*_0.png"))
    for w in WEATHERS:
        imgs = []
        for k, f in enumerate(frames):
            img = cv2.imread(str(f))
            img = img if w == "clear" else (img * 0.8).astype(np.uint8)
            write(root / "preds" / w / f"{k:03d}.png", encoded(img))
            imgs.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
        write_mp4(root / "video" / f"{w}.mp4", imgs, fps=10.0)
    return root


def _evaluate(root: Path, *extra: str, preds: str = "preds") -> list[str]:
    return ["evaluate", "--method", "folder", "--scenes", str(root / "scene"), "--predictions", str(root / preds),
            "--out", str(root / "out"), "--weathers", *WEATHERS, "--metrics", "temporal_flicker", "fps",
            "--no-progress", *extra]


def _video(root: Path, *extra: str) -> list[str]:
    return _evaluate(root, "--pattern", "{weather}.mp4", *extra, preds="video")


def _render(root: Path, *extra: str) -> list[str]:
    return ["render", "--method", "lidar-init", "--scenes", str(root / "scene"), "--out", str(root / "out"),
            "--weathers", "rain", "--frames", "0-1", "--no-progress", "--no-video", *extra]


def _pred(name: str = "003.png", weather: str = "rain") -> Callable[[Path], Path]:
    return lambda root: root / "preds" / weather / name


def _put(where: Callable[[Path], Path], data: Callable[[Path], bytes | str]) -> Mutation:
    def mutate(root: Path) -> None:
        target = where(root)
        payload = data(target) if callable(data) else data
        target.unlink(missing_ok=True)
        write(target, payload)
    return mutate


def _const(value: bytes | str) -> Callable[[Path], bytes | str]:
    return lambda _path: value


def _scene(rel: str) -> Callable[[Path], Path]:
    return lambda root: root / "scene" / rel


def _json(obj: object) -> Callable[[Path], str]:
    return _const(json.dumps(obj))


def _matrix(m: np.ndarray) -> Callable[[Path], str]:
    return _const(" ".join(repr(float(v)) for v in np.asarray(m, float).ravel()))


def _pose(rotation: np.ndarray, translation: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Callable[[Path], str]:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, translation
    return _matrix(m)


_IMAGE_CASES: dict[str, Callable[[Path], bytes | str]] = {
    "empty file": _const(b""),
    "10 bytes of a png": lambda p: truncated(p, 10),
    "100 bytes of a png": lambda p: truncated(p, 100),
    "half a png": lambda p: truncated(p, 0.5),
    "random bytes": _const(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes()),
    "text": _const("not an image"),
    "png header 100000x100000": _const(png_declaring(100_000, 100_000)),
    # a complete, decodable 20000x20000 image (1.2 GB of pixels in 1.1 MB): refused from its header
    "real 20000x20000 png": lambda _path: _bomb(),
    "png header 0x0": _const(png_declaring(0, 0)),
    "png header 2^31x1": _const(png_declaring(2**31 - 1, 1)),
    "jpeg header 65000x65000": _const(jpeg_declaring(65_000, 65_000)),
    "grayscale": _const(encoded(np.zeros((180, 320), np.uint8))),
    "16-bit": _const(encoded(np.zeros((180, 320, 3), np.uint16))),
    "rgba": _const(encoded(np.zeros((180, 320, 4), np.uint8))),
    "wrong size": _const(encoded(np.zeros((90, 160, 3), np.uint8))),
    "1x1 image": _const(encoded(np.zeros((1, 1, 3), np.uint8))),
}

#: name -> (damage, command, text the one error message must contain)
CASES: dict[str, tuple[Mutation, Callable[[Path], list[str]], str]] = {}
_BOMB: list[bytes] = []


def _bomb() -> bytes:
    if not _BOMB:
        _BOMB.append(real_png_bomb(20_000))
    return _BOMB[0]


for _name, _data in _IMAGE_CASES.items():
    CASES[f"prediction png: {_name}"] = (_put(_pred(), _data), _evaluate, "003.png")
    CASES[f"source image: {_name}"] = (_put(_scene("images/003_0.png"), _data), _evaluate, "003_0.png")
    CASES[f"render source image: {_name}"] = (_put(_scene("images/003_0.png"), _data), _render, "003_0.png")


def _dir_instead(root: Path) -> None:
    p = _pred()(root)
    p.unlink()
    p.mkdir()


def _symlink_out(root: Path) -> None:
    outside = root / "elsewhere.png"
    shutil.copy(_pred()(root), outside)
    _pred()(root).unlink()
    _pred()(root).symlink_to(outside)


CASES["prediction png: a folder"] = (_dir_instead, _evaluate, "missing frames [3]")
CASES["prediction png: symlink out of the predictions folder"] = (_symlink_out, _evaluate, "003.png")

_VIDEO = lambda root: root / "video" / "rain.mp4"  # noqa: E731
for _name, _data in {
    "empty": _const(b""), "100 bytes": lambda p: truncated(p, 100), "half": lambda p: truncated(p, 0.5),
    "random bytes": _const(np.random.default_rng(1).integers(0, 256, 20000, dtype=np.uint8).tobytes()),
    "a png": _const(encoded(np.zeros((180, 320, 3), np.uint8))),
}.items():
    CASES[f"prediction mp4: {_name}"] = (_put(_VIDEO, _data), _video, "rain.mp4")

_INFO = _pred("info.json")
for _name, _text in {
    "string fps": json.dumps({"fps": "fast"}), "negative fps": json.dumps({"fps": -5}),
    "zero fps": json.dumps({"fps": 0}), "NaN fps": '{"fps": NaN}', "Infinity fps": '{"fps": Infinity}',
    "huge fps": '{"fps": 1e400}', "bool fps": json.dumps({"fps": True}),
    "list timings": json.dumps({"timings": [1, 2]}),
    "string timings": json.dumps({"timings": "fast"}), "string timings fps": json.dumps({"timings": {"fps": "x"}}),
    "negative timings fps": json.dumps({"timings": {"fps": -1.0}}), "top-level list": json.dumps([1, 2]),
    "top-level string": json.dumps("info"), "truncated": '{"fps": 1', "empty": "",
}.items():
    CASES[f"info.json: {_name}"] = (_put(_INFO, _const(_text)), _evaluate, "info.json")
CASES["info.json: non-UTF-8 bytes"] = (_put(_INFO, _const(b'{"fps": "\xff\xfe"}')), _evaluate, "info.json")

for _name, _text in {
    "NaN timestamp": "[0.0, 0.1, NaN, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1]",
    "string timestamps": json.dumps(["a"] * 12), "object without frames": json.dumps({"x": 1}),
    "too few": json.dumps([0.0, 0.1]), "nested lists": json.dumps([[0.0]] * 12), "number": "3",
    "null": "null", "decreasing": json.dumps([1.2 - 0.1 * k for k in range(12)]),
    "infinite": json.dumps([0.1 * k for k in range(11)] + [1e400]).replace("Infinity", "1e400"),
}.items():
    CASES[f"timestamps.json: {_name}"] = (_put(_scene("timestamps.json"), _const(_text)), _evaluate, "timestamps.json")
CASES["timestamps.json: non-UTF-8"] = (_put(_scene("timestamps.json"), _const(b"[\xff]")), _evaluate, "timestamps.json")

for _name, _text in {"list": "[1, 2]", "string ids": json.dumps({"car": "x"}), "nested": json.dumps({"1": {"a": 1}}),
                     "not JSON": "{"}.items():
    CASES[f"classes.json: {_name}"] = (_put(_scene("classes.json"), _const(_text)), _evaluate, "classes.json")

_K = "intrinsics/0.txt"
for _name, _text in {
    "fx 1e-300": "1e-300 1000 160 90 0 0 0 0 0", "fx 1e300": "1e300 1000 160 90 0 0 0 0 0",
    "fx NaN": "nan 1000 160 90 0 0 0 0 0", "negative fy": "1000 -1000 160 90 0 0 0 0 0",
    "cx inf": "1000 1000 inf 90 0 0 0 0 0", "words": "fx fy cx cy", "too few": "1000 1000 160",
    "empty": "", "huge distortion": "1000 1000 160 90 1e300 0 0 0 0",
}.items():
    CASES[f"intrinsics: {_name}"] = (_put(_scene(_K), _const(_text)), _evaluate, "0.txt")

_E = "extrinsics/003_0.txt"
for _name, _data in {
    "zero rotation": _pose(np.zeros((3, 3))), "scaled rotation": _pose(2 * np.eye(3)),
    "reflection": _pose(np.diag([1.0, 1.0, -1.0])), "NaN": _matrix(np.full((4, 4), np.nan)),
    "huge translation": _pose(np.eye(3), (1e300, 0.0, 0.0)), "bad last row": _matrix(np.ones((4, 4))),
    "12 numbers": _matrix(np.eye(4)[:3]),
}.items():
    CASES[f"camera pose: {_name}"] = (_put(_scene(_E), _data), _evaluate, "003_0.txt")

CASES["lidar: truncated"] = (_put(_scene("lidar/003.bin"), lambda p: truncated(p, 10)), _render, "003.bin")
CASES["lidar: NaN points"] = (_put(_scene("lidar/003.bin"), _const(np.full((100, 4), np.nan, np.float32).tobytes())),
                              _render, "003.bin")
CASES["lidar: points at 1e30 m"] = (
    _put(_scene("lidar/003.bin"), _const(np.full((100, 4), 1e30, np.float32).tobytes())), _render, "003.bin")
CASES["lidar pose: zero rotation"] = (_put(_scene("lidar_pose/003.txt"), _pose(np.zeros((3, 3)))), _render, "003.txt")
CASES["lidar semseg: wrong length"] = (_put(_scene("lidar_semseg/003.bin"), _const(b"\x01\x02")), _render, "003.bin")

_TRACKS = _scene("instances/instances_info.json")
_GOOD_ANN = {"frame_idx": [0, 1], "obj_to_world": [np.eye(4).tolist()] * 2, "box_size": [[4.0, 2.0, 1.5]] * 2}
for _name, _obj in {
    "list": [1, 2], "instance is a list": {"0": [1]}, "annotations missing": {"0": {"id": "a"}},
    "lengths differ": {"0": {"frame_annotations": {**_GOOD_ANN, "frame_idx": [0]}}},
    "NaN pose": {"0": {"frame_annotations": {**_GOOD_ANN, "obj_to_world": [[[float("nan")] * 4] * 4] * 2}}},
    "string sizes": {"0": {"frame_annotations": {**_GOOD_ANN, "box_size": "big"}}},
    "negative size": {"0": {"frame_annotations": {**_GOOD_ANN, "box_size": [[-4.0, 2.0, 1.5]] * 2}}},
    "frame index string": {"0": {"frame_annotations": {**_GOOD_ANN, "frame_idx": ["a", "b"]}}},
}.items():
    CASES[f"instances_info.json: {_name}"] = (_put(_TRACKS, _json(_obj)), _evaluate, "instances_info.json")

for _name, _extra in {
    "--fps -1": ("--fps", "-1"), "--fps nan": ("--fps", "nan"), "--fps inf": ("--fps", "inf"),
    "--fps 0": ("--fps", "0"), "--frame-offset -5": ("--frame-offset", "-5"),
    "--pattern leaving the folder": ("--pattern", "../../scene/images/{frame}_0.png"),
    "--pattern absolute": ("--pattern", "/etc/{frame}.png"),
}.items():
    CASES[f"option: {_name}"] = (lambda root: None, lambda root, e=_extra: _evaluate(root, *e), _extra[0])


def _out_is_a_file(root: Path) -> None:
    write(root / "out", "a file")


CASES["--out is a file"] = (_out_is_a_file, _evaluate, "out")
for _name, _obj in {"list": [1], "no kind": {"results": {}}, "kind only": {"kind": "wcbench-results"},
                    "schema string": {"kind": "wcbench-results", "schema_version": "x"}}.items():
    CASES[f"results.json: {_name}"] = (_put(lambda root: root / "out" / "results.json", _json(_obj)), _evaluate,
                                       "results.json")


def _snapshot(out: Path) -> dict[str, bytes]:
    if out.is_file():
        return {"": out.read_bytes()}
    if not out.is_dir():
        return {}
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_input_exits_2_with_one_message_and_writes_nothing(name, base, tmp_path, capsys, case_counter):
    mutate, argv, expect = CASES[name]
    if argv is _render:
        pytest.importorskip("torch")  # lidar-init renders with the reference model (the [model] extra)
    root = tmp_path / "case"
    shutil.copytree(base, root, symlinks=True)
    mutate(root)
    before = _snapshot(root / "out")
    capsys.readouterr()
    try:
        code = main(argv(root))
    except SystemExit as exc:  # argparse refuses a bad option value itself (usage + one error line)
        code = exc.code
    err = capsys.readouterr().err
    case_counter["hostile files: cases exiting 2 with one message"] += 1
    assert code == 2, f"exit {code}: {err}"
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert expect in err, f"the message does not name {expect!r}: {err}"
    assert _snapshot(root / "out") == before, "the output folder changed"
