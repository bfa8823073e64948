"""Prediction files on disk: the canonical layout, pattern matching for other tools, reading.

Patterns are paths relative to a scene's prediction folder with these tokens:

``{weather}``  the weather name (``rain``...);
``{frame}``    the frame number, an integer with any zero padding (``7``, ``007``, ``0007``);
               a preset's ``frame_start`` says what number the first frame has (default 0);
``{stem}``     the source image's file stem (``000_0`` for ``images/000_0.jpg``);
``*``          any text: files are then matched to frames in natural sort order.

The last component may name an extension (``{weather}/{frame}.png``); without one, any image
extension matches. A pattern whose last component is a video (``{weather}.mp4``) yields the
video's frames in order.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    iter_video_rgb8,
    natural_key,
    read_rgb8,
    resize_rgb8,
)
from wcbench.core.storage import sha256_file
from wcbench.scenes.scene import Scene

DEFAULT_PATTERN = "{weather}/{frame}"
CANONICAL_PATTERN = "{weather}/{frame:03d}.png"
INFO_FILE = "info.json"


class PredictionsMissingError(InputError):
    """No predictions at all for a (scene, weather): the weather folder or video does not exist."""


_TOKEN = re.compile(r"\{(weather|frame|stem|scene)(:[^}]*)?\}")


@dataclass
class PredictionSequence:
    """A method's frames for one (scene, weather), read lazily and checked.

    Attributes
    ----------
    files : list of Path
        One image per frame, or a single video for all frames.
    size : (int, int)
        Expected (width, height): the scene's frame size.
    resize : bool
        Resize frames of another size instead of failing.
    info : dict or None
        The method's ``info.json`` if one was found.
    """

    files: list[Path]
    size: tuple[int, int]
    n_frames: int
    resize: bool = False
    info: dict[str, Any] | None = None
    is_video: bool = False
    _hashes: list[str] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return self.n_frames

    def _fit(self, img: np.ndarray, where: str) -> np.ndarray:
        h, w = img.shape[:2]
        if (w, h) == self.size:
            return img
        if self.resize:
            return resize_rgb8(img, self.size)
        raise InputError(
            f"{where}: image is {w}x{h}, expected {self.size[0]}x{self.size[1]} like the scene's frames "
            "(pass --resize to resize predictions to the scene's size)"
        )

    def __iter__(self) -> Iterator[np.ndarray]:
        """uint8 RGB frames [H, W, 3] in order."""
        if self.is_video:
            count = 0
            for img in iter_video_rgb8(self.files[0]):
                count += 1
                if count > self.n_frames:
                    break
                yield self._fit(img, f"{self.files[0]} frame {count - 1}")
            if count != self.n_frames:
                raise InputError(
                    f"{self.files[0]}: video has {count} frames, expected {self.n_frames} (one per scene frame)"
                )
        else:
            for p in self.files:
                yield self._fit(read_rgb8(p), str(p))

    def sha256s(self) -> list[str]:
        """sha256 of every input file (one for a video)."""
        if self._hashes is None:
            self._hashes = [sha256_file(p) for p in self.files]
        return self._hashes


def _compile(last: str, *, weather: str, scene: Scene) -> tuple[re.Pattern[str], bool, bool]:
    """Regex for the file-name component; returns (regex, uses_frame, uses_stem)."""
    parts, pos, uses_frame, uses_stem = [], 0, False, False
    for m in _TOKEN.finditer(last):
        parts.append(re.escape(last[pos : m.start()]).replace(r"\*", ".*"))
        tok = m.group(1)
        if tok == "frame":
            parts.append(r"(?P<frame>\d+)")
            uses_frame = True
        elif tok == "stem":
            parts.append(r"(?P<stem>.+)")
            uses_stem = True
        elif tok == "weather":
            parts.append(re.escape(weather))
        else:
            parts.append(re.escape(scene.id))
        pos = m.end()
    parts.append(re.escape(last[pos:]).replace(r"\*", ".*"))
    body = "".join(parts)
    has_ext = Path(_TOKEN.sub("x", last)).suffix.lower() in (*IMAGE_EXTENSIONS, *VIDEO_EXTENSIONS)
    if not has_ext:
        exts = "|".join(re.escape(e) for e in IMAGE_EXTENSIONS)
        body += rf"(?i:{exts})"
    return re.compile(rf"^{body}$"), uses_frame, uses_stem


def _substitute_dirs(part: str, *, weather: str, scene: Scene, pattern: str) -> str:
    def sub(m: re.Match[str]) -> str:
        if m.group(1) == "weather":
            return weather
        if m.group(1) == "scene":
            return scene.id
        raise InputError(f"pattern {pattern!r}: {{{m.group(1)}}} may only appear in the file name")

    return _TOKEN.sub(sub, part)


def match_predictions(
    scene: Scene,
    weather: str,
    root: Path,
    *,
    pattern: str = DEFAULT_PATTERN,
    frame_start: int = 0,
    resize: bool = False,
) -> PredictionSequence:
    """Find one prediction per scene frame under ``root`` following ``pattern``.

    Parameters
    ----------
    scene : Scene
    weather : str
    root : Path
        The scene's prediction folder.
    pattern : str
        See the module docstring.
    frame_start : int
        The number ``{frame}`` has for the scene's first frame.
    resize : bool
        Allow predictions of another size (resized on read).

    Raises
    ------
    InputError
        If files are missing or extra (every one named), the folder is empty, or a video is
        unreadable.
    """
    pieces = pattern.split("/")
    folder = root.joinpath(*[_substitute_dirs(p, weather=weather, scene=scene, pattern=pattern) for p in pieces[:-1]])
    last = pieces[-1]
    n = len(scene.frames)
    size = scene.image_size
    where = f"{folder} (pattern {pattern!r}, weather {weather!r})"
    literal_last = _TOKEN.sub(lambda m: weather if m.group(1) == "weather" else scene.id, last)
    if not _TOKEN.search(literal_last) and Path(literal_last).suffix.lower() in VIDEO_EXTENSIONS:
        video = folder / literal_last
        if not video.is_file():
            raise PredictionsMissingError(f"{video}: missing video for weather {weather!r} (pattern {pattern!r})")
        return PredictionSequence([video], size, n, resize, read_info(video.parent), is_video=True)
    if not folder.is_dir():
        raise PredictionsMissingError(f"{where}: folder not found; expected {n} frames for scene {scene.id!r}")
    regex, uses_frame, uses_stem = _compile(last, weather=weather, scene=scene)
    candidates = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
        key=lambda p: natural_key(p.name),
    )
    if not candidates:
        raise InputError(f"{where}: no image files; expected {n} frames for scene {scene.id!r}")
    matched = [(p, m) for p in candidates if (m := regex.match(p.name))]
    unmatched = [p.name for p in candidates if not regex.match(p.name)]
    if uses_frame or uses_stem:
        by_frame: dict[int, list[Path]] = {}
        stems = {f.image_path.stem: f.index for f in scene.frames}
        extra = list(unmatched)
        for p, m in matched:
            if uses_frame:
                k = int(m.group("frame")) - frame_start
            else:
                k = stems.get(m.group("stem"), -1)
            if 0 <= k < n:
                by_frame.setdefault(k, []).append(p)
            else:
                extra.append(p.name)
        missing = [k for k in range(n) if k not in by_frame]
        dupes = {k: [p.name for p in v] for k, v in by_frame.items() if len(v) > 1}
        problems = []
        if missing:
            expect = (
                [f"{k + frame_start}" for k in missing] if uses_frame
                else [scene.frames[k].image_path.stem for k in missing]
            )
            kind = "numbers" if uses_frame else "stems"
            problems.append(f"missing frames {missing} (expected names for {kind} {expect})")
        if extra:
            problems.append(f"extra files {extra}")
        if dupes:
            problems.append(f"several files for one frame {dupes}")
        if problems:
            raise InputError(f"{where}: " + "; ".join(problems) + f"; the scene has {n} frames")
        files = [by_frame[k][0] for k in range(n)]
    else:
        files = [p for p, _ in matched]
        if len(files) != n or unmatched:
            detail = f"extra files {[p.name for p in files[n:]] + unmatched}" if len(files) >= n else (
                f"{n - len(files)} frames missing after {files[-1].name if files else 'the start'}"
            )
            raise InputError(f"{where}: found {len(files)} frames for {n} scene frames: {detail}")
    info = read_info(folder)
    return PredictionSequence(files, size, n, resize, info)


def read_info(folder: Path) -> dict[str, Any] | None:
    """The nearest ``info.json`` in ``folder`` or its two parents (weather, scene, method level)."""
    for d in (folder, folder.parent, folder.parent.parent):
        path = d / INFO_FILE
        if path.is_file():
            try:
                info = json.loads(path.read_text(encoding="utf-8"))
            except json.JSONDecodeError as exc:
                raise InputError(f"{path}: not valid JSON ({exc})") from None
            if not isinstance(info, dict):
                raise InputError(f"{path}: expected a JSON object")
            return info
    return None


def scene_prediction_root(root: Path, scene_id: str, *, n_scenes: int) -> Path:
    """The folder holding one scene's predictions: ``root/<scene>`` if present, else ``root``
    itself when a single scene is evaluated.

    Raises
    ------
    InputError
        If neither exists.
    """
    if not root.is_dir():
        raise InputError(f"{root}: predictions folder not found")
    if (root / scene_id).is_dir():
        return root / scene_id
    if n_scenes == 1:
        if not any(root.iterdir()):
            raise InputError(f"{root}: predictions folder is empty")
        return root
    raise InputError(
        f"{root}: no folder {scene_id!r}; expected one sub-folder per scene ({root}/<scene>/<weather>/...)"
    )


def canonical_frame_path(out_dir: Path, index: int) -> Path:
    """Where frame ``index`` lives in a weather folder of the canonical layout."""
    return out_dir / f"{index:03d}.png"
