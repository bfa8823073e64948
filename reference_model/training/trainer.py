"""Multi-weather optimisation of a WeatherCity model (docs/design.md §7).

Each step takes one training view (a fresh random order every epoch), renders the clear weather and,
every ``weather_interval`` steps, every supervised weather in the **same** rasterization pass, and
minimises

    sum_w [(1 - 0.2) L1 + 0.2 (1 - SSIM)](I_w, target_w)          RGB, raw frame and every edit
                                   (an edit's I_w composed through its weather's haze: ``through_haze``)
    + lambda_cc  L_cc(I_w, raw)      every ``content_interval``-th weather step, VGG16, sky masked
    + lambda_depth |D - D_lidar|     where the frame's lidar landed
    + lambda_opacity L_opacity(A, sky, lidar hits)
    + lambda_deform (|delta|^2 + |delta_t+1 - delta_t|^2)           pedestrians' offsets

with Adam (a learning rate per parameter kind; the centres' may decay exponentially over the
iterations, as in 3DGS: ``means_lr_final``), densification by the absolute 2D gradient under a
Gaussian budget (:mod:`.densify`), and checkpoints from which a killed training resumes with the
same next step (:mod:`.checkpoint`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from wcbench.reference_model.devices import check_device, rasterizer_for
from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.haze import Haze
from wcbench.reference_model.model.scene_model import BACKGROUND, WeatherCityModel
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.reference_model.raster.threads import threads as thread_pools
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.training.config import TrainConfig
from wcbench.reference_model.training.densify import (
    DensifyStats,
    NodeOptimizer,
    append_gaussians,
    densify_and_prune,
    fill_from_lidar,
)
from wcbench.reference_model.training.losses import (
    ContentLoss,
    depth_l1,
    opacity_loss,
    psnr,
    psnr_from_mse,
    rgb_loss,
    weighted_sum,
)
from wcbench.reference_model.training.views import TrainingView, scaled_view

__all__ = ["StepLog", "Trainer", "evaluate_renders", "evaluate_views", "scene_extent"]


def scene_extent(views: Sequence[TrainingView]) -> float:
    """1.1 x the largest distance of a camera from the cameras' mean position (m), at least 1 m (3DGS)."""
    centers = np.stack([v.center for v in views])
    return max(1.0, 1.1 * float(np.linalg.norm(centers - centers.mean(0), axis=1).max()))


@dataclass
class StepLog:
    """What one step measured."""

    step: int
    frame: int
    loss: float
    terms: dict[str, float]
    psnr_clear: float
    gaussians: int
    seconds: float
    #: Wall time (ms) of the step's phases: ``data`` (view, targets), ``render`` (the model's forward:
    #: scene graph, decoders, sky, rasterizer), ``losses`` (their forward), ``backward`` (every
    #: backward, the rasterizer's included), ``stats`` (densification statistics), ``optimizer``,
    #: ``densify`` and ``log``; ``raster`` holds the rasterizer's own phases (``RenderJob.phase_ms``).
    phase_ms: dict[str, float] = field(default_factory=dict)
    raster_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class _ViewTensors:
    """A view's fixed tensors, made once."""

    targets: dict[str, torch.Tensor]
    depth: torch.Tensor | None
    sky: torch.Tensor | None
    non_sky: torch.Tensor | None
    grid: torch.Tensor
    ignore: torch.Tensor | None = None
    solid: torch.Tensor | None = None
    anchored: torch.Tensor | None = None  # pixels with a static trusted return (the lidar fill's)


