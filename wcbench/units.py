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

import copy
import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.byte_cache import ByteBudgetCache
from wcbench.core.errors import InputError
from wcbench.core.image_io import read_mask, read_rgb8, resize_mask, resize_rgb8, to_float
from wcbench.core.parallel import ordered_map, prefetch, thread_count
from wcbench.core.progress import progress
from wcbench.core.storage import atomic_write_json, json_safe, sha256_file, sha256_json
from wcbench.core.working_size import SizeRequest, working_size
from wcbench.methods import Method, is_runnable
from wcbench.metrics.base import Metric, MetricContext
from wcbench.predictions import RESIZE_INTERPOLATION, PredictionSequence
from wcbench.results import SCHEMA_VERSION
from wcbench.scenes.scene import EditTruth, Scene
from wcbench.scenes.sets import SceneRef
from wcbench.unedited import UNEDITED_LEVELS, UNEDITED_THUMB_WIDTH, UneditedCheck

#: How frames are brought to the size scored at, the scene's and (rendered at another size) the
#: method's (see :func:`wcbench.core.image_io.resize_rgb8`), recorded with every such result.
SOURCE_INTERPOLATION = "area (cv2.INTER_AREA) when shrinking, bicubic when enlarging"
#: Which size a unit is scored at when none is asked for: the scene's working size
#: (:func:`~wcbench.core.working_size.working_size` of the scene's frame size), whatever size the
#: method rendered at, so that every method of a scene is scored at one size, as the paper scores
#: every method at the dataset's frames (docs/design.md §8, "Scoring"). Part of every unit's key:
#: results scored under an earlier rule (a method at its own render size) are never reused.
SCORING_RULE = "scene working size"
#: Folder of ``OUT`` holding one finished result per unit.
WORK_DIR = ".work"
#: Frames handed to metrics per update: model metrics batch their inference; 8 frames of 1080p
#: in three float32 streams stay under 0.6 GB.
FRAME_BATCH = 8
#: Bytes of decoded frames kept in memory across the units of a process: the raw frames are read
#: once for a scene's weathers and methods, and predictions decoded by the check before scoring are
#: scored from memory.
FRAME_CACHE_BYTES = 1 << 30
#: Decoded (and resized) frames: ``("source", sha256, size)`` and ``("prediction", unit folder,
#: weather, *frame key, scene size, size)``; predictions are taken out once scored.
FRAME_CACHE: ByteBudgetCache[np.ndarray] = ByteBudgetCache(FRAME_CACHE_BYTES)
#: Share of :data:`FRAME_CACHE` that predictions decoded ahead of scoring may fill, so that the
#: raw frames of the unit being scored never push out predictions still to be scored.
AHEAD_SHARE = 0.5


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
    def edits(self) -> list[Any]:
        """The object edits the predictions were rendered with (``info.json`` ``parameters.edits``,
        in ``--edit``'s JSON form), ``[]`` when none."""
        info = self._opened().info
        params = info.get("parameters") if isinstance(info, dict) else None
        edits = params.get("edits") if isinstance(params, dict) else None
        return edits if isinstance(edits, list) else []

    @property
    def edit_truth(self) -> EditTruth | None:
        """The scene's editing truth of exactly the predictions' :attr:`edits`, or ``None``."""
        return self.scene.edit_truth(self.edits) if self.edits else None

    @property
    def reference_paths(self) -> list[Path] | None:
        """Ground-truth frames of this weather (of the predictions' edits when the scene has an
        editing truth for them), or ``None`` when the scene has none."""
        truth = self.edit_truth
        if truth is not None:
            return truth.references.get(self.weather)
        return self.scene.reference_paths(self.weather)

    def inputs(self) -> dict[str, Any]:
        """sha256 of every input frame (``predictions``, ``source``, ``reference`` or ``None``, and
        with an editing truth its masks, ``edit_masks``) and
        where the predictions were found (``location``, ``layout``, scored ``frames``, ``ignored``, and
        when there are any, frames beyond the scene and lower steps left out: see
        :meth:`PredictionSequence.left_out`)."""
        refs, truth = self.reference_paths, self.edit_truth
        if refs is None:
            ref_hashes = None
        elif self.weather == "clear" and truth is None:
            ref_hashes = self.source_hashes  # the raw frames are the truth of clear
        else:
            ref_hashes = [sha256_file(p) for p in refs]
        p = self._opened()
        masks = {} if truth is None else {"edit_masks": [sha256_file(m) for m in truth.masks]}
        return {"predictions": p.sha256s(), "source": self.source_hashes, "reference": ref_hashes, **masks,
                "info": None if p.info is None else sha256_json(p.info),
                "location": str(p.location) if p.location else None, "layout": p.layout,
                "frames": p.frame_indices, "ignored": p.ignored, **p.left_out()}

    def scored_size(self, resolution: int | None, score_size: SizeRequest | None = None) -> tuple[int, int]:
        """(width, height) the frames are scored at: ``score_size`` when given, else the scene's
        working size (:data:`SCORING_RULE`): the scene's frame size within the working
        ``resolution``, the same for every method of the scene whatever size it rendered at."""
        if score_size is not None:
            return score_size.resolve(self.scene.image_size)
        return working_size(self.scene.image_size, resolution)

    def key(self, metric_config: dict[str, Any], *, fps: float | None = None, resolution: int | None = None,
            score_size: SizeRequest | None = None) -> str:
        """Cache key of this unit's result: every input that can change a number (each frame's
        sha256, the predictions' ``info.json`` with its timings, the ``--fps`` given, the metric
        settings, the size scored at, the rule that chose it and the results schema)."""
        inputs, p = self.inputs(), self._opened()
        return sha256_json({
            "schema_version": SCHEMA_VERSION, "scoring": SCORING_RULE, "scene": self.scene.id, "weather": self.weather,
            "info": p.info, "fps": fps, "working_size": list(self.scored_size(resolution, score_size)),
            "predictions": inputs["predictions"], "source": inputs["source"], "reference": inputs["reference"],
            # an edited run's region scores (the keys of unedited runs stay as they were)
            **({"edits": [self.edits, inputs.get("edit_masks")]} if self.edits else {}),
            "metrics": metric_config, "resize": p.resize, "interpolation": RESIZE_INTERPOLATION if p.resize else None,
            "size": list(p.size),
            "frames": p.frame_indices, "missing": p.missing, "partial_reason": p.partial_reason,
            "check_unedited": [self.check_unedited, UNEDITED_LEVELS, UNEDITED_THUMB_WIDTH],
            "raw_frames": True,  # results carry the raw frames' scores against the truth (older ones do not)
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

    def _prediction_key(self, key: tuple[str, ...], size: tuple[int, int]) -> tuple[Any, ...]:
        """:data:`FRAME_CACHE` key of a prediction of this unit (frame key, see
        :meth:`PredictionSequence.frame_keys`) brought to the scene's size then to ``size``. The unit
        is part of it: two units with equal files each take their own copy once."""
        return ("prediction", str(self.root), self.weather, *key, self._opened().size, size)

    def _predictions_at(self, size: tuple[int, int], *, workers: int) -> Iterator[np.ndarray]:
        """Every prediction in order, uint8 at ``size``: image files decoded by ``workers`` threads,
        a video read in order (by a background thread when ``workers`` > 1)."""
        preds = self._opened()

        def fit(img: np.ndarray) -> np.ndarray:
            return img if img.shape[1::-1] == size else resize_rgb8(img, size)

        if preds.is_video:
            frames = (fit(img) for img in preds)
            yield from (prefetch(frames, FRAME_BATCH) if workers > 1 else frames)
        else:
            yield from ordered_map(lambda i: fit(preds.read_frame(i)), range(len(preds)), workers=workers,
                                   depth=FRAME_BATCH)

    def validate(self, *, size: tuple[int, int] | None = None, keep: bool = False, workers: int | None = None,
                 show_progress: bool = True) -> None:
        """Decode every prediction once (size, bit depth, video length), so bad input fails before work starts.

        Parameters
        ----------
        size : (int, int), optional
            (width, height) the unit will be scored at (:meth:`scored_size`).
        keep : bool
            Keep the decoded predictions, brought to ``size``, in :data:`FRAME_CACHE` (up to
            :data:`AHEAD_SHARE` of its budget) so that :meth:`score` does not decode them again.
        workers : int, optional
            Decoding threads (default :func:`~wcbench.core.parallel.thread_count`).
        show_progress : bool
        """
        preds = self._opened()
        target = size if keep and size is not None else preds.size
        keys = [self._prediction_key(k, target) for k in preds.frame_keys()] if keep else None
        limit = int(AHEAD_SHARE * FRAME_CACHE.budget)
        frames = self._predictions_at(target, workers=thread_count() if workers is None else workers)
        for i, img in enumerate(progress(frames, desc=f"checking {self.scene.id} {self.weather}", total=len(preds),
                                         enabled=show_progress)):
            if keys is not None:
                FRAME_CACHE.put(keys[i], img, fill_limit=limit)

    def score(self, metrics: dict[str, Metric], *, fps: float | None = None, resolution: int | None = None,
              score_size: SizeRequest | None = None, prefetch_frames: bool = True, share_frames: bool = True,
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
            Decode (and resize) frames in worker threads (:func:`~wcbench.core.parallel.thread_count`)
            while the metrics run.
        share_frames : bool
            Use :data:`FRAME_CACHE`: the decoded raw frames are kept for the scene's other units, and
            predictions kept by :meth:`validate` are scored from memory.

        Returns
        -------
        dict
            ``{"outputs": {output: record}, "skipped": [{"scene", "weather", "metric", "reason"}]}``,
            JSON-safe (non-finite values as ``None``).
        """
        scene, preds = self.scene, self._opened()
        refs, truth = self.reference_paths, self.edit_truth
        # the raw frames are the truth of clear, unless the frames were edited and the scene has
        # their editing truth (docs/design.md §3)
        source_is_truth = self.weather == "clear" and truth is None
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
        # The raw frames scored against the same truth, the yardstick of the ground-truth table (docs/guide.md,
        # "The report"): a shallow copy of each reference metric (its reset() gives fresh accumulators, the
        # weights stay shared) fed the source frames in the same pass, so no frame is read twice. Clear has
        # no such row: its truth is the raw frames.
        baseline: dict[str, Metric] = {}
        if needs_ref and not source_is_truth:
            for name, m in active.items():
                if m.needs_reference:
                    baseline[name] = copy.copy(m)
                    baseline[name].reset()
        # Edited frames are also scored on the edited region alone, against the editing truth;
        # without one the region scores say why they are missing.
        region: dict[str, Metric] = {}
        for name, m in active.items():
            if not (self.edits and m.needs_reference):
                continue
            if truth is None or not needs_ref:
                skipped.append({"scene": scene.id, "weather": self.weather, "metric": f"{name} (edit region)",
                                "reason": "no editing truth for this edit"})
            else:
                region[name] = copy.copy(m)
                region[name].reset()
        reads_frames = any(m.reads_frames for m in active.values())
        # Every method of a scene is scored at one size, the scene's working size (the paper scores
        # every method at the dataset's frames; docs/design.md §8, "Scoring"): frames a method
        # rendered at another size are resized to it, up or down, and so are the scene's frames (and
        # any ground truth) when the working resolution is below their size, as they are read.
        w, h = self.scored_size(resolution, score_size)
        workers = thread_count() if prefetch_frames else 1

        def fit(img: np.ndarray) -> np.ndarray:
            return img if img.shape[1::-1] == (w, h) else resize_rgb8(img, (w, h))

        def source_frame(k: int) -> np.ndarray:
            def load() -> np.ndarray:
                return fit(read_rgb8(scene.frames[k].image_path))

            if share_frames and k < len(self.source_hashes):  # decoded once per process for every unit
                return FRAME_CACHE.get(("source", self.source_hashes[k], (w, h)), load)
            return load()

        def others(j: int) -> tuple[np.ndarray, np.ndarray | None]:
            # the scene frames of a partial sequence are one contiguous run: consecutive predictions are
            # consecutive scene frames, as temporal metrics assume
            k = preds.frame_indices[j]
            ref8 = fit(read_rgb8(refs[k])) if refs is not None and needs_ref and not source_is_truth else None
            return source_frame(k), ref8

        def region_mask(j: int) -> np.ndarray:
            assert truth is not None
            mask = read_mask(truth.masks[preds.frame_indices[j]])
            return mask if mask.shape[::-1] == (w, h) else resize_mask(mask, (w, h))

        kept: list[np.ndarray | None] = [None] * len(preds)
        if share_frames:  # decoded by validate(): scored from memory, then dropped
            kept = [FRAME_CACHE.take(self._prediction_key(key, (w, h))) for key in preds.frame_keys()]

        def frames_read() -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
            if preds.is_video and not all(p is not None for p in kept):
                # a video is decoded in order; the raw frames are read by worker threads beside it
                for pred8, (src8, ref8) in zip(self._predictions_at((w, h), workers=workers),
                                               ordered_map(others, range(len(preds)), workers=workers,
                                                           depth=FRAME_BATCH)):
                    yield pred8, src8, ref8
                return

            def item(j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
                pred8 = kept[j]
                if pred8 is None:
                    pred8 = fit(preds.read_frame(j))
                return (pred8, *others(j))

            yield from ordered_map(item, range(len(preds)), workers=workers, depth=FRAME_BATCH)

        check = UneditedCheck() if self.check_unedited else None
        frames = progress(frames_read() if reads_frames or check is not None else iter(()),
                          desc=f"{scene.id} {self.weather}", total=len(preds), enabled=show_progress)
        # frames are converted straight into reused float32 batch buffers (no per-batch stacking)
        streams = ("pred", "source", "reference") if needs_ref else ("pred", "source")
        buffers = {name: np.empty((FRAME_BATCH, h, w, 3), np.float32) for name in streams}
        masks = np.zeros((FRAME_BATCH, h, w), bool)
        filled, seen = 0, 0

        def flush(n: int) -> None:
            if n == 0:
                return
            reference = buffers["reference"][:n] if needs_ref else None
            for m in active.values():
                m.update(buffers["pred"][:n], source=buffers["source"][:n], reference=reference)
            for m in baseline.values():
                m.update(buffers["source"][:n], source=buffers["source"][:n], reference=reference)
            for m in region.values():
                assert reference is not None
                m.update_region(buffers["pred"][:n], source=buffers["source"][:n], reference=reference,
                                mask=masks[:n])

        for pred8, src8, ref8 in frames:
            to_float(pred8, out=buffers["pred"][filled])
            to_float(src8, out=buffers["source"][filled])
            if check is not None:
                check.update(pred8, src8)
            if needs_ref:
                if ref8 is None:  # clear: the raw frames are the truth
                    buffers["reference"][filled] = buffers["source"][filled]
                else:
                    to_float(ref8, out=buffers["reference"][filled])
            if region:
                masks[filled] = region_mask(seen)
            filled += 1
            seen += 1
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
        for name, m in region.items():
            for out_name, value in m.compute().items():
                outputs[f"{out_name}_edit_region"] = {
                    "metric": name, "value": value.value, "variant": f"{value.variant}; {m.region_variant}{at}",
                    "reason": value.reason, "higher_is_better": m.higher_is_better, "per_frame": value.per_frame,
                    "extra": value.extra,
                }
        result: dict[str, Any] = {"outputs": outputs, "skipped": skipped, "warnings": []}
        if truth is not None:
            result["edit_truth"] = {"scene": scene.id, "weather": self.weather, "name": truth.name,
                                    "edit": truth.edit}
        if baseline:
            result["raw_frames"] = {
                out_name: {"metric": name, "value": value.value, "variant": value.variant + at, "reason": value.reason,
                           "higher_is_better": m.higher_is_better}
                for name, m in baseline.items() for out_name, value in m.compute().items()}
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
        if reads_frames and ((w, h) != scene.image_size or (w, h) != preds.size):
            result["working_size"] = {
                "scene": scene.id, "weather": self.weather, "from": list(scene.image_size), "to": [w, h],
                "predictions": list(preds.size), "predictions_resized": (w, h) != preds.size,
                "metric_resolution": resolution, "rule": SCORING_RULE if score_size is None else "asked",
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
    prefetch_frames, share_frames : bool
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
    share_frames: bool = True
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
                        prefetch_frames=scoring.prefetch_frames, share_frames=scoring.share_frames,
                        show_progress=scoring.show_progress)
    atomic_write_json(unit.work_path(scoring.out), {"key": key, "result": result, "checksum": sha256_json(result)})
    return UnitResult(unit, key, result, computed=True)


def render_units(units: Sequence[WorkUnit], settings: RenderSettings) -> list[dict[str, Any]]:
    """Render every unit (resumable; finished folders are left alone); their ``info.json`` contents."""
    return [u.render(settings) for u in units]
