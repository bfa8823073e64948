"""Prediction files on disk: the canonical layout, pattern matching for other tools, reading.

Patterns are paths relative to a scene's prediction folder with these tokens:

``{weather}``  the weather name (``rain``...), or the tool's own name for it when the reader
               declares one (``smog`` for ``fog``, ``raw`` for ``clear``);
``{frame}``    the frame number, an integer with any zero padding (``7``, ``007``, ``0007``);
               a preset's ``frame_start`` says what number the first frame has (default 0);
``{stem}``     the source image's file stem (``000_0`` for ``images/000_0.jpg``);
``{scene}``    the scene id;
``{step}``     any run of digits, e.g. a training step: ``full_set_{step}_rgbs`` matches
               ``full_set_30000_rgbs`` but not ``full_set_30000_gt_rgbs``. When several steps sit
               side by side, the highest is read (a run's last evaluation) and the others are
               named in :attr:`PredictionSequence.passed_over`;
``*``          any text. In the file name, files are then matched to frames in natural sort order.

Folder components may hold ``{weather}``, ``{scene}``, ``{step}`` and ``*``; a wildcard that
matches several folders is an error naming them all. The last component may name an extension
(``{weather}/{frame}.png``); without one, any image extension matches. A last component that is a
video (``{weather}.mp4``) yields the video's frames in order.

Frame *i* of a tool (file number minus ``frame_start``, position in natural order, or video frame)
is scene frame ``i + frame_offset``. A sequence that does not cover the scene is an error listing
the missing frames, unless the reader declares that its tool can end early (``partial_reason``):
then the present frames must be one contiguous run, which is scored, and the missing frames are
named in the results (never silently). Frames a tool wrote beyond the scene (a render of the whole
sequence where the scene is its first 30 frames) are an error naming ``--frames``: with a frame
selection they are left out and counted (:attr:`PredictionSequence.outside_scene`).
"""

from __future__ import annotations

import fnmatch
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.frame_ranges import frames_outside
from wcbench.core.image_io import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    iter_video_rgb8,
    natural_key,
    read_rgb8,
    resize_rgb8,
    video_frame_count,
)
from wcbench.core.storage import sha256_file
from wcbench.core.validation import expect_dict, expect_list, finite_number, read_json
from wcbench.results import frames_text
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import SceneRef

DEFAULT_PATTERN = "{weather}/{frame}"
CANONICAL_PATTERN = "{weather}/{frame:03d}.png"
INFO_FILE = "info.json"
#: How predictions of another size are brought to the scene's size (see :func:`resize_rgb8`);
#: recorded in results.json and part of every cache key.
RESIZE_INTERPOLATION = "OpenCV INTER_AREA to shrink, INTER_CUBIC to enlarge, on uint8 frames"


class PredictionsMissingError(InputError):
    """No predictions at all for a (scene, weather): the weather folder or video does not exist."""


_TOKEN = re.compile(r"\{(weather|frame|stem|scene|step)(:[^}]*)?\}")


