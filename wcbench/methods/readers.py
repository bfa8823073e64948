"""Output readers for tools wcbench does not run, configured by naming presets (data files).

Each ``presets/<name>.toml`` holds a tool's usual output layout::

    name = "controlnet"
    description = "..."
    pattern = "{weather}/{stem}"     # see wcbench.predictions for the tokens
    frame_start = 0                  # the number of the first frame in file names
    weathers = ["rain", "snow", "fog"]
    layout = "text shown to users"

``--pattern`` overrides the preset's pattern.
"""

from __future__ import annotations

import sys
from importlib import resources
from pathlib import Path
from typing import Any

from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import MethodInfo
from wcbench.predictions import DEFAULT_PATTERN, PredictionSequence, match_predictions
from wcbench.scenes.scene import Scene

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class PatternReader:
    """Reads a tool's frames by file-name pattern (see :mod:`wcbench.predictions`).

    Parameters
    ----------
    info : MethodInfo
    pattern : str
        Default pattern, relative to a scene's prediction folder.
    frame_start : int
        Number of the first frame in file names.
    """

    def __init__(self, info: MethodInfo, *, pattern: str = DEFAULT_PATTERN, frame_start: int = 0):
        self.info = info
        self.pattern = pattern
        self.frame_start = frame_start

    def open_predictions(
        self, scene: Scene, weather: str, root: Path, *, pattern: str | None = None, resize: bool = False
    ) -> PredictionSequence:
        """Match the files under ``root`` to ``scene``'s frames (see :func:`match_predictions`)."""
        return match_predictions(
            scene, weather, root, pattern=pattern or self.pattern, frame_start=self.frame_start, resize=resize
        )


def load_preset(name: str) -> dict[str, Any]:
    """The naming preset ``presets/<name>.toml`` as a dict."""
    text = resources.files("wcbench.methods").joinpath("presets").joinpath(f"{name}.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def reader_from_preset(name: str) -> PatternReader:
    """Build the reader of a naming preset."""
    spec = load_preset(name)
    weathers = tuple(spec.get("weathers", WEATHERS))
    unknown = set(weathers) - set(WEATHERS)
    if unknown:
        raise ValueError(f"preset {name!r}: unknown weathers {sorted(unknown)}")
    info = MethodInfo(
        name=spec["name"], description=spec["description"], kind="reader", weathers=weathers,
        layout=spec.get("layout", "").strip(),
        defaults={"pattern": spec["pattern"], "frame_start": spec.get("frame_start", 0)},
    )
    return PatternReader(info, pattern=spec["pattern"], frame_start=int(spec.get("frame_start", 0)))


def __getattr__(attr: str) -> Any:
    """``readers.<preset>`` is a factory for that preset's reader (``qwen_image`` -> ``qwen-image``),
    so the method registry can name readers as plain import strings."""
    name = attr.replace("_", "-")
    if resources.files("wcbench.methods").joinpath("presets").joinpath(f"{name}.toml").is_file():
        return lambda: reader_from_preset(name)
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
