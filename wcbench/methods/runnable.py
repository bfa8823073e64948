"""Shared machinery of runnable methods: render into the canonical layout, resumably.

A subclass implements :meth:`FrameRenderer.render_frame`; :meth:`FrameRenderer.render` writes
``<out>/{frame:03d}.png`` atomically, keeps a small state file so a killed render resumes where it
stopped, times every frame (FPS) and finally writes ``info.json`` with the parameters and the
sha256 of every frame.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.image_io import write_png
from wcbench.methods.protocol import MethodInfo
from wcbench.predictions import (
    CANONICAL_PATTERN,
    INFO_FILE,
    PredictionSequence,
    canonical_frame_path,
    match_predictions,
)
from wcbench.progress import progress
from wcbench.scene import Scene
from wcbench.storage import atomic_write_json, sha256_file, sha256_json
from wcbench.timing import FrameTimer

_STATE_FILE = ".render_state.json"


class FrameRenderer(ABC):
    """Base class of methods wcbench runs frame by frame."""

    info: MethodInfo
    version: str = "1"

    def parameters(self, weather: str) -> dict[str, Any]:
        """Settings that change the frames (recorded in ``info.json`` and part of the resume key)."""
        return {}

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:  # noqa: B027 - optional hook
        """Per-(scene, weather) set-up before the first frame (not part of frame timings)."""

    @abstractmethod
    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> np.ndarray:
        """Frame ``index`` as uint8 RGB [H, W, 3] at the scene's resolution."""

    def open_predictions(
        self, scene: Scene, weather: str, root: Path, *, pattern: str | None = None, resize: bool = False
    ) -> PredictionSequence:
        """Read frames this method wrote (the canonical layout)."""
        return match_predictions(scene, weather, root, pattern=pattern or CANONICAL_PATTERN, resize=resize)

    def _key(self, scene: Scene, weather: str, seed: int) -> str:
        return sha256_json({
            "method": self.info.name, "version": self.version, "weather": weather, "seed": seed,
            "parameters": self.parameters(weather), "scene": scene.id,
            "sources": [sha256_file(f.image_path) for f in scene.frames],
        })

    def render(
        self, scene: Scene, weather: str, out_dir: Path, *, seed: int = 0, show_progress: bool = True
    ) -> dict[str, Any]:
        """Render every frame of ``scene`` into ``out_dir``; skip work that is already done.

        Returns
        -------
        dict
            The ``info.json`` content: method, version, weather, seed, parameters, timings, and
            ``frames`` (file name and sha256 per frame).
        """
        out_dir.mkdir(parents=True, exist_ok=True)
        key = self._key(scene, weather, seed)
        info_path = out_dir / INFO_FILE
        if info_path.is_file():
            old = json.loads(info_path.read_text(encoding="utf-8"))
            if old.get("key") == key and all(
                (out_dir / f["file"]).is_file() and sha256_file(out_dir / f["file"]) == f["sha256"]
                for f in old.get("frames", [])
            ):
                return old
        state_path = out_dir / _STATE_FILE
        state: dict[str, Any] = {"key": key, "frames": {}}
        if state_path.is_file():
            try:
                loaded = json.loads(state_path.read_text(encoding="utf-8"))
                if loaded.get("key") == key:
                    state = loaded
            except json.JSONDecodeError:
                pass  # a torn state file cannot happen (atomic writes); an edited one is ignored
        self.prepare(scene, weather, seed=seed)
        timer = FrameTimer()
        width, height = scene.image_size
        for k in progress(range(len(scene)), desc=f"{self.info.name} {scene.id} {weather}", enabled=show_progress):
            path = canonical_frame_path(out_dir, k)
            done = state["frames"].get(str(k))
            if done and path.is_file() and sha256_file(path) == done["sha256"]:
                timer.frame_ms.append(done["ms"])
                continue
            with timer.frame():
                img = self.render_frame(scene, weather, k, seed=seed)
            if img.shape != (height, width, 3) or img.dtype != np.uint8:
                raise RuntimeError(
                    f"{self.info.name}.render_frame returned {img.dtype} {img.shape}, "
                    f"expected uint8 {(height, width, 3)}"
                )
            write_png(path, img)
            state["frames"][str(k)] = {"sha256": sha256_file(path), "ms": timer.frame_ms[-1]}
            atomic_write_json(state_path, state)
        info = {
            "method": self.info.name, "version": self.version, "scene": scene.id, "weather": weather,
            "seed": seed, "parameters": self.parameters(weather), "key": key,
            "timings": timer.summary(width=width, height=height),
            "frames": [
                {"file": canonical_frame_path(out_dir, k).name, "sha256": state["frames"][str(k)]["sha256"]}
                for k in range(len(scene))
            ],
        }
        atomic_write_json(info_path, info)
        state_path.unlink(missing_ok=True)
        return info
