"""The wrong-folder check: predictions of an editing tool that all equal their source frames.

Tools often keep a copy of their (resized) input beside their edits (FRESCO's ``video/``); pointed
at it, ``--predictions`` would score the unedited input as an edit. A unit whose every frame equals
its source, byte for byte or up to resampling, gets a warning in ``results.json`` (scoring goes on).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

#: "Equal to the source": on every frame, the mean |difference| of 64-px-wide area-averaged
#: thumbnails of prediction and source is at most this many uint8 levels. Measured: a resize round
#: trip through FRESCO's 512-px size plus JPEG at quality 75 stays below 0.6 (pandaset_002 and the
#: demo scene), while a 3 % darkening gives 3.4 and sparse rain streaks 4.8.
UNEDITED_LEVELS = 1.0
UNEDITED_THUMB_WIDTH = 64


def _thumbnail(img: np.ndarray) -> np.ndarray:
    """Area-averaged float32 thumbnail [h, UNEDITED_THUMB_WIDTH, 3] of a uint8 RGB frame."""
    h, w = img.shape[:2]
    size = (UNEDITED_THUMB_WIDTH, max(1, round(UNEDITED_THUMB_WIDTH * h / w)))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA).astype(np.float32)


class UneditedCheck:
    """Whether every prediction equals its source frame: byte for byte, or up to resampling
    (thumbnails within :data:`UNEDITED_LEVELS`)."""

    def __init__(self) -> None:
        self.identical = True
        self.worst = 0.0
        self.frames = 0

    def update(self, pred8: np.ndarray, src8: np.ndarray) -> None:
        """Compare one uint8 RGB prediction [H, W, 3] with its source frame."""
        self.frames += 1
        self.identical = self.identical and np.array_equal(pred8, src8)
        self.worst = max(self.worst, float(np.abs(_thumbnail(pred8) - _thumbnail(src8)).mean()))

    def warning(self, *, scene: str, weather: str, where: Path | str, hint: str) -> dict[str, Any] | None:
        """The ``results.json`` warning record, or ``None`` when some frame was edited."""
        if not self.frames or (not self.identical and self.worst > UNEDITED_LEVELS):
            return None
        how = ("are byte-identical to the scene's source frames" if self.identical else
               f"equal the scene's source frames up to resampling (largest mean |difference| "
               f"{self.worst:.2f}/255 on {UNEDITED_THUMB_WIDTH}-px thumbnails)")
        message = (f"all {self.frames} {weather} frames from {where} {how}: they look like the unedited "
                   "input, not an edit. Is --predictions pointing at the right folder?"
                   + (f" ({hint})" if hint else ""))
        return {"scene": scene, "weather": weather, "kind": "unedited", "message": message,
                "identical": self.identical, "max_thumbnail_difference": self.worst}
