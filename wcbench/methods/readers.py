"""Output readers for tools wcbench does not run, configured by naming presets (data files).

Each ``presets/<name>.toml`` describes what one tool's released code writes (its description cites
the file that writes it); no tool is special-cased in code::

    name = "fresco"
    description = "... (williamyang1991/FRESCO video_blend.py)"
    weathers = ["rain", "snow", "fog"]            # what the tool can produce
    layouts = ["{weather}/blend/{frame}.jpg",     # patterns (see wcbench.predictions), tried in
               "{weather}/blend.mp4"]             # order: the first that exists is read
    frame_start = 0                 # the number of the tool's first frame in file names
    resizes = true                  # the tool works at its own size: resize to the scene's size
    partial = "why the tool can write fewer frames than the scene"
    edits_source = true             # an editor of the source frames: warn when its output equals them
    unedited_hint = "which of its folders holds its input"
    ignore = ["*-depth.png"]        # sibling files in the frames folder that are not frames
    scene_folders = ["{scene}_*"]   # more names of a scene's folder ({scene}: id, data folder, alias)
    layout = "the tree shown by `wcbench methods list -v`"
    [weather_names]                 # the tool's own folder names for our weathers
    fog = ["smog"]
    [hints]                         # other folders the tool writes, explained when no layout matches
    "{weather}/keys" = "holds ..."

``--pattern`` replaces the preset's layouts; every other setting stays (it is what the tool does).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import MethodInfo
from wcbench.predictions import DEFAULT_PATTERN, RESIZE_INTERPOLATION, PredictionSequence, match_predictions
from wcbench.scenes.scene import Scene

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: Preset keys and their types (a preset with other keys is a bug in the data).
_KEYS: dict[str, type | tuple[type, ...]] = {
    "name": str, "description": str, "weathers": list, "layouts": list, "frame_start": int, "resizes": bool,
    "partial": str, "edits_source": bool, "unedited_hint": str, "ignore": list, "scene_folders": list,
    "layout": str, "weather_names": dict, "hints": dict,
}


class PatternReader:
    """Reads a tool's frames by file-name patterns (see :mod:`wcbench.predictions`).

    Parameters
    ----------
    info : MethodInfo
    pattern : str or sequence of str
        Default layouts, relative to a scene's prediction folder, tried in order.
    frame_start : int
        Number of the first frame in file names.
    resizes : bool
        The tool writes frames at its own size: they are resized to the scene's size.
    partial_reason : str, optional
        Why the tool can write fewer frames than the scene (the present run is then scored).
    weather_names : mapping, optional
        The tool's own folder names per weather.
    ignore : sequence of str
        Glob patterns of sibling files that are not frames.
    hints : mapping, optional
        Other folders the tool writes, explained in errors.
    """

    def __init__(self, info: MethodInfo, *, pattern: str | Sequence[str] = DEFAULT_PATTERN, frame_start: int = 0,
                 resizes: bool = False, partial_reason: str | None = None,
                 weather_names: Mapping[str, Sequence[str]] | None = None, ignore: Sequence[str] = (),
                 hints: Mapping[str, str] | None = None):
        self.info = info
        self.layouts = (pattern,) if isinstance(pattern, str) else tuple(pattern)
        self.frame_start = frame_start
        self.resizes = resizes
        self.partial_reason = partial_reason
        self.weather_names = {k: tuple(v) for k, v in (weather_names or {}).items()}
        self.ignore = tuple(ignore)
        self.hints = dict(hints or {})

    @property
    def pattern(self) -> str:
        """The first layout."""
        return self.layouts[0]

    def open_predictions(
        self, scene: Scene, weather: str, root: Path, *, pattern: str | None = None, resize: bool = False,
        frame_offset: int = 0, single_weather: bool = False, frames: Sequence[int] | None = None,
    ) -> PredictionSequence:
        """Match the files under ``root`` to ``scene``'s frames (see :func:`match_predictions`)."""
        return match_predictions(
            scene, weather, root, pattern=pattern or self.layouts, frame_start=self.frame_start,
            frame_offset=frame_offset, resize=resize or self.resizes, weather_names=self.weather_names,
            ignore=self.ignore, partial_reason=self.partial_reason, hints=self.hints,
            weather_level_optional=single_weather, frames=frames,
        )

    def settings(self) -> dict[str, Any]:
        """The naming settings, as recorded in results.json."""
        return {
            "layouts": list(self.layouts), "frame_start": self.frame_start, "resizes": self.resizes,
            "partial": self.partial_reason, "weather_names": {k: list(v) for k, v in self.weather_names.items()},
            "ignore": list(self.ignore), "scene_folders": list(self.info.scene_folders),
        }

    def describe(self) -> list[str]:
        """What the reader reads, one fact a line (``wcbench methods list -v``)."""
        lines = ["reads " + ", else ".join(self.layouts)]
        if self.weather_names:
            named = "; ".join(f"{w} as {' or '.join(repr(n) for n in names)}"
                              for w, names in self.weather_names.items())
            lines.append(f"weather folders: the weather's name, or the tool's: {named}")
        if self.frame_start:
            lines.append(f"frame numbers start at {self.frame_start}")
        if self.ignore:
            lines.append(f"ignores sibling files {', '.join(self.ignore)}")
        if self.resizes:
            lines.append(f"resizes: the tool works at its own size; frames are resized once to the scene's "
                         f"with {RESIZE_INTERPOLATION}")
        else:
            lines.append("size: frames must have the scene's size (else pass --resize)")
        if self.partial_reason:
            lines.append(f"may end early: {self.partial_reason}; the frames present are scored and the missing "
                         "ones named in results.json (partial) and results.csv (missing_frames)")
        if any("{step}" in lay for lay in self.layouts):
            lines.append("steps: of several {step} folders side by side the highest is read; the others are "
                         "named in results.json (inputs: passed_over)")
        if all("{stem}" in lay for lay in self.layouts):
            lines.append("more frames than the scene (edits of the whole processed folder): pass --frames with "
                         "the scene's frames, e.g. 0-29; the others are left out and counted in results.json "
                         "(inputs: outside_scene)")
        else:
            lines.append("more frames than the scene (a render of a longer sequence): pass --frames with the "
                         "scene's frames, e.g. 0-29; the others are left out and counted in results.json "
                         "(inputs: outside_scene). --frame-offset N: the tool's frame i is scene frame i + N "
                         "(its first frame is scene frame N)")
        if self.info.edits_source:
            lines.append("warns when every frame equals its source frame (wrong folder?)")
        folders = ["<scene id>", "<data folder name>", "<alias>", *self.info.scene_folders]
        lines.append("scene folders: " + ", ".join(folders) + " (see the scene set)")
        return [f"* {line}" for line in lines]


