"""What a worker process runs for one unit, from a picklable description (no Dask here).

A distributed run sends every task the run's shared part (:class:`RunShared`: the method, the
metrics, where results go) as pickled bytes with their sha256; a worker unpickles them once and
keeps them, so a method that holds a trained model between the weathers of a scene (and metrics
that hold their network) keeps it across tasks, as in a local run. A worker runs one unit at a
time (:data:`_ONE_AT_A_TIME`): methods and metrics keep state between calls.
"""

from __future__ import annotations

import hashlib
import pickle
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.storage import sha256_json
from wcbench.core.working_size import SizeRequest
from wcbench.methods import Method, is_runnable
from wcbench.metrics.base import Metric
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import SceneRef
from wcbench.units import RenderSettings, Scoring, WorkUnit, execute_unit

__all__ = ["RunShared", "UnitSpec", "empty_task", "pack", "render_task", "score_task", "setup_scene_task", "spec_of"]

_ONE_AT_A_TIME = threading.Lock()
_SHARED: dict[str, RunShared] = {}  # sha256 of the pickled bytes -> the unpickled run
_SCENES: dict[str, Scene] = {}


@dataclass
class RunShared:
    """What every unit of one run shares.

    Attributes
    ----------
    method : Method
    metrics : dict of str to Metric
    metric_config : dict
        Class and settings of every metric (part of each unit's key).
    out : Path, optional
        The results folder (absolute: workers may run elsewhere); scoring only.
    fps : float, optional
    render : RenderSettings, optional
        Rendering only.
    resolution : int, optional
        Metric working resolution; ``None``: native.
    score_size : SizeRequest, optional
        The size to score at (``evaluate --scale``).
    """

    method: Method | None
    metrics: dict[str, Metric]
    metric_config: dict[str, Any]
    out: Path | None = None
    fps: float | None = None
    render: RenderSettings | None = None
    resolution: int | None = None
    score_size: SizeRequest | None = None


@dataclass(frozen=True)
class UnitSpec:
    """One unit as a worker rebuilds it: the scene's reference, not the loaded scene.

    Attributes
    ----------
    label : str
        ``<method> <scene> <weather>``.
    scene : SceneRef
    weather : str
    root : Path
        The scene's predictions folder (absolute).
    source_hashes : tuple of str
    check_unedited : bool
    open_options : dict, optional
        How the client opened the unit (scoring); ``None`` when rendering.
    key : str, optional
        The unit's key as the client computed it (scoring).
    """

    label: str
    scene: SceneRef
    weather: str
    root: Path
    source_hashes: tuple[str, ...]
    check_unedited: bool
    open_options: dict[str, Any] | None = None
    key: str | None = None


def pack(shared: RunShared) -> tuple[bytes, str]:
    """``shared`` pickled once on the client, with the sha256 workers keep it under."""
    data = pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL)
    return data, hashlib.sha256(data).hexdigest()


def spec_of(unit: WorkUnit, *, key: str | None = None) -> UnitSpec:
    """The description of ``unit`` a worker rebuilds it from.

    Raises
    ------
    ValueError
        The unit carries no scene reference (units planned by :func:`wcbench.evaluation.evaluate` do).
    """
    if unit.scene_ref is None:
        raise ValueError(f"{unit.label}: no scene reference; another process cannot load its scene")
    return UnitSpec(label=unit.label, scene=unit.scene_ref, weather=unit.weather, root=unit.root.resolve(),
                    source_hashes=tuple(unit.source_hashes), check_unedited=unit.check_unedited,
                    open_options=unit.open_options, key=key)


def _shared(data: bytes, digest: str) -> RunShared:
    if digest not in _SHARED:
        if hashlib.sha256(data).hexdigest() != digest:
            raise RuntimeError("the run's shared part arrived damaged (sha256 differs)")
        while len(_SHARED) >= 2:  # a run's render and score parts; older runs' models are dropped
            del _SHARED[next(iter(_SHARED))]
        _SHARED[digest] = pickle.loads(data)  # bytes this run's client pickled itself (sha256 checked)
    return _SHARED[digest]


def _scene(ref: SceneRef) -> Scene:
    key = sha256_json({"id": ref.id, "format": ref.format, "path": str(ref.path), "options": ref.options})
    if key not in _SCENES:
        _SCENES[key] = ref.load()
    return _SCENES[key]


def _unit(shared: RunShared, spec: UnitSpec) -> WorkUnit:
    if shared.method is None:
        raise RuntimeError(f"{spec.label}: a task of a run without a method")
    return WorkUnit(shared.method, _scene(spec.scene), spec.weather, spec.root, list(spec.source_hashes),
                    check_unedited=spec.check_unedited, scene_ref=spec.scene)


def setup_scene_task(data: bytes, digest: str, scene: SceneRef) -> float:
    """The method's scene-level work (training) for ``scene``; its seconds."""
    with _ONE_AT_A_TIME:
        shared, start = _shared(data, digest), time.perf_counter()
        if shared.method is not None and is_runnable(shared.method):
            shared.method.setup_scene(_scene(scene), show_progress=False)  # type: ignore[attr-defined]
        return time.perf_counter() - start


def render_task(data: bytes, digest: str, spec: UnitSpec, after: object = None) -> str:
    """Render one unit (``after``: the scene's set-up task, a dependency only); its status."""
    with _ONE_AT_A_TIME:
        shared = _shared(data, digest)
        if shared.render is None:
            raise RuntimeError("render_task of a run without render settings")
        info = _unit(shared, spec).render(shared.render)
        return str(info["status"])


def score_task(data: bytes, digest: str, spec: UnitSpec) -> dict[str, Any]:
    """Score one unit into ``OUT/.work`` unless kept there: ``{"key", "computed", "seconds"}``.

    Raises
    ------
    InputError
        The unit's files changed since the client planned it (its key differs), or bad input.
    """
    with _ONE_AT_A_TIME:
        shared, start = _shared(data, digest), time.perf_counter()
        if shared.out is None:
            raise RuntimeError("score_task of a run without a results folder")
        unit = _unit(shared, spec)
        unit.open(**(spec.open_options or {}))
        scoring = Scoring(shared.out, shared.metrics, shared.metric_config, fps=shared.fps,
                          resolution=shared.resolution, score_size=shared.score_size, show_progress=False)
        key = scoring.key(unit)
        if key != spec.key:
            raise InputError(f"{unit.label}: its files changed since the run was planned (or this worker sees "
                             f"other files under {spec.root}); run again")
        if unit.cached_result(shared.out, key) is None:
            unit.validate(size=unit.scored_size(scoring.resolution, scoring.score_size), keep=True,
                          show_progress=False)
        outcome = execute_unit(unit, scoring, key=key)
        return {"key": key, "computed": outcome.computed, "seconds": time.perf_counter() - start}


def empty_task(data: bytes, digest: str, spec: UnitSpec) -> dict[str, Any]:
    """A unit that does no work: what the distributed path costs by itself (``wcbench bench scale``)."""
    with _ONE_AT_A_TIME:
        _shared(data, digest)
        return {"key": spec.key, "computed": False, "seconds": 0.0}
