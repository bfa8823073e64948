"""Frame numbers in words: runs of consecutive frames as ranges, so a message stays one short line."""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["frames_outside", "ranges_text"]


def ranges_text(frames: Sequence[int]) -> str:
    """``[25, 26, 27, 29]`` -> ``"25-27,29"``; negative frames read ``"-5 to -3"``."""
    values = sorted(set(int(f) for f in frames))
    out, i = [], 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        sep = " to " if values[i] < 0 else "-"
        out.append(str(values[i]) if i == j else f"{values[i]}{sep}{values[j]}")
        i = j + 1
    return ",".join(out)


def frames_outside(outside: Sequence[int], n: int, *, scene_id: str | None = None, option: str = "") -> str:
    """The one-line refusal of frames ``outside`` a scene of ``n`` frames (``option``: the flag that
    asked for them), summarised as ranges: ``frames 30-99 are beyond the 30 frames (0-29) of scene 'x'``."""
    scene = f"scene {scene_id!r}" if scene_id else "the scene"
    lead = f"{option}: " if option else ""
    if not outside:
        return f"{lead}no frame selected; the frames of {scene} are 0-{n - 1}"
    count = len(set(outside))
    word = "frame" if count == 1 else "frames"
    verb = "is" if count == 1 else "are"
    return f"{lead}{word} {ranges_text(outside)} {verb} beyond the {n} frames (0-{n - 1}) of {scene}"
