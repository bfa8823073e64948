"""Benchmark suite ``model``: WeatherCity training time against held-out quality, and render speed.

On ``pandaset_002`` at 480x270 (the demo street when the data is absent) with frames 5, 15 and 25
held out, every case reports the held-out raw PSNR (mean of the held-out frames, dB; ``error``),
the PSNR inside moving-object masks (``dynamic_psnr``), its training's wall time (``time_ms``) and
the whole-frame render speed of what it trained (``fps_rain_fog``: ``paper`` rain with exact fog at
the training size; scene graph, decoders, sky, particles, rasterizer and fog all timed; median
over frames):

weathercity           the ``default`` profile trained to its end (all losses, all weathers every
                      ``weather_interval`` steps, densification under the budget, the centres' rate
                      decayed); ``psnr_half``: the held-out PSNR at half its steps
plain                 the calibration baseline (:mod:`~wcbench.reference_model.training.plain`):
                      Adam + L1 on the static Gaussians of the lidar initialisation, no densification,
                      for **the same wall clock** as ``weathercity`` took, in the same run
weathercity_half      the default profile on half the iterations (its schedule scaled, see
                      :meth:`~wcbench.reference_model.training.config.TrainConfig.scaled`)
<knob>_<value>        the half-iterations default with one setting changed: content loss weight,
                      interval and resolution, weather interval, decoder width (the paper's 64),
                      densification threshold, Gaussian budget, initial voxel and opacity, sky map,
                      the centres' rate decay, far points; ``psnr_vs_default`` against
                      ``weathercity_half``; ``pareto``: on the Pareto front of the half-iteration
                      rows over wall time, held-out PSNR, FPS and ``content_distance`` (the content
                      loss of the edited weathers' held-out renders against the raw frames: what
                      the content loss is for, which raw PSNR cannot see)
one_pass_vs_per_weather
                      forward + backward of one training render of every weather as stacked channels
                      against one pass per weather; ``error``: largest difference of the images
temporal_<weather>    weathercity trained on ``filter2d`` supervision with ``jitter`` 0.5 (seeded per-frame
                      tone, colour and structure perturbations, as frame-by-frame editors flicker):
                      ``error`` is the flow warping error (flow and occlusion mask from the raw
                      sequence) of its renders of every frame (decoded weather, no particles, no
                      physics fog), against ``supervision_error`` of the jittered frames it learnt
                      from and ``raw_error`` of the raw sequence itself
profile_step          the per-phase profile of a training step of the default profile at each thread
                      count of ``threads`` (numba, torch and BLAS set together; default 1,2), rounds
                      interleaving the counts, each the mean over one period of the step schedule
                      (weather and clear steps, one content-loss step): data, scene graph,
                      decoders, sky, the rasterizer's forward and backward, losses, the rest of
                      the backward, densification
                      statistics, optimizer, densification (one per ``densify_interval`` steps,
                      amortised), and ``non_raster`` (everything but the rasterizer); per phase the
                      speed-up from the first count to the second, its Amdahl serial fraction and a
                      *projected* 16-thread speed-up (docs/design.md §8)
render_rain           whole frames of the trained default model under the default rain preset at the
                      training size, interleaved frame by frame in one run: ``image``, the render as
                      it runs (``render_frame``: every node in fixed rows, only the moving nodes' rows
                      written per frame, composited by the inference-only ``rasterize_image``);
                      ``new``, the same rows through the training rasterizer; ``old``, the baseline
                      (``render_frame_concat``: the frame's nodes concatenated afresh, training
                      rasterizer); and ``lidar-init``'s frame of the same weather beside them: per
                      path the FPS and the median ms of each stage (scene graph, particles,
                      rasterizer, fog, the whole ``render_frame``, and writing the PNG),
                      ``fps_ratio`` (old frame time / new), ``image_fps_ratio`` (new / image) and
                      ``image_vs_old_fps_ratio`` (old / image); ``time_ms`` is the image path's;
                      ``error``: the largest difference of the uint8 frames of new against old and
                      of image against new (``error_new_old_uint8``, ``error_image_new_uint8``)
skip_<what>           what a skip of the scene graph saves: the median time of a training step of a
                      model built with the skip (``time_ms``) and without it (``without_ms``):
                      dropping Gaussians outside every training frustum, keeping tracks that do not
                      move in the background (not the default: it leaves them uneditable), and not
                      training a weather without supervision

``error`` is the held-out PSNR (dB, higher is better): this suite reports quality, not a deviation.
Set ``WCBENCH_BENCH_MODEL_GROUPS`` to run some of the groups
``headline,temporal,knobs,skips,profile,render`` (default all; the headline and the temporal group
each train the default profile, the render group renders the headline's model or, without the
headline, trains one the same way; the knobs take about 4 minutes each), and
``WCBENCH_BENCH_MODEL_KNOBS`` to a comma-separated list of knob case names to run only those.
"""

