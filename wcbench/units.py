"""The unit of work: one method x scene x weather, rendered (runnable methods) and scored.

Everything that produces numbers goes through :class:`WorkUnit`: ``wcbench run`` renders then
scores each unit, ``wcbench evaluate`` scores units of another tool's files, ``wcbench render``
renders units without scoring, and the benchmarks call the same code. A unit's result is kept in
``OUT/.work/<scene>/<weather>.json`` under a key over every input that can change a number (the
sha256 of each prediction, source and reference frame, the metric settings and the results schema),
so a killed run resumes, a re-run with unchanged inputs does no work, and units can be computed in
any order or place and assembled afterwards (docs/design.md §1, §9).
"""

from __future__ import annotations

import json
import queue
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, resize_rgb8, to_float
from wcbench.core.progress import progress
from wcbench.core.storage import atomic_write_json, json_safe, sha256_file, sha256_json
from wcbench.core.working_size import SizeRequest, working_size
from wcbench.methods import Method, is_runnable
from wcbench.metrics.base import Metric, MetricContext
from wcbench.predictions import RESIZE_INTERPOLATION, PredictionSequence
from wcbench.results import SCHEMA_VERSION
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import SceneRef
from wcbench.unedited import UNEDITED_LEVELS, UNEDITED_THUMB_WIDTH, UneditedCheck

#: How the scene's frames are resized for a method scored at its own resolution (see
#: :func:`wcbench.core.image_io.resize_rgb8`), recorded with every such result.
SOURCE_INTERPOLATION = "area (cv2.INTER_AREA) when shrinking, bicubic when enlarging"
#: Folder of ``OUT`` holding one finished result per unit.
WORK_DIR = ".work"
#: Frames handed to metrics per update: model metrics batch their inference; 8 frames of 1080p
#: in three float32 streams stay under 0.6 GB.
FRAME_BATCH = 8
#: Bytes of decoded source frames kept in memory across the units of a process: the other weathers
#: and methods of a scene read the raw frames once.
SOURCE_CACHE_BYTES = 1 << 30