def load_preset(name: str) -> dict[str, Any]:
    """The naming preset ``presets/<name>.toml`` as a dict, checked.

    Raises
    ------
    ValueError
        On unknown keys, values of the wrong type, or unknown weathers (a bug in the preset).
    """
    text = resources.files("wcbench.methods").joinpath("presets").joinpath(f"{name}.toml").read_text(encoding="utf-8")
    return check_preset(tomllib.loads(text), name=name)


def check_preset(spec: dict[str, Any], *, name: str) -> dict[str, Any]:
    """Return ``spec`` after checking its keys, their types and its weathers.

    Raises
    ------
    ValueError
        On unknown or missing keys, values of the wrong type, or unknown weathers.
    """
    where = f"preset {name!r}"
    unknown = sorted(set(spec) - set(_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown} (known: {sorted(_KEYS)})")
    for key in ("name", "description", "layouts"):
        if key not in spec:
            raise ValueError(f"{where}: missing {key!r}")
    for key, kind in _KEYS.items():
        if key in spec and not isinstance(spec[key], kind):
            raise ValueError(f"{where}: {key!r} must be of type {kind}, got {type(spec[key]).__name__}")
    for key in ("layouts", "weathers", "ignore", "scene_folders"):
        if key in spec and not all(isinstance(v, str) for v in spec[key]):
            raise ValueError(f"{where}: {key!r} must be a list of strings")
    if not spec["layouts"]:
        raise ValueError(f"{where}: 'layouts' is empty")
    weathers = spec.get("weathers", list(WEATHERS))
    for what, names in (("weathers", weathers), ("weather_names", list(spec.get("weather_names", {})))):
        bad = sorted(set(names) - set(WEATHERS))
        if bad:
            raise ValueError(f"{where}: unknown weathers in {what}: {bad} (known: {', '.join(WEATHERS)})")
    return spec


def reader_from_preset(name: str) -> PatternReader:
    """Build the reader of a naming preset."""
    spec = load_preset(name)
    names = {w: [v] if isinstance(v, str) else list(v) for w, v in spec.get("weather_names", {}).items()}
    info = MethodInfo(
        name=spec["name"], description=spec["description"], kind="reader",
        weathers=tuple(spec.get("weathers", WEATHERS)), layout="",
        edits_source=bool(spec.get("edits_source", False)), unedited_hint=spec.get("unedited_hint", ""),
        scene_folders=tuple(spec.get("scene_folders", ())),
    )
    reader = PatternReader(
        info, pattern=spec["layouts"], frame_start=int(spec.get("frame_start", 0)),
        resizes=bool(spec.get("resizes", False)), partial_reason=spec.get("partial"), weather_names=names,
        ignore=spec.get("ignore", ()), hints=spec.get("hints", {}),
    )
    tree = spec.get("layout", "").strip("\n")
    reader.info = replace(info, layout="\n".join([tree, *reader.describe()]).strip("\n"),
                          defaults=reader.settings())
    return reader


def __getattr__(attr: str) -> Any:
    """``readers.<preset>`` is a factory for that preset's reader (``qwen_image`` -> ``qwen-image``),
    so the method registry can name readers as plain import strings."""
    name = attr.replace("_", "-")
    if resources.files("wcbench.methods").joinpath("presets").joinpath(f"{name}.toml").is_file():
        return lambda: reader_from_preset(name)
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