from __future__ import annotations

import copy
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from wcbench.bench.overview import pareto_flags
from wcbench.bench.phases import parse_threads, phase_table, run_interleaved
from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.core.errors import InputError
from wcbench.methods.scene_training import content_loss_for, training_inputs
from wcbench.methods.weathercity import WeatherCityMethod
from wcbench.metrics.temporal.flicker import flow_warping_error
from wcbench.reference_model.model.haze import Haze
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.threads import get_threads
from wcbench.reference_model.raster.threads import threads as thread_count
from wcbench.reference_model.scene_graph.lidar_init import LidarInitOptions, estimate_sky_color, init_scene_from_lidar
from wcbench.reference_model.training.build import build_model
from wcbench.reference_model.training.config import TrainConfig, make_config
from wcbench.reference_model.training.losses import ContentLoss
from wcbench.reference_model.training.plain import PlainOptimisation
from wcbench.reference_model.training.trainer import Trainer, evaluate_views
from wcbench.reference_model.training.views import TrainingView
from wcbench.reference_model.weather.conditions import Weather
from wcbench.scenes.demo import ensure_demo_scene
from wcbench.scenes.loaders import load_scene
from wcbench.scenes.scene import Scene

__all__ = ["run"]

_SCENE_ID = "pandaset_002"
#: The case groups of ``WCBENCH_BENCH_MODEL_GROUPS`` (default all).
GROUPS = ("headline", "temporal", "knobs", "skips", "profile", "render")
_HOLDOUT = (5, 15, 25)
#: (case name, knob, value, settings changed from the default profile)
_KNOBS: list[tuple[str, str, Any, dict[str, Any]]] = [
    ("content_interval_2", "content_interval", 2, {"content_interval": 2}),
    ("content_interval_8", "content_interval", 8, {"content_interval": 8}),
    ("content_size_120x68", "content_size", "120x68", {"content_size": (120, 68)}),
    ("content_weight_1", "content_weight", 1.0, {"content_weight": 1.0}),
    ("no_content_loss", "content_weight", 0.0, {"content_weight": 0.0}),
    ("weather_interval_8", "weather_interval", 8, {"weather_interval": 8}),
    ("weather_interval_16", "weather_interval", 16, {"weather_interval": 16}),
    ("weather_weight_0.5", "weather_weight", 0.5, {"weather_weight": 0.5}),
    ("hidden_64", "hidden", 64, {"hidden": 64}),
    ("densify_grad_4e-4", "densify_grad", 4e-4, {"densify_grad": 4e-4}),
    ("densify_grad_1.6e-3", "densify_grad", 1.6e-3, {"densify_grad": 1.6e-3}),
    ("budget_100k", "budget", 100_000, {"budget": 100_000}),
    ("budget_300k", "budget", 300_000, {"budget": 300_000}),
    ("voxel_0.15", "voxel_m", 0.15, {"voxel_m": 0.15, "node_voxel_m": 0.08}),
    ("init_opacity_0.5", "init_opacity", 0.5, {"init_opacity": 0.5}),
    ("sky_whole_sphere", "sky_window", False, {"sky_window": False, "sky_map": (32, 128)}),
    ("means_lr_decay_0.01", "means_lr_final", 0.01, {"means_lr_final": 0.01}),
    ("no_far_points", "far_points", False, {"far_points": False}),
]


#: The share of the ``quick`` profile's iterations a ``--quick`` run trains (its smoke test runs in CI).
_QUICK_FRACTION = 0.5


def _scene(data_root: Path | None) -> tuple[Scene, str]:
    if data_root is not None and (data_root / _SCENE_ID).is_dir():
        return load_scene(data_root / _SCENE_ID, scene_id=_SCENE_ID), _SCENE_ID
    return load_scene(ensure_demo_scene() / "demo_street"), f"demo street ({_SCENE_ID} not found)"