class _SourceCache:
    """Decoded (and resized) raw frames by (sha256, size), least recently used dropped beyond a budget."""

    def __init__(self, budget_bytes: int):
        self.budget = budget_bytes
        self._items: OrderedDict[tuple[str, tuple[int, int]], np.ndarray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def clear(self) -> None:
        """Forget every frame (benchmarks start cold)."""
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def get(self, key: tuple[str, tuple[int, int]], load: Callable[[], np.ndarray]) -> np.ndarray:
        """The frame under ``key``, loaded by ``load()`` on a miss (kept if it fits the budget)."""
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        img = load()
        img.setflags(write=False)  # shared by units: nobody may change it
        with self._lock:
            if key not in self._items and img.nbytes <= self.budget:
                self._items[key] = img
                self._bytes += img.nbytes
                while self._bytes > self.budget:
                    _, old = self._items.popitem(last=False)
                    self._bytes -= old.nbytes
        return img


SOURCE_CACHE = _SourceCache(SOURCE_CACHE_BYTES)


def prefetch(items: Iterable[Any], depth: int) -> Iterator[Any]:
    """``items`` produced by a background thread, up to ``depth`` ahead, in order (decoding and
    resizing release the GIL, so frames are read while the metrics run). An exception of the
    producer is raised here, at its place in the sequence."""
    q: queue.Queue[tuple[bool, Any]] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        q.put((True, item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((False, None))
        except BaseException as exc:  # handed to the consumer, raised there
            q.put((False, exc))

    thread = threading.Thread(target=produce, name="wcbench-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            ok, item = q.get()
            if not ok:
                if item is not None:
                    raise item
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.05)


@dataclass(frozen=True)
class RenderSettings:
    """How a runnable method renders a unit (part of the method's own resume key).

    Attributes
    ----------
    seed : int
        Random seed of the method; each frame is a pure function of (seed, frame).
    frames : tuple of int, optional
        Frame indices to render (default: all).
    overwrite : bool
        Replace a folder rendered with other settings.
    video : bool
        Also write ``<weather>.mp4`` beside the weather folder.
    show_progress : bool
        Progress bars.
    """

    seed: int = 0
    frames: tuple[int, ...] | None = None
    overwrite: bool = False
    video: bool = False
    show_progress: bool = True


@dataclass
class WorkUnit:
    """One method x scene x weather.

    Attributes
    ----------
    method : Method
    scene : Scene
    weather : str
    root : Path
        The scene's prediction folder (``<predictions>/<scene>``, or the predictions folder itself
        when one scene is scored).
    source_hashes : list of str
        sha256 of the scene's raw frames (shared by the scene's units).
    predictions : PredictionSequence or None
        Set by :meth:`open`.
    check_unedited : bool
        Warn when every prediction equals its source frame (readers of editing tools; see
        :mod:`wcbench.unedited`).
    scene_ref : SceneRef, optional
        Where the scene was loaded from (another process loads it again from there).
    open_options : dict, optional
        The keyword arguments :meth:`open` was called with (another process opens it the same way).
    """

    method: Method
    scene: Scene
    weather: str
    root: Path
    source_hashes: list[str] = field(default_factory=list)
    predictions: PredictionSequence | None = None
    check_unedited: bool = False
    scene_ref: SceneRef | None = None
    open_options: dict[str, Any] | None = None

    @property
    def label(self) -> str:
        """``<method> <scene> <weather>`` for messages and progress bars."""
        return f"{self.method.info.name} {self.scene.id} {self.weather}"

    def render(self, settings: RenderSettings) -> dict[str, Any]:
        """Render this unit's frames into ``root/<weather>/`` (runnable methods only; resumable).

        Returns
        -------
        dict
            The ``info.json`` content plus ``status`` (``"rendered"`` or ``"up to date"``).

        Raises
        ------
        InputError
            If the method is an output reader (wcbench cannot run it).
        """
        if not is_runnable(self.method):
            name = self.method.info.name
            raise InputError(
                f"method {name!r} is an output reader: wcbench cannot run it. Render with the tool itself, "
                f"then score its frames with `wcbench evaluate --method {name} --predictions DIR`"
            )
        return self.method.render(  # type: ignore[attr-defined]
            self.scene, self.weather, self.root / self.weather, seed=settings.seed, frames=settings.frames,
            overwrite=settings.overwrite, video=settings.video, show_progress=settings.show_progress,
        )

    def open(self, *, pattern: str | None = None, resize: bool = False, frame_offset: int = 0,
             single_weather: bool = False, frames: Sequence[int] | None = None) -> PredictionSequence:
        """Match the unit's prediction files to the scene's frames (see :meth:`Method.open_predictions`);
        ``frames``: only these scene frames (a contiguous run) are scored."""
        self.open_options = {"pattern": pattern, "resize": resize, "frame_offset": frame_offset,
                             "single_weather": single_weather, "frames": None if frames is None else list(frames)}
        self.predictions = self.method.open_predictions(
            self.scene, self.weather, self.root, pattern=pattern, resize=resize, frame_offset=frame_offset,
            single_weather=single_weather, frames=frames,
        )
        return self.predictions

    def _opened(self) -> PredictionSequence:
        if self.predictions is None:
            raise RuntimeError(f"{self.label}: open() the predictions first")
        return self.predictions

    @property
    def reference_paths(self) -> list[Path] | None:
        """Ground-truth frames of this weather, or ``None`` when the scene has none."""
        return self.scene.reference_paths(self.weather)

    def inputs(self) -> dict[str, Any]:
        """sha256 of every input frame (``predictions``, ``source``, ``reference`` or ``None``) and
        where the predictions were found (``location``, ``layout``, scored ``frames``, ``ignored``)."""
        refs = self.reference_paths
        if refs is None:
            ref_hashes = None
        elif self.weather == "clear":
            ref_hashes = self.source_hashes  # the raw frames are the truth of clear
        else:
            ref_hashes = [sha256_file(p) for p in refs]
        p = self._opened()
        return {"predictions": p.sha256s(), "source": self.source_hashes, "reference": ref_hashes,
                "info": None if p.info is None else sha256_json(p.info),
                "location": str(p.location) if p.location else None, "layout": p.layout,
                "frames": p.frame_indices, "ignored": p.ignored}

    def scored_size(self, resolution: int | None, score_size: SizeRequest | None = None) -> tuple[int, int]:
        """(width, height) the frames are scored at: ``score_size`` when given, else the predictions'
        size within the working ``resolution``."""
        if score_size is not None:
            return score_size.resolve(self.scene.image_size)
        return working_size(self._opened().size, resolution)

    def key(self, metric_config: dict[str, Any], *, fps: float | None = None, resolution: int | None = None,
            score_size: SizeRequest | None = None) -> str:
        """Cache key of this unit's result: every input that can change a number (each frame's
        sha256, the predictions' ``info.json`` with its timings, the ``--fps`` given, the metric
        settings, the size scored at and the results schema)."""
        inputs, p = self.inputs(), self._opened()
        return sha256_json({
            "schema_version": SCHEMA_VERSION, "scene": self.scene.id, "weather": self.weather,
            "info": p.info, "fps": fps, "working_size": list(self.scored_size(resolution, score_size)),
            "predictions": inputs["predictions"], "source": inputs["source"], "reference": inputs["reference"],
            "metrics": metric_config, "resize": p.resize, "interpolation": RESIZE_INTERPOLATION if p.resize else None,
            "size": list(p.size),
            "frames": p.frame_indices, "missing": p.missing, "partial_reason": p.partial_reason,
            "check_unedited": [self.check_unedited, UNEDITED_LEVELS, UNEDITED_THUMB_WIDTH],
        })

    def work_path(self, out: Path) -> Path:
        """Where this unit's finished result is kept: ``out/.work/<scene>/<weather>.json``."""
        return out / WORK_DIR / self.scene.id / f"{self.weather}.json"

    def cached_result(self, out: Path, key: str) -> dict[str, Any] | None:
        """The finished result stored under ``key``, or ``None``.

        A unit file carries the sha256 of its result: a file that was edited, damaged or is not
        a unit file at all is not served; the unit is computed again and the file replaced.
        """
        path = self.work_path(out)
        if not path.is_file():
            return None
        try:
            rec = json.loads(path.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, ValueError, RecursionError):
            return None  # never torn (atomic writes); a damaged file is simply recomputed
        if not (isinstance(rec, dict) and rec.get("key") == key and isinstance(rec.get("result"), dict)):
            return None
        if rec.get("checksum") != sha256_json(rec["result"]):
            return None
        result: dict[str, Any] = rec["result"]
        return result

    def validate(self, *, show_progress: bool = True) -> None:
        """Decode every prediction once (size, bit depth, video length), so bad input fails before work starts."""
        preds = self._opened()
        for _ in progress(preds, desc=f"checking {self.scene.id} {self.weather}", total=len(preds),
                          enabled=show_progress):
            pass

    def score(self, metrics: dict[str, Metric], *, fps: float | None = None, resolution: int | None = None,
              score_size: SizeRequest | None = None, prefetch_frames: bool = True, share_sources: bool = True,
              show_progress: bool = True) -> dict[str, Any]:
        """Run every metric over the unit's frames.

        Parameters
        ----------
        metrics : dict of str to Metric
        fps : float, optional
            Frame rate to report when the predictions carry no timings.
        resolution : int, optional
            Metric working resolution (:func:`working_size`): frames are area-downscaled so that
            their longer side is at most this many pixels; ``None`` scores at the predictions' size.
        score_size : SizeRequest, optional
            Score at this size instead (predictions and scene frames area-resized to it).
        prefetch_frames : bool
            Decode (and resize) frames in a background thread while the metrics run.
        share_sources : bool
            Keep the decoded raw frames in memory (:data:`SOURCE_CACHE`) for the scene's other units.

        Returns
        -------
        dict
            ``{"outputs": {output: record}, "skipped": [{"scene", "weather", "metric", "reason"}]}``,
            JSON-safe (non-finite values as ``None``).
        """
        scene, preds = self.scene, self._opened()
        refs = self.reference_paths
        ctx = MetricContext(
            weather=self.weather, n_frames=len(preds), has_reference=refs is not None,
            has_source=True, method_info=preds.info, fps_override=fps,
        )
        active, skipped = {}, []
        for name, m in metrics.items():
            m.bind(ctx)
            reason = m.skip_reason(ctx)
            if reason:
                skipped.append({"scene": scene.id, "weather": self.weather, "metric": name, "reason": reason})
            else:
                m.reset()
                active[name] = m
        needs_ref = refs is not None and any(m.needs_reference for m in active.values())
        reads_frames = any(m.reads_frames for m in active.values())
        # A method that renders at its own resolution is scored there, and frames larger than the
        # working resolution are scored downscaled: the scene's frames (and any ground truth) are
        # resized to that size as they are read.
        w, h = self.scored_size(resolution, score_size)
        shrink_preds = (w, h) != preds.size

        def source_frame(k: int) -> np.ndarray:
            def load() -> np.ndarray:
                img = read_rgb8(scene.frames[k].image_path)
                return img if img.shape[1::-1] == (w, h) else resize_rgb8(img, (w, h))

            if share_sources and k < len(self.source_hashes):  # decoded once per process for every unit
                return SOURCE_CACHE.get((self.source_hashes[k], (w, h)), load)
            return load()

        def reference_frame(k: int) -> np.ndarray:
            assert refs is not None
            img = read_rgb8(refs[k])
            return img if img.shape[1::-1] == (w, h) else resize_rgb8(img, (w, h))

        def frames_read() -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]]:
            # the scene frames of a partial sequence are one contiguous run: consecutive predictions are
            # consecutive scene frames, as temporal metrics assume
            for k, pred8 in zip(preds.frame_indices, preds):
                if shrink_preds:
                    pred8 = resize_rgb8(pred8, (w, h))
                ref8 = None
                if needs_ref and self.weather != "clear":
                    ref8 = reference_frame(k)
                yield k, pred8, source_frame(k), ref8

        frames = progress(prefetch(frames_read(), FRAME_BATCH) if reads_frames and prefetch_frames else frames_read(),
                          desc=f"{scene.id} {self.weather}", total=len(preds), enabled=show_progress)
        check = UneditedCheck() if self.check_unedited else None
        # frames are converted straight into reused float32 batch buffers (no per-batch stacking)
        streams = ("pred", "source", "reference") if needs_ref else ("pred", "source")
        buffers = {name: np.empty((FRAME_BATCH, h, w, 3), np.float32) for name in streams}
        filled = 0

        def flush(n: int) -> None:
            if n == 0:
                return
            reference = buffers["reference"][:n] if needs_ref else None
            for m in active.values():
                m.update(buffers["pred"][:n], source=buffers["source"][:n], reference=reference)

        for _, pred8, src8, ref8 in frames:
            to_float(pred8, out=buffers["pred"][filled])
            to_float(src8, out=buffers["source"][filled])
            if check is not None:
                check.update(pred8, src8)
            if needs_ref:
                if ref8 is None:  # clear: the raw frames are the truth
                    buffers["reference"][filled] = buffers["source"][filled]
                else:
                    to_float(ref8, out=buffers["reference"][filled])
            filled += 1
            if filled == FRAME_BATCH:
                flush(filled)
                filled = 0
        flush(filled)
        outputs: dict[str, Any] = {}
        at = f"; scored at {w}x{h}" if (w, h) != scene.image_size and reads_frames else ""
        for name, m in active.items():
            for out_name, value in m.compute().items():
                variant = value.variant + (at if m.reads_frames else "")
                outputs[out_name] = {
                    "metric": name, "value": value.value, "variant": variant, "reason": value.reason,
                    "higher_is_better": m.higher_is_better, "per_frame": value.per_frame, "extra": value.extra,
                }
        result: dict[str, Any] = {"outputs": outputs, "skipped": skipped, "warnings": []}
        warning = None if check is None else check.warning(
            scene=scene.id, weather=self.weather, where=preds.location or preds.files[0],
            hint=self.method.info.unedited_hint)
        if warning is not None:
            result["warnings"].append(warning)
        if preds.missing:
            result["partial"] = {
                "scene": scene.id, "weather": self.weather, "n_scene_frames": len(scene),
                "scored": [preds.frame_indices[0], preds.frame_indices[-1]], "missing": preds.missing,
                "reason": preds.partial_reason,
            }
        if (w, h) != scene.image_size and reads_frames:
            result["working_size"] = {
                "scene": scene.id, "weather": self.weather, "from": list(scene.image_size), "to": [w, h],
                "predictions": list(preds.size), "metric_resolution": resolution,
                "interpolation": SOURCE_INTERPOLATION,
            }
        if preds.native_sizes:
            result["resized"] = {
                "scene": scene.id, "weather": self.weather, "from": sorted(list(s) for s in preds.native_sizes),
                "to": list(scene.image_size), "interpolation": RESIZE_INTERPOLATION,
            }
        safe: dict[str, Any] = json_safe(result)
        return safe


@dataclass
class Scoring:
    """What scoring a unit needs besides the unit: the metrics and where results go.

    Attributes
    ----------
    out : Path
        The results folder (units are kept in ``out/.work/``).
    metrics : dict of str to Metric
    metric_config : dict
        Class and settings of every metric (part of each unit's key and of results.json).
    fps : float, optional
        Frame rate to report when the predictions carry no timings (``--fps``).
    resolution : int, optional
        Metric working resolution (:func:`~wcbench.core.working_size.working_size`); ``None``: native.
    score_size : SizeRequest, optional
        Score at this size instead (``evaluate --scale``).
    prefetch_frames, share_sources : bool
        As :meth:`WorkUnit.score` (off only to measure what they save).
    show_progress : bool
    """

    out: Path
    metrics: dict[str, Metric]
    metric_config: dict[str, Any]
    fps: float | None = None
    resolution: int | None = None
    score_size: SizeRequest | None = None
    prefetch_frames: bool = True
    share_sources: bool = True
    show_progress: bool = True

    def key(self, unit: WorkUnit) -> str:
        """``unit``'s cache key under these settings (:meth:`WorkUnit.key`)."""
        return unit.key(self.metric_config, fps=self.fps, resolution=self.resolution, score_size=self.score_size)


@dataclass
class UnitResult:
    """A unit's scores and whether they were computed now or reused from ``.work``."""

    unit: WorkUnit
    key: str
    result: dict[str, Any]
    computed: bool


def execute_unit(unit: WorkUnit, scoring: Scoring, *, key: str | None = None) -> UnitResult:
    """Score ``unit`` unless its result is already kept under its key; keep the new result atomically.

    Parameters
    ----------
    unit : WorkUnit
        With its predictions opened.
    scoring : Scoring
    key : str, optional
        The unit's key if already computed (:meth:`WorkUnit.key`).
    """
    key = key or scoring.key(unit)
    cached = unit.cached_result(scoring.out, key)
    if cached is not None:
        return UnitResult(unit, key, cached, computed=False)
    result = unit.score(scoring.metrics, fps=scoring.fps, resolution=scoring.resolution, score_size=scoring.score_size,
                        prefetch_frames=scoring.prefetch_frames, share_sources=scoring.share_sources,
                        show_progress=scoring.show_progress)
    atomic_write_json(unit.work_path(scoring.out), {"key": key, "result": result, "checksum": sha256_json(result)})
    return UnitResult(unit, key, result, computed=True)


def render_units(units: Sequence[WorkUnit], settings: RenderSettings) -> list[dict[str, Any]]:
    """Render every unit (resumable; finished folders are left alone); their ``info.json`` contents."""
    return [u.render(settings) for u in units]