@dataclass
class PredictionSequence:
    """A method's frames for one (scene, weather), read lazily and checked.

    Attributes
    ----------
    files : list of Path
        One image per scored frame, or a single video for all of them.
    size : (int, int)
        Expected (width, height): the scene's frame size.
    frame_indices : list of int
        The scene frame of each prediction, increasing and contiguous (all frames unless partial).
    resize : bool
        Resize frames of another size (with :data:`RESIZE_INTERPOLATION`) instead of failing.
    info : dict or None
        The method's ``info.json`` if one was found.
    is_video : bool
        ``files`` is one video whose frames are the predictions, in order.
    missing : list of int
        Scene frames the tool did not produce (only when ``partial_reason`` allows it).
    partial_reason : str or None
        Why the tool may produce fewer frames than the scene (from the reader).
    layout : str
        The pattern that matched.
    location : Path or None
        The folder (or video) the frames were read from.
    ignored : list of str
        Sibling files left out by a reader's ignore rule (depth maps...).
    native_sizes : set of (int, int)
        (width, height) of every frame seen so far that had to be resized.
    video_positions : list of int or None
        For a video scored on some of its frames (``--frames``): the position in the video of
        each prediction; ``None``: every frame of the video, in order.
    outside_scene : list of int
        Frames the tool wrote beyond the scene's frames, left out under a frame selection
        (``--frames``), numbered like scene frames (tool frame *i* is ``i + frame_offset``:
        30-79 for a 80-frame render of a 30-frame scene).
    passed_over : list of str
        Folders of lower steps beside the ``{step}`` folder read (relative to the predictions
        folder), e.g. ``videos_eval/raw/full_set_20000_rgbs`` when ``full_set_30000_rgbs`` is read.
    """

    files: list[Path]
    size: tuple[int, int]
    frame_indices: list[int]
    resize: bool = False
    info: dict[str, Any] | None = None
    is_video: bool = False
    missing: list[int] = field(default_factory=list)
    partial_reason: str | None = None
    layout: str = ""
    location: Path | None = None
    ignored: list[str] = field(default_factory=list)
    native_sizes: set[tuple[int, int]] = field(default_factory=set)

    def __post_init__(self) -> None:
        # a file the user cannot read fails here, before any unit is scored, naming every such file
        unreadable = [p for p in self.files if not os.access(p, os.R_OK)]
        if unreadable:
            listing = "\n".join(f"  {p}" for p in unreadable[:10])
            more = f"\n  ... and {len(unreadable) - 10} more" if len(unreadable) > 10 else ""
            raise InputError(f"{len(unreadable)} prediction file(s) cannot be read by this user "
                             f"(permission denied):\n{listing}{more}")
    video_positions: list[int] | None = None
    outside_scene: list[int] = field(default_factory=list)
    passed_over: list[str] = field(default_factory=list)
    _hashes: list[str] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.frame_indices)

    @property
    def n_frames(self) -> int:
        """Number of predictions (scene frames scored)."""
        return len(self.frame_indices)

    def _fit(self, img: np.ndarray, where: str) -> np.ndarray:
        h, w = img.shape[:2]
        if (w, h) == self.size:
            return img
        if self.resize:
            self.native_sizes.add((w, h))
            return resize_rgb8(img, self.size)
        raise InputError(
            f"{where}: image is {w}x{h}, expected {self.size[0]}x{self.size[1]} like the scene's frames "
            "(pass --resize to resize predictions to the scene's size)"
        )

    def __iter__(self) -> Iterator[np.ndarray]:
        """uint8 RGB frames [H, W, 3] in order, at the scene's size."""
        if self.is_video:
            wanted = list(range(self.n_frames)) if self.video_positions is None else self.video_positions
            keep, last = set(wanted), (wanted[-1] if wanted else -1)
            count = 0
            for img in iter_video_rgb8(self.files[0]):
                count += 1
                if count - 1 in keep:
                    yield self._fit(img, f"{self.files[0]} frame {count - 1}")
                if count - 1 >= last:
                    break
            if count != last + 1:
                raise InputError(
                    f"{self.files[0]}: video has {count} frames, expected {last + 1} (one per scene frame)"
                )
        else:
            for i in range(len(self.files)):
                yield self.read_frame(i)

    def read_frame(self, i: int) -> np.ndarray:
        """Prediction ``i`` (uint8 RGB [H, W, 3] at the scene's size) of an image sequence; a video is
        read in order by iterating."""
        if self.is_video:
            raise ValueError("read_frame: the frames of a video are read in order, by iterating")
        return self._fit(read_rgb8(self.files[i]), str(self.files[i]))

    def frame_keys(self) -> list[tuple[str, ...]]:
        """A content key of every prediction: its file's sha256, with its position for a video's frames."""
        hashes = self.sha256s()
        if not self.is_video:
            return [(h,) for h in hashes]
        positions = list(range(self.n_frames)) if self.video_positions is None else self.video_positions
        return [(hashes[0], str(p)) for p in positions]

    def sha256s(self) -> list[str]:
        """sha256 of every input file (one for a video)."""
        if self._hashes is None:
            self._hashes = [sha256_file(p) for p in self.files]
        return self._hashes

    def left_out(self) -> dict[str, Any]:
        """What was found and deliberately not read, for the record (``results.json`` inputs):
        ``outside_scene`` (``{"count", "frames"}``: frames beyond the scene under ``--frames``) and
        ``passed_over`` (lower ``{step}`` folders), each only when there is any, so that the
        record of a sequence read whole is unchanged."""
        out: dict[str, Any] = {}
        if self.outside_scene:
            out["outside_scene"] = {"count": len(self.outside_scene),
                                    "frames": signed_frames_text(self.outside_scene)}
        if self.passed_over:
            out["passed_over"] = list(self.passed_over)
        return out