def _timed_training(step: Callable[[], Any], marks: list[float],
                    evaluate: Callable[[], dict[str, Any]]) -> tuple[dict[float, dict[str, Any]], int, float]:
    """Step until the last of ``marks`` (seconds of the training's own wall clock), evaluating (off
    the clock) at each mark; returns the evaluations by mark, the steps and the seconds spent."""
    out, steps, spent = {}, 0, 0.0
    for mark in sorted(marks):
        while spent < mark:
            t = time.perf_counter()
            step()
            spent += time.perf_counter() - t
            steps += 1
        out[mark] = {**evaluate(), "steps": steps}
    return out, steps, spent


def _fps_rain_fog(scene: Scene, model: Any, config: TrainConfig, facts: dict[str, Any]) -> dict[str, Any]:
    """Whole-frame render time of ``paper`` rain with exact fog (200 m visibility), median over frames."""
    rain = Weather(kind="rain", preset="paper", visibility_m=200.0, fog_mode="exact")
    method = WeatherCityMethod(physics={"rain": rain})
    method.config = config
    method.use_model(scene, model, facts)
    method.prepare(scene, "rain", seed=0)
    times, stages = [], []
    frames = list(range(0, len(scene), max(1, len(scene) // 10)))
    method.render_frame(scene, "rain", frames[0], seed=0)  # warm-up (kernels compiled, caches filled)
    for k in frames:
        t = time.perf_counter()
        _, info = method.render_frame(scene, "rain", k, seed=0)
        times.append(time.perf_counter() - t)
        stages.append(info.get("timings_ms", {}))
    ms = 1e3 * statistics.median(times)
    keys = sorted({k for s in stages for k in s})
    return {"fps_rain_fog": round(1e3 / ms, 2), "frame_ms": round(ms, 1),
            **{f"stage_{k}_ms": round(statistics.median(s.get(k, 0.0) for s in stages), 1) for k in keys}}


#: Stages of a whole frame (``render_frame``'s ``timings_ms``, and the PNG the runner writes).
RENDER_STAGES = ("scene_graph", "particles", "raster", "fog", "total", "write_png")


def _recording(rasterizer: Callable[..., Any], phases: dict[str, dict[str, float]], name: str) -> Callable[..., Any]:
    """``rasterizer`` that keeps the ``phase_ms`` of its last call in ``phases[name]``."""

    def call(*args: Any, **kwargs: Any) -> Any:
        out = rasterizer(*args, **kwargs)
        phases[name] = dict(out.meta.get("phase_ms", {}))
        return out

    return call


def _render_case(scene: Scene, model: Any, config: TrainConfig, facts: dict[str, Any], *, frames: int,
                 folder: Path) -> BenchCase:
    """Whole frames of default rain at the training size, three ways interleaved frame by frame in
    one process: ``image``, what a render runs (``render_frame``: the fixed rows of
    :class:`~wcbench.reference_model.model.scene_model.FrameRows`, composited by the inference-only
    :func:`~wcbench.reference_model.raster.rasterizer.rasterize_image`); ``new``, the same rows
    through the training rasterizer ``rasterize`` (the render before the inference kernel);
    ``old``, the baseline, ``render_frame_concat`` (the frame's nodes concatenated afresh) through
    ``rasterize``; and lidar-init's frame of the same weather and size beside them. ``error``: the
    largest difference of the uint8 frames of ``new`` against ``old`` and of ``image`` against
    ``new``."""
    from wcbench.core.image_io import write_png
    from wcbench.methods.lidar_init import LidarInitMethod
    from wcbench.reference_model.raster.rasterizer import rasterize

    width, height = config.size_for(scene.image_size)
    rain = Weather(kind="rain")
    methods = {}
    for name in ("image", "new", "old"):  # one method each: the twin's frames would make the new one copy its rows
        method = WeatherCityMethod(physics={"rain": rain}, size=(width, height))
        method.config = config
        method.use_model(scene, model, facts)
        method.prepare(scene, "rain", seed=0)
        methods[name] = method
    for name in ("new", "old"):  # the training rasterizer, as every render used before the image kernel
        renderer = methods[name]._renderer
        assert renderer is not None
        renderer.rasterizer = rasterize
    lidar = LidarInitMethod(physics={"rain": rain}, size=(width, height))
    lidar.prepare(scene, "rain", seed=0)
    paths = {"image": methods["image"].render_frame, "new": methods["new"].render_frame,
             "old": methods["old"].render_frame_concat, "lidar_init": lidar.render_frame}
    # the rasterizer's own phases (projection, sort, binning, blending) of each path's last frame
    phases: dict[str, dict[str, float]] = {}
    for name, renderer in (*((n, m._renderer) for n, m in methods.items()), ("lidar_init", lidar._renderer)):
        assert renderer is not None
        renderer.rasterizer = _recording(renderer.rasterizer, phases, name)
    picked = list(range(0, len(scene), max(1, len(scene) // frames)))[:frames]
    for render in paths.values():  # warm-up (kernels compiled, caches filled)
        render(scene, "rain", picked[0], seed=0)
    stages: dict[str, list[dict[str, float]]] = {name: [] for name in paths}
    worst = {"new_old": 0, "image_new": 0}
    for k in picked:
        images = {}
        for name, render in paths.items():
            t = time.perf_counter()
            img, info = render(scene, "rain", k, seed=0)
            frame_ms = 1e3 * (time.perf_counter() - t)
            t = time.perf_counter()
            write_png(folder / f"{name}.png", img)
            stages[name].append({**info["timings_ms"], "frame": frame_ms,
                                 "write_png": 1e3 * (time.perf_counter() - t),
                                 **{f"raster_{k}": v for k, v in phases.get(name, {}).items()}})
            images[name] = img
        for key, (a, b) in (("new_old", ("new", "old")), ("image_new", ("image", "new"))):
            worst[key] = max(worst[key], int(np.abs(images[a].astype(np.int16) - images[b]).max()))

    def median(name: str, key: str) -> float:
        return statistics.median(s.get(key, 0.0) for s in stages[name])

    extra: dict[str, Any] = {"frames": len(picked), "size": f"{width}x{height}", "default": True}
    for name in paths:
        extra[f"{name}_fps"] = round(1e3 / median(name, "frame"), 2)
        keys = [*RENDER_STAGES, *sorted({k for st in stages[name] for k in st if k.startswith("raster_")})]
        extra.update({f"{name}_{key}_ms": round(median(name, key), 2) for key in keys})
    extra["fps_ratio"] = round(median("old", "frame") / median("new", "frame"), 3)
    extra["image_fps_ratio"] = round(median("new", "frame") / median("image", "frame"), 3)
    extra["image_vs_old_fps_ratio"] = round(median("old", "frame") / median("image", "frame"), 3)
    extra.update({f"error_{key}_uint8": value for key, value in worst.items()})
    extra["threads"] = get_threads()["numba"]
    return BenchCase(name="render_rain", knob="scene_rows", value="fixed", time_ms=median("image", "frame"),
                     error=float(max(worst.values())), error_unit="abs_uint8", extra=extra)


def _one_pass_case(model: Any, views: list[TrainingView], repeats: int) -> BenchCase:
    """Forward + backward of all weathers in one pass against one pass per weather."""
    v = views[0]
    grid = model.sky.grid(torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)))
    weathers = model.weathers

    def run(groups: list[tuple[str, ...]]) -> tuple[float, torch.Tensor]:
        best, images = float("inf"), None
        for _ in range(repeats):
            model.zero_grad(set_to_none=True)
            t = time.perf_counter()
            outs = [model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, g, sky_grid=grid, depth=True)
                    for g in groups]
            img = torch.cat([o.images for o in outs], -1)
            loss = img.mean() + sum(o.depth.mean() for o in outs if o.depth is not None)
            loss.backward()
            best = min(best, time.perf_counter() - t)
            images = img.detach()
        assert images is not None
        return best, images

    t_one, img_one = run([weathers])
    t_sep, img_sep = run([(w,) for w in weathers])
    model.zero_grad(set_to_none=True)
    return BenchCase(
        name="one_pass_vs_per_weather", knob="weathers_per_pass", value=len(weathers), time_ms=1e3 * t_one,
        error=float((img_one - img_sep).abs().max()), error_unit="abs",
        extra={"per_weather_ms": round(1e3 * t_sep, 1), "speedup": round(t_sep / t_one, 2),
               "gaussians": model.counts()["total"], "default": True},
    )


def _plain_case(scene: Scene, base: TrainConfig, train_views: list[TrainingView], held: list[TrainingView],
                seconds: float) -> BenchCase:
    """The calibration baseline on the same lidar initialisation, for the same clock."""
    options = LidarInitOptions(voxel_m=base.voxel_m, node_voxel_m=base.node_voxel_m, opacity=base.init_opacity)
    graph = init_scene_from_lidar(scene, options, frames=[v.frame for v in train_views])
    plain = PlainOptimisation(graph, train_views, background=estimate_sky_color(scene))
    evals, steps, spent = _timed_training(plain.step, [seconds / 2, seconds], lambda: plain.evaluate(held))
    return BenchCase(
        name="plain", knob="method", value="plain", time_ms=1e3 * spent, error=evals[seconds]["mean_psnr"],
        error_unit="psnr_db", extra={
            "psnr_half_clock": round(evals[seconds / 2]["mean_psnr"], 3),
            "dynamic_psnr": round(evals[seconds]["mean_dynamic_psnr"], 3), "steps": steps,
            "s_per_step": round(spent / steps, 3), "gaussians": len(graph)},
    )


def _step_ms(scene: Scene, train_views: list[TrainingView], views: list[TrainingView], config: TrainConfig,
             weathers: tuple[str, ...], content: Any, *, steps: int,
             hazes: dict[str, Haze] | None = None) -> tuple[float, int]:
    """Median ms of a training step (no densification) of a freshly built model, and its Gaussians."""
    model, _ = build_model(scene, train_views, config, weathers=weathers)
    trainer = Trainer(model, views, replace(config, densify_from=10**9), content=content, hazes=hazes)
    for _ in range(2):  # warm-up, and step 0 renders every weather whatever the interval
        trainer.step()
    return 1e3 * statistics.median(trainer.step().seconds for _ in range(steps)), model.counts()["total"]


#: Rows of the training-step profile (see the module docstring), in step order.
STEP_PHASES = ("data", "scene_graph", "decoders", "sky", "raster_fwd", "losses", "raster_bwd", "backward_rest",
               "stats", "optimizer", "densify", "log")


class _Stopwatch:
    """Sums the wall time of a module's forward calls (forward pre-hook to forward hook)."""

    def __init__(self, module: torch.nn.Module):
        self.ms = 0.0
        self._t = 0.0
        self._handles = [module.register_forward_pre_hook(self._start), module.register_forward_hook(self._stop)]

    def _start(self, *_: Any) -> None:
        self._t = time.perf_counter()

    def _stop(self, *_: Any) -> None:
        self.ms += 1e3 * (time.perf_counter() - self._t)

    def take(self) -> float:
        ms, self.ms = self.ms, 0.0
        return ms

    def remove(self) -> None:
        for h in self._handles:
            h.remove()


def _profile_case(scene: Scene, train_views: list[TrainingView], views: list[TrainingView], config: TrainConfig,
                  weathers: tuple[str, ...], content: Any, counts: list[int], *, rounds: int,
                  hazes: dict[str, Haze] | None = None) -> tuple[BenchCase, list[str]]:
    """Per-phase profile of a training step at each thread count (see the module docstring).

    Each round runs one period of the step schedule per count and averages it: ``weather_interval``
    2 alternates weather and clear steps, and the content loss comes every ``content_interval``
    weather steps, so a period of 2 x ``content_interval`` steps holds each kind in its share (two
    steps per count let the content steps, every 8th, all fall on the first count, whose losses and
    backward then read 3-9x slower than they are). Densification is disabled in the steps and timed
    once per count on a copy of the trainer, then divided by ``densify_interval``.
    """
    model, _ = build_model(scene, train_views, config, weathers=weathers)
    trainer = Trainer(model, views, replace(config, densify_from=10**9, weather_interval=2), content=content,
                      hazes=hazes)
    decoders, sky = _Stopwatch(model.decoders), _Stopwatch(model.sky)
    raster_fwd = [0.0]
    inner = trainer.rasterizer

    def timed_raster(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        out = inner(*args, **kwargs)
        raster_fwd[0] += 1e3 * (time.perf_counter() - t)
        return out

    trainer.rasterizer = timed_raster

    period = 2 * max(config.content_interval, 1) if content is not None and config.content_weight > 0 else 2

    def once() -> dict[str, float]:
        ph: dict[str, float] = {}
        for _ in range(period):
            raster_fwd[0] = 0.0
            log = trainer.step()
            p = log.phase_ms
            dec, sk = decoders.take(), sky.take()
            bwd = sum(v for k, v in log.raster_ms.items() if k.startswith("bwd_"))
            row = {"data": p["data"], "decoders": dec, "sky": sk, "raster_fwd": raster_fwd[0],
                   "scene_graph": p["render"] - dec - sk - raster_fwd[0], "losses": p["losses"], "raster_bwd": bwd,
                   "backward_rest": p["backward"] - bwd, "stats": p["stats"], "optimizer": p["optimizer"],
                   "log": p["log"]}
            for k, v in row.items():
                ph[k] = ph.get(k, 0.0) + v / period
        return ph

    samples, effective = run_interleaved(once, counts, rounds)
    decoders.remove()
    sky.remove()
    # One densification per count, each on its own copy of the model, optimizer and statistics the
    # rounds accumulated (the views, targets and content network are shared, not copied).
    for n in counts:
        twin = copy.copy(trainer)
        twin.model, twin.optimizer, twin.stats = copy.deepcopy((trainer.model, trainer.optimizer, trainer.stats))
        twin.generator = torch.Generator().set_state(trainer.generator.get_state())
        twin.densify_log = []
        with thread_count(n):
            t = time.perf_counter()
            twin.densify()
            ms = 1e3 * (time.perf_counter() - t) / max(config.densify_interval, 1)
        for ph in samples[n]:
            ph["densify"] = ms
    for ph in (ph for runs in samples.values() for ph in runs):
        ph["total"] = sum(ph[k] for k in STEP_PHASES)
        ph["non_raster"] = ph["total"] - ph["raster_fwd"] - ph["raster_bwd"]
    fields, lines = phase_table(f"profile_step: a training step ({model.counts()['total']} Gaussians, "
                                f"{config.size_for(scene.image_size)[0]}x{config.size_for(scene.image_size)[1]})",
                                samples, effective, [*STEP_PHASES, "non_raster"], "total")
    whole, rest = fields["phases"]["total"], fields["phases"]["non_raster"]
    case = BenchCase(name="profile_step", knob="threads", value=",".join(map(str, counts)),
                     time_ms=whole["ms"][str(counts[0])], error=None, error_unit="-",
                     extra={"speedup": whole["speedup"], "serial": whole["serial"],
                            "projected_16t": whole["projected_16t"], "non_raster_speedup": rest["speedup"],
                            "gaussians": model.counts()["total"], **fields})
    return case, lines


def _skip_cases(scene: Scene, base: TrainConfig, train_views: list[TrainingView], views: list[TrainingView],
                trained: tuple[str, ...], content: Any, *, steps: int,
                hazes: dict[str, Haze] | None = None) -> list[BenchCase]:
    """What each skip saves per training step (see the module docstring)."""
    clear_steps = replace(base, weather_interval=10**9)  # clear-only steps after the first
    every_step = replace(base, weather_interval=1)
    # (name, knob, value with the skip, whether the default skips, with, without, their weathers)
    pairs = [
        ("skip_frustum_cull", "cull_frustum", True, base.cull_frustum, clear_steps,
         replace(clear_steps, cull_frustum=False), trained, trained),
        # the default makes every boxed track a node (editable); the skip leaves the still ones in the background
        ("skip_static_tracks", "static_nodes", False, not base.static_nodes, replace(clear_steps, static_nodes=False),
         replace(clear_steps, static_nodes=True), trained, trained),
        ("skip_unsupervised_weather", "weathers", len(trained) - 1, True, every_step, every_step, trained[:-1],
         trained),
    ]
    out = []
    for name, knob, value, default, with_cfg, without_cfg, with_w, without_w in pairs:
        t_with, n_with = _step_ms(scene, train_views, views, with_cfg, with_w, content, steps=steps, hazes=hazes)
        t_without, n_without = _step_ms(scene, train_views, views, without_cfg, without_w, content, steps=steps,
                                        hazes=hazes)
        out.append(BenchCase(
            name=name, knob=knob, value=value, time_ms=t_with, error=None, error_unit="-",
            extra={"without_ms": round(t_without, 1), "saving_pct": round(100 * (1 - t_with / t_without), 1),
                   "gaussians": n_with, "gaussians_without": n_without, "default": default},
        ))
    return out


def _temporal_cases(scene: Scene, base: TrainConfig, content: Any, *, jitter: float) -> list[BenchCase]:
    """Flow warping error of weathercity trained on jittered supervision (see the module docstring)."""
    inputs = training_inputs(scene, base, supervision="filter2d", jitter=jitter)
    views = inputs.views
    train_views = [v for v in views if v.frame not in base.holdout]
    model, _ = build_model(scene, train_views, base, weathers=inputs.trained)
    trainer = Trainer(model, views, base, content=content if base.content_weight > 0 else None,
                      hazes=inputs.hazes)
    t = time.perf_counter()
    trainer.train()
    spent = time.perf_counter() - t
    raw = np.stack([v.images["clear"] for v in views])
    raw_error = flow_warping_error(raw)
    grids = [model.sky.grid(torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)))
             for v in views]
    out = []
    for weather in inputs.trained[1:]:
        with torch.no_grad():
            renders = np.stack([
                model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, (weather,), sky_grid=grid,
                             depth=False).images.clamp(0, 1).numpy()
                for v, grid in zip(views, grids)])
        supervision = np.stack([v.images[weather] for v in views])
        error = flow_warping_error(renders, raw)
        sup_error = flow_warping_error(supervision, raw)
        out.append(BenchCase(
            name=f"temporal_{weather}", knob="jitter", value=jitter, time_ms=1e3 * spent, error=error,
            error_unit="flow_warp_error", extra={
                "supervision_error": round(sup_error, 6), "raw_error": round(raw_error, 6),
                "vs_supervision": round(error / sup_error, 3), "vs_raw": round(error / raw_error, 3),
                "frames": len(views), "default": True},
        ))
    return out


def _held_out_content(model: Any, held: list[TrainingView], content: Any) -> float | None:
    """Mean content loss (VGG16 feature distance to the raw frame, sky masked) of the model's renders of
    every edited weather on the held-out views: what the content loss is for, which raw PSNR does not
    see. ``None`` without the loss (no VGG16 weights) or without edited weathers."""
    weathers = tuple(w for w in model.weathers if w != "clear")
    if content is None or not weathers:
        return None
    values = []
    with torch.no_grad():
        for v in held:
            grid = model.sky.grid(torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)))
            r = model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, weathers, sky_grid=grid,
                             depth=False)
            non_sky = None if v.sky is None else ~torch.from_numpy(v.sky)
            # held-out frames are keyed apart from the training frames in the loss's feature cache
            values.append(float(content(r.images, -1 - v.frame, torch.from_numpy(v.images["clear"]), non_sky)))
    return round(float(np.mean(values)), 5)


