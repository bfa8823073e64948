"""Frame sizes: the metric working resolution (docs/design.md §8), and sizes asked for on the command
line (:class:`SizeRequest`).

Scoring a 1920x1080 sequence at its own size costs most of a run's time (optical flow, SSIM and
LPIPS grow with the pixel count). How much each score moves when the frames are first
area-downscaled, and what that saves, is measured per resolution by ``wcbench bench metrics``; the
default below comes from that table. ``native`` keeps the exact protocol.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from wcbench.core.errors import InputError

__all__ = ["METRIC_RESOLUTION", "NATIVE", "SizeRequest", "parse_metric_resolution", "working_size"]

#: Default working resolution: frames whose longer side exceeds this many pixels are scored
#: area-downscaled to it (aspect kept).
METRIC_RESOLUTION: int | None = 960
#: The word for "score at the scene's own frame size" (no working resolution).
NATIVE = "native"


def working_size(size: tuple[int, int], resolution: int | None) -> tuple[int, int]:
    """The (width, height) frames of ``size`` are scored at.

    ``size`` itself when ``resolution`` is ``None`` or its longer side fits; otherwise scaled
    (aspect kept, rounded, at least 1 px) so that the longer side is ``resolution`` pixels.
    """
    w, h = size
    if resolution is None or max(w, h) <= resolution:
        return w, h
    s = resolution / max(w, h)
    return max(1, round(w * s)), max(1, round(h * s))


def parse_metric_resolution(text: str | int | None) -> int | None:
    """``"native"`` -> ``None`` (native size); ``None`` -> :data:`METRIC_RESOLUTION`; a pixel count
    (the longer side, >= 32) -> that int.

    Raises
    ------
    InputError
        On anything else.
    """
    if text is None:
        return METRIC_RESOLUTION
    if text == NATIVE:
        return None
    try:
        value = int(text)
    except (TypeError, ValueError):
        value = 0
    if value < 32:
        raise InputError(f"metric resolution: expected {NATIVE!r} or the longer side in pixels (>= 32), got {text!r}")
    return value


@dataclass(frozen=True)
class SizeRequest:
    """A frame size asked for with ``--scale`` or ``--width/--height`` (run, render, evaluate).

    Attributes
    ----------
    scale : float, optional
        Fraction of the scene's size, in (0, 4].
    size : (int, int), optional
        (width, height) in pixels. Exactly one of ``scale`` and ``size`` is set.
    """

    scale: float | None = None
    size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if (self.scale is None) == (self.size is None):
            raise InputError("give either --scale or --width and --height")
        if self.scale is not None and not 0 < self.scale <= 4:
            raise InputError(f"--scale must be in (0, 4], got {self.scale}")
        if self.size is not None and not (len(self.size) == 2 and all(int(v) >= 1 for v in self.size)):
            raise InputError(f"--width and --height must be positive, got {self.size}")

    def resolve(self, scene_size: tuple[int, int]) -> tuple[int, int]:
        """(width, height) for a scene of ``scene_size``."""
        if self.size is not None:
            return int(self.size[0]), int(self.size[1])
        assert self.scale is not None
        w, h = scene_size
        return max(1, round(w * self.scale)), max(1, round(h * self.scale))

    def to_json(self) -> dict[str, Any]:
        """``{"scale": s}`` or ``{"size": [w, h]}``."""
        return {"scale": self.scale} if self.scale is not None else {"size": list(self.size or ())}