# --------------------------------------------------------------------------- pattern pieces
def _literal(text: str) -> str:
    return re.escape(text).replace(r"\*", ".*")


def _part_regex(part: str, *, weather: str, scene_id: str, pattern: str, file_name: bool) -> tuple[str, set[str]]:
    """Regex body of one path component and the tokens it uses."""
    pieces, pos, used = [], 0, set()
    for m in _TOKEN.finditer(part):
        pieces.append(_literal(part[pos : m.start()]))
        tok = m.group(1)
        if tok in ("frame", "stem") and not file_name:
            raise InputError(f"pattern {pattern!r}: {{{tok}}} may only appear in the file name")
        if tok in used and tok in ("frame", "stem"):
            raise InputError(f"pattern {pattern!r}: {{{tok}}} appears twice in one name")
        step = r"\d+" if "step" in used else r"(?P<step>\d+)"  # a second {step} in one name: digits, no group
        pieces.append({"frame": r"(?P<frame>\d+)", "stem": r"(?P<stem>.+)", "step": step,
                       "weather": re.escape(weather), "scene": re.escape(scene_id)}[tok])
        used.add(tok)
        pos = m.end()
    pieces.append(_literal(part[pos:]))
    if "*" in _TOKEN.sub("", part):
        used.add("*")
    return "".join(pieces), used


def _is_video_name(last: str) -> bool:
    tokens = {m.group(1) for m in _TOKEN.finditer(last)}
    return not tokens & {"frame", "stem"} and Path(_TOKEN.sub("x", last)).suffix.lower() in VIDEO_EXTENSIONS


def _highest_step(found: list[tuple[Path, re.Match[str]]], passed_over: list[Path] | None) -> list[Path]:
    """Of sibling names that differ only in their ``{step}`` digits, the highest step (a run's last
    evaluation, e.g. WeatherCity's final ``full_set_30000_rgbs`` beside ``full_set_20000_rgbs``);
    equal steps (``030000``, ``30000``) all stay, to be reported as ambiguous. The others are
    appended to ``passed_over``."""
    if len(found) < 2:
        return [c for c, _ in found]
    top = max(int(m.group("step")) for _, m in found)
    kept = [c for c, m in found if int(m.group("step")) == top]
    if passed_over is not None:
        passed_over += [c for c, m in found if int(m.group("step")) != top]
    return kept


def _expand(root: Path, parts: Sequence[str], *, weather: str, scene_id: str, pattern: str,
            files: bool = False, passed_over: list[Path] | None = None) -> list[Path]:
    """Every path under ``root`` matching the components ``parts`` (the last ones are files when
    ``files``), wildcards expanded, in natural order. Where a component with ``{step}`` (and no
    ``*``) matches several siblings, only the highest step is kept (:func:`_highest_step`); the
    others are appended to ``passed_over``."""
    current = [root]
    for i, part in enumerate(parts):
        want_file = files and i == len(parts) - 1
        body, used = _part_regex(part, weather=weather, scene_id=scene_id, pattern=pattern, file_name=want_file)
        nxt: list[Path] = []
        for base in current:
            if not used & {"step", "*"}:
                name = _TOKEN.sub(lambda m: weather if m.group(1) == "weather" else scene_id, part)
                cand = base / name
                if cand.is_file() if want_file else cand.is_dir():
                    nxt.append(cand)
            elif base.is_dir():
                regex = re.compile(rf"^{body}$")
                found = sorted(((c, m) for c in base.iterdir()
                                if (c.is_file() if want_file else c.is_dir()) and (m := regex.match(c.name))),
                               key=lambda cm: natural_key(cm[0].name))
                one_step = "step" in used and "*" not in used  # a * level may differ in more than the step
                nxt += _highest_step(found, passed_over) if one_step else [c for c, _ in found]
        current = nxt
    return current


def _weather_names(weather: str, weather_names: Mapping[str, Sequence[str]]) -> list[str]:
    """Names the ``{weather}`` token may take: the tool's own names for it, then ours."""
    return list(dict.fromkeys([*weather_names.get(weather, ()), weather]))