#: The front's objectives: (field, +1 where higher is better).
_OBJECTIVES = (("time_ms", -1), ("error", 1), ("fps_rain_fog", 1), ("content_distance", -1))


def _pareto(cases: list[BenchCase]) -> None:
    """Mark each case on the Pareto front of lower wall time, higher held-out PSNR, higher FPS and lower
    held-out content distance with ``pareto`` (an objective some row lacks is left out for every row)."""

    def value(c: BenchCase, key: str) -> Any:
        return getattr(c, key) if key in ("time_ms", "error") else c.extra.get(key)

    keys = [(k, sign) for k, sign in _OBJECTIVES if all(value(c, k) is not None for c in cases)]
    flags = pareto_flags([[sign * float(value(c, k)) for k, sign in keys] for c in cases])
    for c, flag in zip(cases, flags):
        c.extra["pareto"] = flag


def run(*, data_root: Path | None, quick: bool = False, threads: str | list[int] | None = None) -> BenchReport:
    """Run the suite.

    Parameters
    ----------
    data_root : Path or None
        Folder holding ``pandaset_002`` (else the demo street, and a note says so).
    quick : bool
        A smoke run: the ``quick`` profile at half its iterations and two knob cases; not a measurement.
    threads : str or list of int, optional
        Thread counts of ``profile_step`` (default ``1,2``; the first is the baseline).

    Returns
    -------
    BenchReport
        Suite ``"model"`` (see the module docstring).
    """
    groups = set(os.environ.get("WCBENCH_BENCH_MODEL_GROUPS", ",".join(GROUPS)).split(","))
    bad_groups = groups - set(GROUPS)
    if bad_groups:
        raise InputError(f"WCBENCH_BENCH_MODEL_GROUPS: unknown groups {sorted(bad_groups)}; "
                         f"known: {', '.join(GROUPS)}")
    counts = parse_threads(threads)
    chosen = os.environ.get("WCBENCH_BENCH_MODEL_KNOBS")
    knobs = _KNOBS[:2] if quick else _KNOBS
    if chosen:  # checked before any work
        picked = chosen.split(",")
        unknown = sorted(set(picked) - {k[0] for k in _KNOBS})
        if unknown:
            raise InputError(f"WCBENCH_BENCH_MODEL_KNOBS: unknown knob cases {unknown}; known: "
                             f"{', '.join(k[0] for k in _KNOBS)}")
        knobs = [k for k in _KNOBS if k[0] in picked]
    report = BenchReport(suite="model")
    scene, source = _scene(data_root)
    if source != _SCENE_ID:
        report.stand_ins.append(f"{_SCENE_ID} not found: the built-in demo street stood in")
    profile = "quick" if quick else "default"
    holdout = tuple(h for h in _HOLDOUT if h < len(scene)) or (len(scene) // 2,)
    base = make_config(profile, holdout=holdout, checkpoint_interval=10**9)
    if quick:  # a smoke run of every case: half the quick profile's steps (the knobs train half of that)
        base = base.scaled(_QUICK_FRACTION)
    # the suite's numbers have been measured on filter2d supervision: kept, so that they compare across runs
    inputs = training_inputs(scene, base, supervision="filter2d")
    views = inputs.views
    train_views = [v for v in views if v.frame not in holdout]
    held = [v for v in views if v.frame in holdout]
    width, height = base.size_for(scene.image_size)
    report.notes.append(f"scene: {source}, {width}x{height}, held out {list(holdout)}; supervision filter2d "
                        f"(no streaks or flakes); profile {profile}: {base.iterations} iterations "
                        f"(knobs: {base.scaled(0.5).iterations})")
    torch.manual_seed(0)
    content, content_note = content_loss_for(base, None)
    report.notes.append(f"content loss: {content_note}")
    if "profile" in groups:
        case, table = _profile_case(scene, train_views, views, base, inputs.trained, content, counts,
                                    rounds=2 if quick else 8, hazes=inputs.hazes)
        report.cases.append(case)
        report.notes += table
    if "skips" in groups:
        report.cases += _skip_cases(scene, base, train_views, views, inputs.trained, content, steps=3 if quick else 8,
                                    hazes=inputs.hazes)

    def train(config: TrainConfig) -> tuple[dict[int, Any], float, dict[str, Any]]:
        model, facts = build_model(scene, train_views, config, weathers=inputs.trained)
        loss = content
        if content is not None and config.content_size != base.content_size:  # the knob's own resolution
            loss = ContentLoss(content.features, size=config.content_size)
        trainer = Trainer(model, views, config, content=loss if config.content_weight > 0 else None,
                          hazes=inputs.hazes)
        evals: dict[int, Any] = {}
        spent = 0.0
        for mark in (config.iterations // 2, config.iterations):
            t = time.perf_counter()
            trainer.train(until=mark)
            spent += time.perf_counter() - t
            evals[mark] = evaluate_views(model, held)
        row = {"steps": config.iterations, "s_per_step": round(spent / config.iterations, 3),
               "gaussians": model.counts()["total"],
               "dynamic_psnr": round(evals[config.iterations]["mean_dynamic_psnr"], 3),
               "content_distance": _held_out_content(model, held, content),
               **_fps_rain_fog(scene, model, config, {**facts, "gaussians": model.counts()})}
        if config is base and "render" in groups:
            with tempfile.TemporaryDirectory() as tmp:
                report.cases.append(_render_case(scene, model, config, {**facts, "gaussians": model.counts()},
                                                 frames=5 if quick else 10, folder=Path(tmp)))
        if config is base and "headline" in groups:
            report.cases.append(_one_pass_case(model, train_views, repeats=2 if quick else 3))
            skipped = facts["skipped"]
            report.notes.append("skipped by the scene graph: " + ", ".join(
                f"{k}={v}" for k, v in skipped.items() if v not in (None, 0)))
        return evals, spent, row

    if "render" in groups and "headline" not in groups:  # a model of its own, trained as the headline's
        train(base)
    if "headline" in groups:
        evals, spent, row = train(base)
        psnr = evals[base.iterations]["mean_psnr"]
        plain = _plain_case(scene, base, train_views, held, spent)
        report.cases.append(BenchCase(
            name="weathercity", knob="method", value="weathercity", time_ms=1e3 * spent, error=psnr,
            error_unit="psnr_db", extra={
                "psnr_half": round(evals[base.iterations // 2]["mean_psnr"], 3),
                "vs_plain_db": round(psnr - float(plain.error or "nan"), 3), **row, "default": True},
        ))
        report.cases.append(plain)
    if "temporal" in groups:
        report.cases += _temporal_cases(scene, base, content, jitter=0.5)
    if "knobs" not in groups:
        return report
    half = base.scaled(0.5)
    evals, spent, row = train(half)
    default_half = evals[half.iterations]["mean_psnr"]
    knob_cases = [BenchCase(name="weathercity_half", knob="iterations", value=half.iterations, time_ms=1e3 * spent,
                            error=default_half, error_unit="psnr_db",
                            extra={**row, "default": True, "stands_for_knobs": True})]
    for name, knob, value, settings in knobs:
        config = replace(base, **settings).scaled(0.5)
        evals, spent, row = train(config)
        psnr = evals[config.iterations]["mean_psnr"]
        knob_cases.append(BenchCase(
            name=name, knob=knob, value=value, time_ms=1e3 * spent, error=psnr, error_unit="psnr_db",
            extra={"psnr_vs_default": round(psnr - default_half, 3), **row},
        ))
    _pareto(knob_cases)
    report.cases += knob_cases
    return report
