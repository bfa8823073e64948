"""Shared machinery of runnable methods: render into the canonical layout, resumably.

A subclass implements :meth:`FrameRenderer.render_frame` (and optionally :meth:`prepare`,
:meth:`native_size`, :meth:`describe`); :meth:`FrameRenderer.render` writes
``<out>/{frame:03d}.png`` atomically, keeps a small state file so a killed render resumes where it
stopped, times every frame (FPS) and finally writes ``info.json`` with the parameters (among them
``physics``, the weather it rendered, and ``truth_draw``, what of the ground truth it used) and the
sha256 of every frame. A folder finished with other settings is never replaced unless asked.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from wcbench.core.errors import InputError, ResultsExistError
from wcbench.core.frame_ranges import frames_outside
from wcbench.core.image_io import read_rgb8, resize_rgb8, write_mp4, write_png
from wcbench.core.options import Option, Range
from wcbench.core.progress import progress
from wcbench.core.storage import atomic_write_json, sha256_file, sha256_json
from wcbench.core.timing import FrameTimer
from wcbench.core.working_size import SizeRequest
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.weather_spec import truth_draw as _truth_draw
from wcbench.predictions import (
    CANONICAL_PATTERN,
    INFO_FILE,
    PredictionSequence,
    canonical_frame_path,
    match_predictions,
)
from wcbench.scenes.scene import Scene

_STATE_FILE = ".render_state.json"
FrameOutput = np.ndarray | tuple[np.ndarray, dict[str, Any]]


def sequence_frame_rate(timestamps: Sequence[float]) -> float:
    """Frames per second of a sequence from its timestamps (s); 10 when they do not increase."""
    dt = np.diff(np.asarray(timestamps, np.float64))
    if len(dt) == 0 or not np.all(dt > 0):
        return 10.0
    return float(min(max(1.0 / np.median(dt), 1.0), 120.0))


def _rendered_frames(folder: Path) -> list[int] | None:
    """The scene frames a finished render in ``folder`` lists in its ``info.json`` (``None``: no
    readable list; the folder is then checked against every scene frame)."""
    try:
        info = json.loads((folder / INFO_FILE).read_text(encoding="utf-8"))
        frames = sorted({int(f["index"]) for f in info["frames"]})
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return frames or None


def size_option(doc: str) -> Option:
    """The declared ``size`` option of a method: (width, height) in pixels, or null (the method's own)."""
    return Option("size", "ints", doc, length=2, range=Range(1), nullable=True)


class FrameRenderer(ABC):
    """Base class of methods wcbench runs frame by frame.

    A subclass declares the keyword options of its constructor in ``OPTIONS`` (name -> :class:`Option`;
    :func:`wcbench.methods.validate_method_options` checks them before it is built).
    """

    info: MethodInfo
    version: str = "1"
    OPTIONS: ClassVar[dict[str, Option]] = {}

    def parameters(self, weather: str) -> dict[str, Any]:
        """Settings that change the frames (recorded in ``info.json`` and part of the resume key)."""
        return {}

    _size_request: SizeRequest | None = None

    def request_size(self, request: SizeRequest | None) -> None:
        """Render at ``request`` (``--scale`` or ``--width/--height``) instead of :meth:`native_size`
        (``None``: the method's own size again). A method that draws at the scene's size (a 2D
        editor) has its frames area-resized to the requested size."""
        self._size_request = request

    def native_size(self, scene: Scene) -> tuple[int, int]:
        """(width, height) the method renders at unless told otherwise: the scene's own size unless a
        method says otherwise."""
        return scene.image_size

    def output_size(self, scene: Scene) -> tuple[int, int]:
        """(width, height) of the rendered frames: the requested size, else :meth:`native_size`."""
        if self._size_request is not None:
            return self._size_request.resolve(scene.image_size)
        return self.native_size(scene)

    def setup_scene(self, scene: Scene, *, show_progress: bool = True) -> None:  # noqa: B027 - optional hook
        """Scene-level work that every weather of ``scene`` shares (training a model), done once.

        :meth:`prepare` must do it too when it has not been done in this process; what it makes
        must be kept where a :meth:`prepare` in another process finds it (the cache folder), so a
        distributed run does it as one unit on one worker before the scene's weathers render.
        """

    def check_scene(self, scene: Scene, weather: str) -> None:  # noqa: B027 - optional hook
        """Raise ``InputError`` if ``scene`` lacks what rendering ``weather`` needs; called for every
        unit of a run before its first frame is rendered, so a run fails before writing anything."""

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:  # noqa: B027 - optional hook
        """Per-(scene, weather) set-up before the first frame (not part of frame timings)."""

    def required_models(self) -> tuple[str, ...]:
        """Model-store entries the method reads (fetched before a run starts; default none)."""
        return ()

    def describe(self) -> dict[str, Any]:
        """Facts known after :meth:`prepare` (model sizes...), added to ``info.json`` parameters."""
        return {}

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """The physics weather ``weather`` of ``scene`` is rendered with (``info.json``
        ``parameters.physics``).

        A method that renders a physics weather returns its
        :func:`~wcbench.methods.weather_spec.physics_record` (the Weather, rate and visibility a
        supervision check compares); the record is then part of the render key, since the scene's
        requested weather decides the frames. One that takes none says so in a sentence (the
        default). Called before anything is written, so an :class:`InputError` here (a weather the
        scene cannot give) stops the run cleanly.
        """
        return f"none: {self.info.name} renders no physics weather"

    def truth_draw(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any]:
        """What of the scene's ground truth the render used (``info.json`` ``parameters.truth_draw``;
        :func:`~wcbench.methods.weather_spec.truth_draw`). Default: nothing."""
        return _truth_draw(scene, None)

    def setup_timings(self) -> dict[str, float]:
        """Time spent before the frames (e.g. ``{"train_s": ...}``), added to ``info.json`` timings."""
        return {}

    @abstractmethod
    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> FrameOutput:
        """Frame ``index`` as uint8 RGB [H, W, 3] at :meth:`output_size`, optionally with a dict of
        per-frame facts for ``info.json``."""

    def open_predictions(
        self, scene: Scene, weather: str, root: Path, *, pattern: str | None = None, resize: bool = False,
        frame_offset: int = 0, single_weather: bool = False, frames: Sequence[int] | None = None,
    ) -> PredictionSequence:
        """Read frames this method wrote (the canonical layout).

        Frames rendered at another size than the scene's (``info.json`` ``size``) are read at that
        size and resized to the scene's working size as they are scored, as every method's are (see
        :meth:`wcbench.units.WorkUnit.score`), unless ``resize`` asks for them to be resized to the
        scene's size as they are read. A
        render of some frames (``wcbench render --frames``; ``info.json`` lists them) is scored on
        those frames when ``frames`` does not say otherwise.
        """
        if frames is None and pattern is None:
            frames = _rendered_frames(root / weather)
        seq = match_predictions(scene, weather, root, pattern=pattern or CANONICAL_PATTERN, resize=resize,
                                frame_offset=frame_offset, weather_level_optional=single_weather, frames=frames)
        size = (seq.info or {}).get("size")
        if size is not None and not resize:
            if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
                raise InputError(f"{root / weather / INFO_FILE}: 'size' must be [width, height] in pixels, "
                                 f"got {size!r}")
            seq.size = (size[0], size[1])
        return seq

    def _key(self, scene: Scene, weather: str, seed: int, frames: list[int]) -> str:
        inputs: dict[str, Any] = {
            "method": self.info.name, "version": self.version, "weather": weather, "seed": seed,
            "parameters": self.parameters(weather), "size": list(self.output_size(scene)), "frames": frames,
            "scene": scene.id, "sources": [sha256_file(f.image_path) for f in scene.frames],
        }
        physics = self.physics(scene, weather, seed=seed)
        if isinstance(physics, dict):  # a weather resolved from the scene decides the frames; a "none" does not
            inputs["physics"] = physics
        return sha256_json(inputs)

    def _check_existing(self, out_dir: Path, key: str, overwrite: bool) -> dict[str, Any] | None:
        """The finished info.json if it is up to date; clears a stale one when ``overwrite``."""
        info_path = out_dir / INFO_FILE
        if not info_path.is_file():
            return None
        try:
            old = json.loads(info_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            if not overwrite:
                raise InputError(f"{info_path}: not valid JSON ({exc}); pass --overwrite to re-render") from None
            old = {}
        if old.get("key") == key:
            if all((out_dir / f["file"]).is_file() and sha256_file(out_dir / f["file"]) == f["sha256"]
                   for f in old.get("frames", [])):
                return old
            return None  # same settings, damaged frames: re-render those (frames are deterministic)
        if not overwrite:
            raise ResultsExistError(
                f"{out_dir}: holds a finished render of {old.get('method')!r} with other settings; "
                "pass --overwrite to replace it or choose another --out"
            )
        info_path.unlink()  # without it a killed re-render resumes from the state file
        for stale in out_dir.glob("*.png"):
            stale.unlink()
        return None

    def render(
        self,
        scene: Scene,
        weather: str,
        out_dir: Path,
        *,
        seed: int = 0,
        frames: Sequence[int] | None = None,
        overwrite: bool = False,
        video: bool = False,
        show_progress: bool = True,
    ) -> dict[str, Any]:
        """Render frames of ``scene`` into ``out_dir``; skip work that is already done.

        Parameters
        ----------
        frames : sequence of int, optional
            Frame indices (default: all). Each frame is a pure function of (seed, frame).
        overwrite : bool
            Replace a folder finished with other settings (otherwise :class:`ResultsExistError`).
        video : bool
            Also write ``out_dir.parent / "<weather>.mp4"``.

        Returns
        -------
        dict
            The ``info.json`` content (method, version, weather, seed, parameters, timings,
            ``frames`` with file name, index, sha256 and per-frame facts), plus ``status``:
            ``"rendered"`` or ``"up to date"`` (not stored).
        """
        indices = list(range(len(scene))) if frames is None else sorted(set(frames))
        outside = [k for k in indices if not 0 <= k < len(scene)]
        if outside or not indices:
            raise InputError(frames_outside(outside, len(scene), scene_id=scene.id))
        key = self._key(scene, weather, seed, indices)
        out_dir.mkdir(parents=True, exist_ok=True)
        done_info = self._check_existing(out_dir, key, overwrite)
        if done_info is not None:
            return {**done_info, "status": "up to date"}
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
        width, height = self.output_size(scene)
        images: dict[int, np.ndarray] = {}
        bar = progress(indices, desc=f"{self.info.name} {scene.id} {weather}", total=len(indices),
                       enabled=show_progress and len(indices) > 1)
        for k in bar:
            path = canonical_frame_path(out_dir, k)
            done = state["frames"].get(str(k))
            if done and path.is_file() and sha256_file(path) == done["sha256"]:
                timer.frame_ms.append(done["ms"])
                continue
            with timer.frame():
                out = self.render_frame(scene, weather, k, seed=seed)
            img, facts = out if isinstance(out, tuple) else (out, {})
            if img.shape[:2] == scene.image_size[::-1] and (width, height) != scene.image_size \
                    and img.dtype == np.uint8:  # drawn at the scene's size, asked for another
                img = resize_rgb8(img, (width, height))
            if img.shape != (height, width, 3) or img.dtype != np.uint8:
                raise RuntimeError(
                    f"{self.info.name}.render_frame returned {img.dtype} {img.shape}, "
                    f"expected uint8 {(height, width, 3)}"
                )
            write_png(path, img)
            images[k] = img
            state["frames"][str(k)] = {"sha256": sha256_file(path), "ms": timer.frame_ms[-1], "info": facts}
            atomic_write_json(state_path, state)
        video_path = out_dir.parent / f"{weather}.mp4"
        if video and len(indices) > 1:
            seq = [images[k] if k in images else read_rgb8(canonical_frame_path(out_dir, k)) for k in indices]
            write_mp4(video_path, seq, fps=sequence_frame_rate([scene.frames[k].timestamp for k in indices]))
        info = {
            "method": self.info.name, "version": self.version, "scene": scene.id, "weather": weather,
            "seed": seed, "key": key, "size": [width, height],
            "parameters": {**self.parameters(weather), **self.describe(),
                           "physics": self.physics(scene, weather, seed=seed),
                           "truth_draw": self.truth_draw(scene, weather, seed=seed)},
            "timings": {**timer.summary(width=width, height=height), **self.setup_timings()},
            "frames": [
                {"file": canonical_frame_path(out_dir, k).name, "index": k,
                 "sha256": state["frames"][str(k)]["sha256"], "info": state["frames"][str(k)].get("info", {})}
                for k in indices
            ],
            "video": video_path.name if video and len(indices) > 1 else None,
        }
        atomic_write_json(out_dir / INFO_FILE, info)
        state_path.unlink(missing_ok=True)
        return {**info, "status": "rendered"}