def _locate(root: Path, layout: str, *, names: Sequence[str], scene: Scene,
            passed_over: list[Path] | None = None) -> list[tuple[Path, str]]:
    """(folder or video, weather name used) for every place ``layout`` points to that exists
    (lower ``{step}`` folders passed over are appended to ``passed_over``)."""
    pieces = layout.split("/")
    video = _is_video_name(pieces[-1])
    found: dict[Path, str] = {}
    for name in names:
        if video:
            hits = _expand(root, pieces, weather=name, scene_id=scene.id, pattern=layout, files=True,
                           passed_over=passed_over)
        else:
            hits = _expand(root, pieces[:-1], weather=name, scene_id=scene.id, pattern=layout,
                           passed_over=passed_over)
        for h in hits:
            found.setdefault(h, name)
    return list(found.items())


def _drop_weather_level(layout: str) -> str | None:
    """``layout`` without its ``{weather}`` folder level (``None`` if it has none)."""
    pieces = layout.split("/")
    kept = [p for p in pieces[:-1] if p != "{weather}"]
    if len(kept) == len(pieces) - 1:
        return None
    return "/".join([*kept, pieces[-1]])


def _with_weather(layout: str, name: str) -> str:
    """``layout`` with ``{weather}`` written out (for messages)."""
    return _TOKEN.sub(lambda m: name if m.group(1) == "weather" else m.group(0), layout)


