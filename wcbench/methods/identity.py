"""The ``identity`` method: returns the raw frames unchanged, for sanity checks.

Scored against itself it must give perfect content metrics, zero CLIP-DS and a flicker ratio of
exactly 1, which makes it a quick check of a metric set-up.
"""

from __future__ import annotations

import numpy as np

from wcbench.core.image_io import read_rgb8
from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer
from wcbench.scenes.scene import Scene


class IdentityMethod(FrameRenderer):
    """Copies the scene's raw frames for every weather."""

    info = MethodInfo(
        name="identity",
        description="Returns the raw frames unchanged (sanity check for metrics)",
        kind="runnable",
        weathers=WEATHERS,
        layout="writes <out>/identity/<scene>/<weather>/{frame:03d}.png + info.json",
    )

    def physics(self, scene: Scene, weather: str, *, seed: int) -> str:
        """None: every weather is the raw frames."""
        return "none: identity copies the raw frames; it renders no weather"

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> np.ndarray:
        """The raw frame ``index`` as uint8 RGB."""
        return read_rgb8(scene.frames[index].image_path)
