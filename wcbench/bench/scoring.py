"""Scoring speed against error: the metric working resolution and the shared source work.

Cases of ``wcbench bench metrics`` (on ``pandaset_002`` at 1920x1080 when ``--data-root`` holds
it, else the built-in demo street as a stand-in, said in the report):

resolution_<px>     the default metrics over two units, ``clear`` predictions that differ from the raw
                    frames (each raw frame JPEG-compressed at quality 70 and shifted in tone, so
                    that PSNR, SSIM and LPIPS against the raw frames are finite) and ``filter2d``
                    rain, scored with frames downscaled to ``<px>`` on the longer side (``native``:
                    the exact protocol); ``time_ms`` of the whole scoring, ``error`` the largest
                    relative deviation of any output from its native value, per output in
                    ``errors``; ``default`` marks :data:`~wcbench.core.working_size.METRIC_RESOLUTION`
identity_run        ``run --method identity`` scoring (clear, default metrics): the old path
                    (native size, one thread, every frame decoded where it is used, nothing kept
                    between units, every pair computed: ``old_ms``) against the new default (working
                    resolution, worker threads, :data:`~wcbench.units.FRAME_CACHE`, frames equal to
                    their reference given PSNR, SSIM and LPIPS's exact values without the work) in
                    the same run; ``speedup`` and the largest relative deviation.
                    ``identity_run_computed`` is the new default computing every pair: what the rest
                    of the speed-up owes to the other changes
two_weathers        ``evaluate`` of ``filter2d`` rain and snow with only temporal flicker and the flow
                    warping error, old path against new (the second weather reuses the raw
                    frames and their flows)

The flow cache is emptied before every timed scoring, so each starts cold.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from wcbench.bench.schema import BenchCase
from wcbench.core.image_io import read_rgb8
from wcbench.core.parallel import THREADS_ENV
from wcbench.core.working_size import METRIC_RESOLUTION
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.methods import get_method
from wcbench.metrics.registry import DEFAULT_METRICS
from wcbench.metrics.temporal.flicker import FLOW_CACHE
from wcbench.scenes.demo import ensure_demo_scene
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import resolve_scenes
from wcbench.units import FRAME_CACHE, RenderSettings, WorkUnit

__all__ = ["scoring_cases"]

_SCENE_ID = "pandaset_002"
#: Metrics that give a frame equal to its reference their exact value without computing it.
IDENTICAL_SKIPPERS = ("psnr", "ssim", "lpips")
_RESOLUTIONS: tuple[int | None, ...] = (None, 1440, 960, 720, 480)


def _scene(data_root: Path | None) -> tuple[str, Scene, str | None]:
    """(scenes argument, scene, stand-in note or None)."""
    if data_root is not None and (data_root / _SCENE_ID).is_dir():
        spec = str(data_root / _SCENE_ID)
        return spec, resolve_scenes(spec)[0].load(), None
    spec = str(ensure_demo_scene() / "demo_street")
    return spec, resolve_scenes(spec)[0].load(), f"{_SCENE_ID} not found: the demo street (320x180) stood in"


def _degraded_clear(scene: Scene, root: Path, n: int) -> None:
    """``root/<scene>/clear/NNN.png``: each raw frame JPEG-compressed (quality 70) and toned down 5 %."""
    out = root / scene.id / "clear"
    out.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        img = read_rgb8(scene.frames[k].image_path)
        ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 70])
        assert ok
        decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        assert decoded is not None
        back = decoded[..., ::-1].astype(np.float32) * 0.95
        cv2.imwrite(str(out / f"{k:03d}.png"), np.clip(back, 0, 255).astype(np.uint8)[..., ::-1])


def _render(method: str, scene: Scene, weather: str, root: Path) -> None:
    WorkUnit(get_method(method), scene, weather, root / method / scene.id).render(
        RenderSettings(seed=0, show_progress=False, video=False))


@contextmanager
def _threads(n: int | None) -> Iterator[None]:
    """``WCBENCH_THREADS=n`` inside the block (``None``: unchanged)."""
    before = os.environ.get(THREADS_ENV)
    if n is not None:
        os.environ[THREADS_ENV] = str(n)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(THREADS_ENV, None)
        else:
            os.environ[THREADS_ENV] = before


def _score(cfg: EvaluateConfig, *, threads: int | None = None) -> tuple[float, dict[str, float], dict[str, Any]]:
    """Seconds of one cold scoring (the in-process caches emptied first, as in a fresh process) with
    ``threads`` worker threads (default: :func:`~wcbench.core.parallel.thread_count`), its numeric
    outputs by ``weather/output`` and the results document."""
    FLOW_CACHE.clear()
    FRAME_CACHE.clear()
    with _threads(threads):
        t = time.perf_counter()
        doc = evaluate(cfg).results
        seconds = time.perf_counter() - t
    values = {f"{w}/{name}": r["value"] for ws in doc["results"].values() for w, outs in ws.items()
              for name, r in outs.items() if isinstance(r.get("value"), (int, float)) and name != "fps"}
    return seconds, values, doc


def _deviation(new: dict[str, float], old: dict[str, float]) -> tuple[float, dict[str, float]]:
    """Largest and per-output relative deviation of ``new`` from ``old`` (absolute where old is 0)."""
    errors = {}
    for k, v in old.items():
        w = new.get(k)
        if w is None or not (math.isfinite(v) and math.isfinite(w)):
            continue
        errors[k] = abs(w - v) / abs(v) if v else abs(w - v)
    return (max(errors.values()) if errors else 0.0), {k: round(e, 6) for k, e in sorted(errors.items())}


def scoring_cases(*, data_root: Path | None, quick: bool) -> tuple[list[BenchCase], list[str], list[str]]:
    """The cases of the module docstring, notes (metrics skipped) and stand-ins (the demo street
    when ``pandaset_002`` is missing)."""
    spec, scene, stand_in = _scene(data_root)
    notes: list[str] = []
    cases: list[BenchCase] = []
    # a quick run is on the demo street (320x180): 160 px is the only size below its own
    resolutions = (None, 160) if quick else _RESOLUTIONS
    default = 160 if quick else METRIC_RESOLUTION
    with tempfile.TemporaryDirectory(prefix="wcbench-bench-scoring-") as tmp:
        root = Path(tmp)
        _degraded_clear(scene, root / "mixed", len(scene))
        for weather in ("rain", "snow"):
            _render("filter2d", scene, weather, root)
        shutil.copytree(root / "filter2d" / scene.id / "rain", root / "mixed" / scene.id / "rain")

        def config(name: str, method: str, predictions: Path, weathers: list[str], metrics: list[str],
                   resolution: int | None, fast: bool, skip_identical: bool | None = None) -> EvaluateConfig:
            # the old path computes even the frames equal to their reference
            skip = fast if skip_identical is None else skip_identical
            options = {} if skip else {m: {"skip_identical": False} for m in IDENTICAL_SKIPPERS if m in metrics}
            return EvaluateConfig(method=method, scenes=spec, predictions=predictions, out=root / "out" / name,
                                  weathers=weathers, metrics=metrics, metric_resolution=resolution,
                                  prefetch_frames=fast, share_frames=fast, show_progress=False,
                                  metric_options=options)

        metrics = list(DEFAULT_METRICS)
        native: dict[str, float] = {}
        for res in resolutions:
            label = "native" if res is None else str(res)
            seconds, values, doc = _score(config(f"res_{label}", "folder", root / "mixed", ["clear", "rain"],
                                                 metrics, res, True))
            if res is None:
                native = values
                scored = {r["metric"] for ws in doc["results"].values() for outs in ws.values()
                          for r in outs.values()}
                never = sorted(set(metrics) - scored)
                if never:
                    notes.append(f"scoring cases: {', '.join(never)} not scored on any unit (weights not "
                                 "installed or not applicable; `wcbench models list` shows what is installed)")
            worst, errors = _deviation(values, native)
            cases.append(BenchCase(
                name=f"resolution_{label}", knob="metric_resolution", value=label, time_ms=1e3 * seconds,
                error=worst, error_unit="rel", extra={"errors": errors, "default": res == default,
                                                      "frames": len(scene), "size": list(scene.image_size)}))
        runs = [("two_weathers", "filter2d", ["rain", "snow"], ["temporal_flicker", "flow_warping_error"])]
        if not quick:
            _render("identity", scene, "clear", root)
            runs.insert(0, ("identity_run", "identity", ["clear"], metrics))
        for name, method, weathers, chosen in runs:
            old_s, old, _ = _score(config(f"{name}_old", method, root / method, weathers, chosen, None, False),
                                   threads=1)
            new_s, new, _ = _score(config(f"{name}_new", method, root / method, weathers, chosen, default, True))
            worst, errors = _deviation(new, old)
            cases.append(BenchCase(name=name, knob="scoring", value=f"{default} px, threads, shared frames",
                                   time_ms=1e3 * new_s, error=worst, error_unit="rel",
                                   extra={"old_ms": round(1e3 * old_s, 1), "speedup": round(old_s / new_s, 2),
                                          "errors": errors}))
            if name == "identity_run":
                all_s, every, _ = _score(config(f"{name}_computed", method, root / method, weathers, chosen, default,
                                                True, skip_identical=False))
                worst, errors = _deviation(every, old)
                cases.append(BenchCase(name=f"{name}_computed", knob="scoring",
                                       value=f"{default} px, threads, shared frames, every pair computed",
                                       time_ms=1e3 * all_s, error=worst, error_unit="rel",
                                       extra={"old_ms": round(1e3 * old_s, 1), "speedup": round(old_s / all_s, 2),
                                              "errors": errors}))
    return cases, notes, [stand_in] if stand_in else []