# --------------------------------------------------------------------------- matching
def match_predictions(
    scene: Scene,
    weather: str,
    root: Path,
    *,
    pattern: str | Sequence[str] = DEFAULT_PATTERN,
    frame_start: int = 0,
    frame_offset: int = 0,
    resize: bool = False,
    weather_names: Mapping[str, Sequence[str]] | None = None,
    ignore: Sequence[str] = (),
    partial_reason: str | None = None,
    hints: Mapping[str, str] | None = None,
    weather_level_optional: bool = False,
    frames: Sequence[int] | None = None,
) -> PredictionSequence:
    """Find one prediction per scene frame under ``root`` following ``pattern``.

    Parameters
    ----------
    scene : Scene
    weather : str
    root : Path
        The scene's prediction folder.
    pattern : str or sequence of str
        See the module docstring. Several patterns are alternative layouts of one tool, tried in
        order: the first whose folder (or video) exists is read.
    frame_start : int
        The number ``{frame}`` has for the tool's first frame.
    frame_offset : int
        Tool frame *i* is scene frame ``i + frame_offset`` (numbered files, natural order, videos;
        ``{stem}`` names the scene frame itself).
    resize : bool
        Allow predictions of another size (resized on read with :data:`RESIZE_INTERPOLATION`).
    weather_names : mapping, optional
        The tool's own folder names per weather (``{"fog": ["smog"]}``), tried before ours.
    ignore : sequence of str
        Glob patterns (``fnmatch``) of sibling files in the frames folder that are not frames
        (``*-depth.png``); they are left out instead of being reported as extra files.
    partial_reason : str, optional
        Set when the tool can write fewer frames than the scene: a contiguous run of frames is
        then accepted and the missing ones are listed in :attr:`PredictionSequence.missing`.
    hints : mapping, optional
        Pattern -> explanation of folders the tool also writes (``{weather}/keys``); when no layout
        matches but such a folder exists, the error says what it holds.
    weather_level_optional : bool
        One weather is scored: its ``{weather}`` folder level may be left out when it is absent.
    frames : sequence of int, optional
        Only these scene frames are scored (``--frames``; a contiguous run): predictions of other
        frames are left alone, not reported as extra, and only these may be missing.

    Raises
    ------
    PredictionsMissingError
        When no layout exists for this weather (the weather was not produced).
    InputError
        If files are missing (every one named) or extra, several folders match a wildcard, the
        folder is empty, or a video is unreadable or of the wrong length.
    """
    if frames is not None:
        selected = sorted(set(frames))
        if not selected or selected != list(range(selected[0], selected[-1] + 1)):
            raise InputError(f"frames {frames_text(list(frames))}: scoring needs one contiguous run of frames "
                             "(temporal metrics compare neighbours), e.g. 0-9")
        if selected[0] < 0 or selected[-1] >= len(scene.frames):
            n = len(scene.frames)
            raise InputError(frames_outside([k for k in selected if not 0 <= k < n], n, scene_id=scene.id))
    layouts = [pattern] if isinstance(pattern, str) else list(pattern)
    for lay in layouts:
        if lay.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", lay) or ".." in lay.replace("\\", "/").split("/"):
            raise InputError(f"--pattern {lay!r}: a pattern must stay inside the predictions folder "
                             "(no absolute path, no '..')")
    names = _weather_names(weather, weather_names or {})
    n = len(scene.frames)
    chosen: tuple[str, Path, str] | None = None
    passed: list[Path] = []
    for candidate in layouts:
        read, passed = candidate, []
        hits = _locate(root, read, names=names, scene=scene, passed_over=passed)
        dropped = _drop_weather_level(candidate) if weather_level_optional else None
        if not hits and dropped is not None:
            read, passed = dropped, []
            # without its weather level, a frames folder counts only if it holds images
            hits = [(p, w) for p, w in _locate(root, read, names=names, scene=scene, passed_over=passed)
                    if p.is_file() or any(c.suffix.lower() in IMAGE_EXTENSIONS for c in p.iterdir())]
        if len(hits) > 1:
            listing = "\n".join(f"  {p}" for p, _ in hits)
            raise InputError(
                f"{root}: pattern {read!r} matches {len(hits)} places for weather {weather!r}, expected one:\n"
                f"{listing}\npass --pattern with the one to score"
            )
        if hits:
            chosen = (read, *hits[0])
            break
    if chosen is None:
        expected = " or ".join(repr(str(root / _with_weather(lay, names[0]))) for lay in layouts)
        hint_places = list((hints or {}).items())
        if weather_level_optional:
            hint_places += [(d, msg) for hp, msg in hint_places if (d := _drop_weather_level(hp)) is not None]
        found_hints = [f"{p} {msg}" for hp, msg in hint_places for name in names
                       for p in _expand(root, hp.split("/"), weather=name, scene_id=scene.id, pattern=hp)]
        if found_hints:
            raise InputError(f"{root}: no predictions for weather {weather!r} (expected {expected}); "
                             + "; ".join(found_hints))
        raise PredictionsMissingError(
            f"{root}: folder not found for weather {weather!r}: expected {expected} holding {n} frames "
            f"for scene {scene.id!r}"
        )
    layout, location, _ = chosen
    _check_inside(location, root)
    # the lower steps beside a folder (or video) on the chosen path, named in the record
    passed_over = [q.relative_to(root).as_posix() for q in passed
                   if q.parent in location.parents and q not in location.parents]
    last = layout.split("/")[-1]
    size = scene.image_size
    if _is_video_name(last):
        count = video_frame_count(location)
        pairs = [(location, frame_offset + i) for i in range(count)]
        found, missing, outside = _check_frames(
            pairs, scene, where=f"{location}", partial_reason=partial_reason, video_count=count, unmatched=[],
            stem_mode=False, frame_start=frame_start, frame_offset=frame_offset, selection=frames)
        return PredictionSequence([location], size, [k for _, k in found], resize=resize,
                                  info=read_info(location.parent), is_video=True, missing=missing,
                                  partial_reason=partial_reason, layout=layout, location=location,
                                  video_positions=None if frames is None else [k - frame_offset for _, k in found],
                                  outside_scene=outside, passed_over=passed_over)
    where = f"{location} (pattern {layout!r}, weather {weather!r})"
    body, used = _part_regex(last, weather=chosen[2], scene_id=scene.id, pattern=layout, file_name=True)
    if Path(_TOKEN.sub("x", last)).suffix.lower() not in IMAGE_EXTENSIONS:
        body += "(?i:" + "|".join(re.escape(e) for e in IMAGE_EXTENSIONS) + ")"
    regex = re.compile(rf"^{body}$")
    everything = sorted((p for p in location.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                        key=lambda p: natural_key(p.name))
    ignored = [p.name for p in everything if any(fnmatch.fnmatchcase(p.name, g) for g in ignore)]
    skip = set(ignored)
    candidates = [p for p in everything if p.name not in skip]
    if not candidates:
        raise InputError(f"{where}: no image files; expected {n} frames for scene {scene.id!r}"
                         + (f" ({len(ignored)} files ignored by the reader's rules {list(ignore)})" if ignored else ""))
    matched = [(p, m) for p in candidates if (m := regex.match(p.name))]
    unmatched = [p.name for p in candidates if not regex.match(p.name)]
    if "frame" in used:
        pairs = [(p, int(m.group("frame")) - frame_start + frame_offset) for p, m in matched]
    elif "stem" in used:
        stems = {f.image_path.stem: f.index for f in scene.frames}
        if any(m.group("stem") not in stems for _, m in matched):
            stems = {**_source_frame_numbers(scene), **stems}
        unmatched += [p.name for p, m in matched if m.group("stem") not in stems]
        pairs = [(p, stems[m.group("stem")]) for p, m in matched if m.group("stem") in stems]
    else:
        pairs = [(p, frame_offset + i) for i, (p, _) in enumerate(matched)]
    found, missing, outside = _check_frames(
        pairs, scene, where=where, partial_reason=partial_reason, video_count=None, unmatched=unmatched,
        stem_mode="stem" in used and "frame" not in used, frame_start=frame_start, frame_offset=frame_offset,
        selection=frames)
    for p, _ in found:
        _check_inside(p, root)
    return PredictionSequence([p for p, _ in found], size, [k for _, k in found], resize=resize,
                              info=read_info(location), missing=missing, partial_reason=partial_reason,
                              layout=layout, location=location, ignored=ignored, outside_scene=outside,
                              passed_over=passed_over)


def _source_frame_numbers(scene: Scene) -> dict[str, int]:
    """Stems of every image of the scene's camera in its image folder, numbered like scene frames.

    A scene can be a window of a longer processed sequence (``waymo_5``: the first 30 of about 200
    frames); an editor run on the whole folder also edits the frames outside the window. drivestudio
    names images ``{t:03d}_{cam}`` (docs/design.md §3), so in natural order the image ``k`` places
    after the scene's first frame is scene frame ``k`` (negative before it, ``n`` or more after it).
    """
    first = scene.frames[0].image_path
    camera = first.stem.rpartition("_")[2] if "_" in first.stem else None
    names = sorted((c.stem for c in first.parent.iterdir()
                    if c.is_file() and c.suffix.lower() in IMAGE_EXTENSIONS
                    and (camera is None or ("_" in c.stem and c.stem.rpartition("_")[2] == camera))),
                   key=natural_key)
    if first.stem not in names:
        return {}
    base = names.index(first.stem)
    return {stem: i - base for i, stem in enumerate(names)}


def _check_inside(path: Path, root: Path) -> None:
    """Refuse a prediction file or folder that resolves outside ``root`` (a symlink leading out):
    a scored frame must be a file of the predictions folder it was found in."""
    real, base = path.resolve(), root.resolve()
    if not real.is_relative_to(base):
        raise InputError(f"{path}: leads to {real}, outside the predictions folder {base}; "
                         "symlinks out of the predictions folder are not followed")


def signed_frames_text(frames: list[int]) -> str:
    """:func:`~wcbench.results.frames_text` that stays readable with frames before the scene
    (negative numbers): ``[-5, -4, -3, 20, 21]`` -> ``"-5 to -3,20-21"``."""
    if not frames or frames[0] >= 0:
        return frames_text(frames)
    return ",".join(part if not part.startswith("-") else re.sub(r"^(-\d+)-", r"\1 to ", part)
                    for part in frames_text(frames).split(","))


def _outside_hint(n: int, frame_offset: int, *, stem_mode: bool = False) -> str:
    """What to pass when a tool wrote frames beyond the scene's (``--frame-offset`` does not apply
    to files named after the source frames)."""
    frames = f"pass --frames 0-{n - 1} to score the scene's frames and leave the others out (they are counted " \
             "in results.json)"
    if stem_mode:
        return frames
    return (frames + ", and --frame-offset N when the tool's first frame is scene frame N (a render from a "
            "later start_timestep)" + (f"; --frame-offset is {frame_offset} now" if frame_offset else ""))


def _check_frames(
    pairs: list[tuple[Path, int]], scene: Scene, *, where: str, partial_reason: str | None, video_count: int | None,
    unmatched: list[str], stem_mode: bool, frame_start: int, frame_offset: int,
    selection: Sequence[int] | None = None,
) -> tuple[list[tuple[Path, int]], list[int], list[int]]:
    """Check (file, scene frame) pairs against the scene; return the pairs in frame order, the
    missing frames (allowed only as a missing head or tail when ``partial_reason`` is set) and the
    frames beyond the scene left out. With a ``selection``, only those scene frames are expected;
    the others' files are left alone, and so are frames beyond the scene (a render of a longer
    sequence), which are otherwise an error naming ``--frames``."""
    n = len(scene.frames)
    by_frame: dict[int, list[Path]] = {}
    extra = list(unmatched)
    beyond = sorted({k for _, k in pairs if not 0 <= k < n})
    for p, k in pairs:
        if 0 <= k < n:
            by_frame.setdefault(k, []).append(p)
    if selection is not None:
        chosen = set(selection)
        by_frame = {k: v for k, v in by_frame.items() if k in chosen}
    wanted = range(n) if selection is None else sorted(set(selection))
    missing = [k for k in wanted if k not in by_frame]
    if video_count is not None:
        outside = [i for i, (_, k) in enumerate(pairs) if not 0 <= k < n] if selection is None else []
        if (missing and partial_reason is None) or outside:
            shift = f" with --frame-offset {frame_offset}" if frame_offset else ""
            detail = (f"; video frames {signed_frames_text(outside)} fall outside the scene{shift}: "
                      f"{_outside_hint(n, frame_offset)}" if outside else "")
            start = "" if outside or frame_offset else \
                "; --frame-offset N when the video's first frame is scene frame N"
            raise InputError(f"{where}: video has {video_count} frames, expected {n} (one per scene frame)"
                             f"{detail}" + (f"; missing scene frames {missing}" if missing and frame_offset else "")
                             + start)
    dupes = {k: [p.name for p in v] for k, v in by_frame.items() if len(v) > 1}
    present = sorted(by_frame)
    holes = [k for k in wanted if present[0] <= k <= present[-1] and k not in by_frame] if present else []
    problems = []
    if missing and (partial_reason is None or holes or not present):
        only_holes = partial_reason is not None and bool(present)
        shown = holes if only_holes else missing
        expect = ([scene.frames[k].image_path.stem for k in shown] if stem_mode
                  else [str(k + frame_start - frame_offset) for k in shown])
        kind = "stems" if stem_mode else "numbers"
        inside = " inside the sequence (the tool may only end early, not skip frames)" if only_holes else ""
        before = [k for k in shown if k < frame_offset]
        if before and not stem_mode:
            problems.append(f"missing frames {shown}{inside} (frames {before} come before the tool's first frame "
                            f"with --frame-offset {frame_offset}; expected names for the others: "
                            f"{[e for k, e in zip(shown, expect) if k >= frame_offset]})")
        else:
            offset = "" if stem_mode or frame_offset or only_holes else \
                "; --frame-offset N when the tool's first frame is scene frame N"
            problems.append(f"missing frames {shown}{inside} (expected names for {kind} {expect}{offset})")
    if video_count is None and selection is None and beyond:
        names = [p.name for p, k in pairs if not 0 <= k < n]
        shown_names = f"{names[:5]} ... ({len(names)} in all)" if len(names) > 5 else str(names)
        hint = _outside_hint(n, frame_offset, stem_mode=stem_mode)
        problems.append(f"extra files {shown_names}: frames {signed_frames_text(beyond)} beyond the scene's frames "
                        f"0-{n - 1} (a render of a longer sequence?): {hint}")
    if extra:
        problems.append(f"extra files {extra}")
    if dupes:
        problems.append(f"several files for one frame {dupes}")
    if problems:
        shift = f" (with --frame-offset {frame_offset}: the tool's frame i is scene frame i{frame_offset:+d})" \
            if frame_offset else ""
        raise InputError(f"{where}: " + "; ".join(problems) + f"; the scene has {n} frames{shift}")
    return [(by_frame[k][0], k) for k in present], missing, beyond


#: Frame rates above this are not a timing but a typo (frames per second).
MAX_FPS = 1e6


def check_info(info: Any, path: Path) -> dict[str, Any]:
    """``info`` (an ``info.json``) if the fields wcbench reads have the right types and ranges.

    ``fps`` and ``timings.fps`` are finite and in (0, :data:`MAX_FPS`] (or ``null``), ``timings`` is
    an object whose numbers are finite and >= 0, ``timings.frame_ms`` a list of them; other fields
    are the tool's own.

    Raises
    ------
    InputError
        Naming ``path`` and the field.
    """
    info = expect_dict(info, path=path)
    if info.get("fps") is not None:
        finite_number(info["fps"], path=path, field="fps", positive=True, high=MAX_FPS)
    timings = info.get("timings")
    if timings is not None:
        timings = expect_dict(timings, path=path, field="timings")
        if timings.get("fps") is not None:
            finite_number(timings["fps"], path=path, field="timings.fps", positive=True, high=MAX_FPS)
        for key, value in timings.items():
            if isinstance(value, (int, float)) and key != "fps":
                finite_number(value, path=path, field=f"timings.{key}", low=0.0)
        if timings.get("frame_ms") is not None:
            for i, v in enumerate(expect_list(timings["frame_ms"], path=path, field="timings.frame_ms")):
                finite_number(v, path=path, field=f"timings.frame_ms[{i}]", low=0.0)
    return info


def read_info(folder: Path) -> dict[str, Any] | None:
    """The nearest ``info.json`` in ``folder`` or its two parents (weather, scene, method level),
    checked by :func:`check_info`."""
    for d in (folder, folder.parent, folder.parent.parent):
        path = d / INFO_FILE
        if path.is_file():
            return check_info(read_json(path, what="info.json"), path)
    return None


# --------------------------------------------------------------------------- scene folders
@dataclass(frozen=True)
class SceneFolder:
    """Where one scene's predictions are and why that folder was chosen.

    Attributes
    ----------
    scene_id : str
    path : Path
    matched : str
        The name that matched (the scene id, the scene's data folder name, an alias), or ``""``
        when the predictions folder itself is used (one scene).
    rule : str
        How it matched, for the user.
    """

    scene_id: str
    path: Path
    matched: str
    rule: str

    def record(self) -> dict[str, str]:
        """JSON form for results.json."""
        return {"folder": str(self.path), "matched": self.matched, "rule": self.rule}


def scene_names(ref: SceneRef) -> list[tuple[str, str]]:
    """(name, why) a tool may call scene ``ref``: its id, its data folder's name, its aliases."""
    out = {ref.id: "the scene id"}
    out.setdefault(ref.path.name, f"named like the scene's data folder, {ref.path.name}")
    for a in ref.aliases:
        out.setdefault(a, "an alias in the scene set")
    return list(out.items())


def find_scene_folder(root: Path, ref: SceneRef, *, n_scenes: int,
                      folder_patterns: Sequence[str] = ()) -> SceneFolder:
    """The folder holding one scene's predictions.

    It is the sub-folder of ``root`` named like the scene (:func:`scene_names`), or matching one
    of a reader's ``folder_patterns`` (``"{scene}_*"``: ``{scene}`` stands for any of those names,
    ``*`` for any text); else ``root`` itself when a single scene is evaluated.

    Raises
    ------
    InputError
        If ``root`` is missing or empty, no folder matches (several scenes), or several do
        (every candidate named).
    """
    if not root.is_dir():
        raise InputError(f"{root}: predictions folder not found")
    subdirs = sorted((d for d in root.iterdir() if d.is_dir()), key=lambda d: natural_key(d.name))
    hits: dict[Path, tuple[str, str]] = {}
    for name, why in scene_names(ref):
        for pat in ("{scene}", *folder_patterns):
            regex = re.compile("^" + _literal(pat).replace(re.escape("{scene}"), re.escape(name)) + "$")
            for d in subdirs:
                if regex.match(d.name):
                    rule = why if pat == "{scene}" else f"{why}, folder pattern {pat!r}"
                    hits.setdefault(d, (name, rule))
    if len(hits) == 1:
        (path, (name, rule)), = hits.items()
        return SceneFolder(ref.id, path, name, rule)
    if len(hits) > 1:
        listing = "\n".join(f"  {p.name}  ({rule})" for p, (_, rule) in hits.items())
        raise InputError(f"{root}: several folders could hold scene {ref.id!r}:\n{listing}\n"
                         "keep one, or point --predictions at the one to score (with a single scene)")
    if n_scenes == 1:
        if not any(root.iterdir()):
            raise InputError(f"{root}: predictions folder is empty")
        return SceneFolder(ref.id, root, "", "the predictions folder itself: one scene is scored")
    tried = ", ".join(repr(pat.replace("{scene}", name)) for name, _ in scene_names(ref)
                      for pat in ("{scene}", *folder_patterns))
    raise InputError(
        f"{root}: no folder for scene {ref.id!r} (tried {tried}); expected one sub-folder per scene "
        f"({root}/<scene>/<weather>/...)"
    )


def canonical_frame_path(out_dir: Path, index: int) -> Path:
    """Where frame ``index`` lives in a weather folder of the canonical layout."""
    return out_dir / f"{index:03d}.png"