@dataclass
class Trainer:
    """Trains ``model`` on ``views``.

    Parameters
    ----------
    model : WeatherCityModel
    views : sequence of TrainingView
        Every view; those in ``config.holdout`` are not trained on.
    config : TrainConfig
    content : ContentLoss, optional
        The content loss; ``None`` skips the term (no VGG16 weights, or the ablation).
    rasterizer : callable
        ``rasterize``-compatible (tests inject the pure-torch twin).
    hazes : mapping of str to Haze, optional
        The physics haze of each edited weather, composed into its render when
        ``config.through_haze`` (:mod:`~wcbench.reference_model.model.haze`).
    threads : int, optional
        Threads of numba, torch and BLAS together while :meth:`train` runs
        (:func:`~wcbench.reference_model.raster.threads.set_threads`, restored after it); ``None``
        leaves the pools as they are.
    device : {"cpu", "cuda"}
        Where the model and the training step live (:mod:`~wcbench.reference_model.devices`): on
        ``"cuda"`` the model moves there, the default rasterizer becomes gsplat and the numba kernels
        give way to their torch twins; ``"cpu"`` changes nothing.

    Raises
    ------
    ValueError
        No training view is left after the holdout; ``device`` cannot be used (no CUDA, no gsplat).
    """

    model: WeatherCityModel
    views: Sequence[TrainingView]
    config: TrainConfig
    content: ContentLoss | None = None
    hazes: Mapping[str, Haze] | None = None
    rasterizer: Callable[..., Any] = rasterize
    threads: int | None = None
    device: str = "cpu"
    step_index: int = 0
    history: list[StepLog] = field(default_factory=list)
    densify_log: list[dict[str, Any]] = field(default_factory=list)
    train_seconds: float = 0.0

    def __post_init__(self) -> None:
        cfg = self.config
        if self.device != "cpu":
            check_device(self.device)
            self.model.to(self.device)
            if self.content is not None:
                self.content.to(self.device)
            if self.rasterizer is rasterize:
                self.rasterizer = rasterizer_for(self.device)
        self.train_views = [v for v in self.views if v.frame not in cfg.holdout]
        if not self.train_views:
            raise ValueError("no training view left after the holdout")
        self.weathers = self.model.weathers
        self.extent = scene_extent(self.train_views)
        self._tensors = {v.frame: self._view_tensors(v) for v in self.train_views}
        self._scaled: dict[tuple[int, int], tuple[TrainingView, _ViewTensors]] = {}  # progressive resolution
        self.optimizer = self._make_optimizer()
        self._means_lr = {g["name"]: g["lr"] for g in self.optimizer.adam.param_groups if g["name"].endswith(".means")}
        self.stats = {name: DensifyStats() for name in self._densified_nodes()}
        self.rng = np.random.default_rng(cfg.seed)
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self._order: list[int] = []
        # per training frame, its anchored pixels its last full-resolution render left below half
        # opacity (the lidar fill's input; reset by each densification that reads it)
        self.holes: dict[int, torch.Tensor] = {}

    # -- set-up -------------------------------------------------------------------------------

    def _view_tensors(self, v: TrainingView) -> _ViewTensors:
        dev = torch.device(self.device)

        def put(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(a).to(dev)

        grid = self.model.sky.grid(put(view_directions(v.camera_to_world, v.K, v.width, v.height)))
        missing = [w for w in self.weathers if w not in v.images]
        if missing:
            raise ValueError(f"view of frame {v.frame} lacks supervision for {missing}")
        sky = None if v.sky is None else put(v.sky)
        ignore = put(v.ignore) if v.ignore.shape == (v.height, v.width) and v.ignore.any() else None
        non_sky = None if sky is None else ~sky
        if ignore is not None:
            non_sky = ~ignore if non_sky is None else non_sky & ~ignore
        return _ViewTensors(
            targets={w: put(v.images[w]) for w in self.weathers},
            depth=None if v.depth is None else put(v.depth),
            sky=sky,
            non_sky=non_sky,
            grid=grid,
            ignore=ignore,
            solid=put(v.solid) if v.solid is not None and v.solid.any() else None,
            anchored=put(v.anchor_depth > 0) if v.anchor_depth is not None and (v.anchor_depth > 0).any() else None,
        )

    def _view_at(self, v: TrainingView, divisor: int) -> tuple[TrainingView, _ViewTensors]:
        """``v`` and its tensors at 1/``divisor`` of the training resolution (made once per level; the
        previous level's are dropped)."""
        if divisor == 1:
            return v, self._tensors[v.frame]
        key = (v.frame, divisor)
        if key not in self._scaled:
            self._scaled = {k: s for k, s in self._scaled.items() if k[1] == divisor}
            small = scaled_view(v, divisor)
            self._scaled[key] = (small, self._view_tensors(small))
        return self._scaled[key]

    def _densified_nodes(self) -> list[str]:
        return [BACKGROUND] + [f"rigid:{o.track_id}" for o in self.model.rigid_objects()]

    def _make_optimizer(self) -> NodeOptimizer:
        lr = self.config.lr
        groups: list[tuple[str, torch.nn.Parameter, float]] = []
        for name, params in self.model.nodes().items():
            for key, p in params.tensors().items():
                rate = lr["means"] * self.extent if key == "means" else lr[key]
                if key == "quats" and name != BACKGROUND:
                    rate = lr["object_quats"]
                groups.append((f"{name}.{key}", p, rate))
        for obj in self.model.nonrigid_objects():
            groups.append((f"nonrigid:{obj.track_id}.offsets", obj.offsets, lr["offsets"]))
        for pname, p in self.model.decoders.named_parameters():
            groups.append((f"decoders.{pname}", p, lr["decoders"]))
        groups.append(("sky.logits", self.model.sky.logits, lr["sky"]))
        return NodeOptimizer(groups)

    def _decay_means_lr(self) -> None:
        # 3DGS's exponential decay of the centres' rate: large moves early, fine placement late.
        # A function of the step alone, so a resumed training continues the same schedule.
        cfg = self.config
        factor = cfg.means_lr_final ** min(self.step_index / max(cfg.iterations, 1), 1.0)
        for group in self.optimizer.adam.param_groups:
            base = self._means_lr.get(group["name"])
            if base is not None:
                group["lr"] = base * factor

    # -- one step ---------------------------------------------------------------------------

    def _next_view(self) -> TrainingView:
        if not self._order:
            self._order = list(self.rng.permutation(len(self.train_views)))
        return self.train_views[self._order.pop()]

    def _weather_step(self, it: int) -> bool:
        """Whether step ``it`` renders every supervised weather (else the clear one alone)."""
        return len(self.weathers) > 1 and it % max(self.config.weather_interval, 1) == 0

    def _content_step(self, it: int) -> bool:
        """Whether step ``it`` adds the content loss (every ``content_interval``-th weather step)."""
        cfg = self.config
        return (self.content is not None and cfg.content_weight > 0 and self._weather_step(it)
                and (it // max(cfg.weather_interval, 1)) % max(cfg.content_interval, 1) == 0)

    def _densify_after(self, done: int) -> bool:
        """Whether the step that makes ``done`` steps densifies after its update."""
        cfg = self.config
        return cfg.densify_from <= done <= cfg.densify_until and done % cfg.densify_interval == 0

    def step_kinds(self, start: int, stop: int) -> list[str]:
        """What each of the steps ``start..stop-1`` of :meth:`train` does, as it costs: ``"clear"`` or
        ``"weather"``, with ``"+content"``, ``"+densify"`` and ``"+checkpoint"`` when it computes the
        content loss, densifies, or follows a checkpoint (``train`` saves one after a step's callback,
        so its time falls before the next step's). The schedule is fixed in advance; the progress line's
        time left weighs each kind by its measured time (:class:`wcbench.core.progress.TimeLeft`).

        Parameters
        ----------
        start, stop : int
            The first step and the step after the last (``config.iterations`` for a whole training).

        Returns
        -------
        list of str
            One kind per step; under progressive resolution a kind names its level (``"clear@1/4"``).
        """
        interval = self.config.checkpoint_interval
        kinds = []
        for it in range(start, stop):
            parts = ["weather" if self._weather_step(it) else "clear"]
            divisor = self.config.resolution_divisor(it)
            parts[0] += f"@1/{divisor}" if divisor > 1 else ""
            parts += ["content"] * self._content_step(it)
            parts += ["densify"] * self._densify_after(it + 1)
            parts += ["checkpoint"] * (it > start and it % interval == 0)
            kinds.append("+".join(parts))
        return kinds

    def kind_weights(self, start: int, stop: int) -> dict[str, float]:
        """The relative cost of each kind of :meth:`step_kinds` (``start..stop-1``): its share of the full
        resolution's pixels, so that the time left prices the later, larger levels of a progressive
        training before they are measured (:class:`wcbench.core.progress.TimeLeft`'s ``weights``)."""
        kinds = self.step_kinds(start, stop)
        return {kind: 1.0 / self.config.resolution_divisor(it) ** 2 for kind, it in zip(kinds, range(start, stop))}

    def step(self) -> StepLog:
        """One optimisation step (with densification and a checkpoint when they are due)."""
        cfg = self.config
        start = time.perf_counter()
        it = self.step_index
        v, tv = self._view_at(self._next_view(), cfg.resolution_divisor(it))
        all_weathers = self._weather_step(it)
        weathers = self.weathers if all_weathers else ("clear",)
        want_depth = cfg.depth_weight > 0 and tv.depth is not None
        target = tv.targets["clear"] if len(weathers) == 1 else torch.cat([tv.targets[w] for w in weathers], -1)
        marks = [("data", time.perf_counter())]
        render = self.model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, weathers,
                                   sky_grid=tv.grid, depth=want_depth, absgrad=True, rasterizer=self.rasterizer,
                                   hazes=self.hazes if cfg.through_haze else None)
        marks.append(("render", time.perf_counter()))
        if tv.ignore is not None:  # the ego vehicle's body: the render is its own target there (no gradient)
            target = torch.where(tv.ignore[..., None], render.images.detach(), target)
        if cfg.lidar_fill and tv.anchored is not None and tv is self._tensors.get(v.frame):
            self.holes[v.frame] = (render.alpha.detach() < 0.5) & tv.anchored
        per_weather = rgb_loss(render.images, target, ssim_weight=cfg.ssim_weight)
        if len(weathers) > 1 and cfg.weather_weight != 1.0:
            # the raw frame is weathers[0] (the decoders' first weather, "clear")
            rgb = per_weather[0] + cfg.weather_weight * per_weather[1:].sum()
        else:
            rgb = per_weather.sum()
        terms: list[tuple[float, torch.Tensor]] = [(1.0, rgb)]
        # the logged terms stay on the device until the step's end: one host transfer per step (on a GPU
        # each float() would wait for the queue to drain)
        logged: dict[str, torch.Tensor] = {f"rgb_{w}": x for w, x in zip(weathers, per_weather.detach())}
        if self._content_step(it) and self.content is not None:
            cc = self.content(render.images[..., 3:], v.frame, tv.targets["clear"], tv.non_sky)
            terms.append((cfg.content_weight, cc))
            logged["content"] = cc.detach()
        if want_depth:
            assert render.depth is not None and tv.depth is not None
            d = depth_l1(render.depth, tv.depth)
            terms.append((cfg.depth_weight, d))
            logged["depth"] = d.detach()
        if cfg.opacity_weight > 0:
            o = opacity_loss(render.alpha, tv.sky, solid=cfg.opacity_solid, lidar=tv.solid,
                             lidar_weight=cfg.opacity_lidar, sky_weight=cfg.opacity_sky)
            terms.append((cfg.opacity_weight, o))
            logged["opacity"] = o.detach()
        if self.model.nonrigid and cfg.deform_weight > 0:
            pen = torch.stack([obj.deformation_penalty() for obj in self.model.nonrigid_objects()]).sum()
            terms.append((cfg.deform_weight, pen))
            logged["deform"] = pen.detach()
        loss = weighted_sum(terms)
        marks.append(("losses", time.perf_counter()))
        loss.backward()
        marks.append(("backward", time.perf_counter()))
        self._accumulate(render, v.width, v.height)
        marks.append(("stats", time.perf_counter()))
        self._decay_means_lr()
        self.optimizer.step()
        self.optimizer.zero_grad()
        self.step_index += 1
        marks.append(("optimizer", time.perf_counter()))
        if self._densify_after(self.step_index):
            self.densify()
        marks.append(("densify", time.perf_counter()))
        with torch.no_grad():
            mse = (render.image("clear").detach() - tv.targets["clear"]).double().square().mean()
        loss_value, mse_value, *term_values = torch.stack(
            [loss.detach().double(), mse, *(t.double() for t in logged.values())]).tolist()
        quality = psnr_from_mse(mse_value)
        end = time.perf_counter()
        marks.append(("log", end))
        seconds = end - start
        self.train_seconds += seconds
        phases, prev = {}, start
        for name, t in marks:
            phases[name] = 1e3 * (t - prev)
            prev = t
        log = StepLog(step=it, frame=v.frame, loss=loss_value, terms=dict(zip(logged, term_values)),
                      psnr_clear=quality,
                      gaussians=self.model.counts()["total"], seconds=seconds, phase_ms=phases,
                      raster_ms=dict(render.raster.meta.get("phase_ms", {})))
        self.history.append(log)
        return log

    def _accumulate(self, render: Any, width: int, height: int) -> None:
        g = render.raster.means2d_abs
        if g is None or g.grad is None:
            return
        # gradients in normalised device coordinates (x 2/W per pixel), as the 3DGS / AbsGS
        # thresholds are stated: the same threshold then holds at any resolution
        norm = (g.grad * g.grad.new_tensor([0.5 * width, 0.5 * height])).norm(dim=1)
        visible = (render.raster.radii > 0).all(dim=1)
        masked, seen = torch.where(visible, norm, 0.0), visible.to(norm.dtype)  # once for every node
        nodes = self.model.nodes()
        for key, start, stop in render.gaussians.segments:
            if key in self.stats:
                st = self.stats[key]
                st.ensure(len(nodes[key]), device=norm.device)
                st.add_masked(masked[start:stop], seen[start:stop])

    def densify(self) -> dict[str, Any]:
        """Clone, split and prune every densified node within the budget (see :mod:`.densify`)."""
        cfg = self.config
        nodes = self.model.nodes()
        room = cfg.budget - self.model.counts()["total"]
        record: dict[str, Any] = {"step": self.step_index}
        for name in self._densified_nodes():
            before = len(nodes[name])
            share = room if name == BACKGROUND else max(room // 4, 0)
            counts = densify_and_prune(
                name, nodes[name], self.stats[name], self.optimizer, grad_threshold=cfg.densify_grad,
                split_scale_m=cfg.split_scale * self.extent, max_scale_m=0.3 * self.extent,
                prune_opacity=cfg.prune_opacity, room=share, generator=self.generator,
            )
            room -= len(nodes[name]) - before
            self.stats[name] = DensifyStats()
            if any(counts.values()):
                record[name] = counts
        if cfg.lidar_fill and self.holes:
            record["lidar_fill"] = self._fill_from_lidar(limit=max(cfg.budget // 100, 1))
        record["total"] = self.model.counts()["total"]
        self.densify_log.append(record)
        return record

    def _fill_from_lidar(self, *, limit: int) -> int:
        """Add to the background a Gaussian at the anchor of every hole of the training views (one per
        2 cm cell, at most ``limit``, in frame and then row-major order); returns how many."""
        views = {v.frame: v for v in self.train_views}
        clouds = []
        for frame in sorted(self.holes):
            v = views[frame]
            assert v.anchor_depth is not None  # holes are kept for anchored views only
            clouds.append(fill_from_lidar(self.holes[frame].cpu().numpy(), v.anchor_depth, v.K, v.camera_to_world,
                                          v.images["clear"]))
        self.holes = {}
        cloud = GaussianCloud.concatenate(clouds)
        if len(cloud) == 0:
            return 0
        # several views see one structure: a return per 2 cm cell is enough
        _, first = np.unique(np.floor(cloud.means / 0.02).astype(np.int64), axis=0, return_index=True)
        cloud = cloud.subset(np.sort(first)[:limit])
        new = GaussianParams.from_cloud(cloud, feature_dim=self.model.background.feature_dim,
                                        seed=self.config.seed + self.step_index)
        return append_gaussians(BACKGROUND, self.model.background, self.optimizer, new)

    # -- the loop ---------------------------------------------------------------------------

    def train(self, *, until: int | None = None, callback: Callable[[StepLog], None] | None = None,
              checkpoint: Callable[[Trainer], Any] | None = None) -> list[StepLog]:
        """Step until ``until`` (default ``config.iterations``), calling ``callback`` after each step and
        ``checkpoint`` every ``config.checkpoint_interval`` steps and at the end."""
        stop = self.config.iterations if until is None else until
        logs = []
        with thread_pools(self.threads):
            while self.step_index < stop:
                log = self.step()
                logs.append(log)
                if callback is not None:
                    callback(log)
                if checkpoint is not None and (self.step_index % self.config.checkpoint_interval == 0
                                               or self.step_index == stop):
                    checkpoint(self)
        return logs


def evaluate_renders(render: Callable[[TrainingView], torch.Tensor],
                     views: Sequence[TrainingView]) -> dict[str, Any]:
    """PSNR (dB) of ``render(view)`` [H, W, 3] against each view's raw frame: per frame, their mean,
    and inside moving objects (``nan`` where no view has one)."""
    per_view, dynamic = {}, {}
    with torch.no_grad():
        for v in views:
            img = render(v).clamp(0, 1).cpu()  # a no-op on the CPU
            target = torch.from_numpy(v.images["clear"])
            per_view[v.frame] = psnr(img, target)
            if v.dynamic.any():
                dynamic[v.frame] = psnr(img, target, torch.from_numpy(v.dynamic))
    finite = [p for p in per_view.values() if np.isfinite(p)]
    dyn = [p for p in dynamic.values() if np.isfinite(p)]
    return {"psnr": per_view, "mean_psnr": float(np.mean(finite)) if finite else float("nan"),
            "dynamic_psnr": dynamic, "mean_dynamic_psnr": float(np.mean(dyn)) if dyn else float("nan")}


def evaluate_views(model: WeatherCityModel, views: Sequence[TrainingView], *,
                   rasterizer: Callable[..., Any] | None = None) -> dict[str, Any]:
    """:func:`evaluate_renders` of the model's clear renders, on the model's device (``rasterizer``:
    default :func:`~wcbench.reference_model.devices.rasterizer_for` that device)."""
    dev = model.sky.basis.device
    if rasterizer is None:
        rasterizer = rasterizer_for(dev.type)

    def render(v: TrainingView) -> torch.Tensor:
        grid = model.sky.grid(torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)).to(dev))
        return model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, ("clear",), sky_grid=grid,
                            depth=False, rasterizer=rasterizer).images

    return evaluate_renders(render, views)
