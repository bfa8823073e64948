"""Training settings, the named profiles (``default``, ``quick``, ``paper``) and ablations (``no-wgs``,
``no-content-loss``).

Every field that can change the trained model is part of the training's cache key; the defaults of
the ``default`` profile are chosen from the time-versus-quality table of ``wcbench bench model``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from functools import cache
from typing import Any

from wcbench.core.options import Option, Range, options_from_dataclass, validate_options

__all__ = ["ABLATIONS", "PROFILES", "PROFILE_PHYSICS", "SETTING_RANGES", "TrainConfig", "make_config",
           "settings_options"]


@dataclass(frozen=True)
class TrainConfig:
    """How a WeatherCity model is built and trained.

    Attributes
    ----------
    width, height : int
        Training (and rendering) resolution in pixels; ``width`` 0 is the scene's native width,
        ``height`` 0 keeps the scene's aspect ratio (:meth:`size_for`).
    iterations : int
        Optimisation steps.
    feature_dim, hidden : int
        Shared feature size and decoder hidden width (paper: 32 and 64). The default width is 32,
        the released code's: ``wcbench bench model`` measured the paper's 64 slower at the same
        held-out PSNR, off the Pareto front (docs/design.md §7).
    shared_decoder : bool
        One decoder for every weather (the "w/o WGS" ablation).
    ssim_weight : float
        lambda of the RGB loss (paper: 0.2).
    content_weight, content_interval : float, int
        Content loss weight (paper: 1.0; default 0.1, since on VGG16 ``relu4_1`` features the
        paper's weight makes the term 4-10x each weather's RGB term and costs held-out quality, as
        ``wcbench bench model`` measures) and its interval in weather steps (every
        ``content_interval``-th step that renders the edited weathers; 0 weight: off).
    content_size : (int, int)
        (width, height) the content loss runs at.
    depth_weight, opacity_weight, deform_weight : float
        Lidar depth (paper: 0.01), opacity/sky (paper: 0.05) and pedestrian deformation weights.
    opacity_solid : bool
        The opacity loss also pulls every non-sky pixel's opacity to 1 (:func:`~.losses.opacity_loss`):
        under an edited weather's haze the sky map is not seen, so structure it drew would vanish
        into the airlight. Off: the paper's two terms only.
    opacity_lidar : float
        Weight of the pull toward opacity 1 of the pixels a trusted lidar return lands in
        (``TrainingView.solid``), on top of ``opacity_solid``'s (1): a thin structure against the
        sky (a wire, a mast) is otherwise drawn by the sky map, not the Gaussians, and counts as sky.
        Default 30: on ``pandaset_002``'s full ``default`` training, with ``lidar_fill``, it left 61
        of the trusted pixels shown as sky against 201 at 10 (2,851 with neither) for 0.05 dB of
        held-out PSNR (docs/findings.md, "Lidar fill"); ``settings.opacity_lidar=0`` turns it off.
    opacity_sky : float
        Weight of the push toward opacity 0 of the sky's pixels (the paper's second term), relative
        to the others' 1.
    lidar_fill : bool
        At each densification, place a Gaussian at the nearest static trusted lidar return
        (``TrainingView.anchor_depth``) of every pixel that its view's last render left below half
        opacity, coloured as the raw frame there (:func:`~.densify.fill_from_lidar`): a structure
        the lidar saw but no Gaussian covers (a wire no clone or split reaches, a return in a gap
        the budget left) is drawn by the Gaussians, not the sky map. Up to 1 % of ``budget`` a
        densification, beyond it if need be (docs/findings.md, "Lidar fill").
    weather_interval : int
        Every this many steps the edited weathers are rendered (in the same pass) and supervised;
        the other steps fit the raw frame only. Default 4: at 8 the snow decoder kept the clear
        sky's blue on Gaussians beside thin structure of the real side cameras (docs/findings.md,
        "The weathers every 4th step by default").
    weather_weight : float
        Weight of each edited weather's RGB loss relative to the raw frame's 1 (the paper's sum:
        1). With Adam, a decoder seen only in a weather's loss learns at about the same pace for
        any weight, while the scene's shared geometry takes that weather's push scaled by it.
    through_haze : bool
        Compose each edited weather's physics haze (fog; rain and snow extinction) into its
        training render, so its decoder learns the appearance behind the haze, which the renderer
        then adds once (:mod:`~wcbench.reference_model.model.haze`). Off: the paper's recipe, which
        learns an edit's haze into the colors and adds the physics haze on top of it.
    lr : dict of str to float
        Adam learning rates: ``means`` (times the scene extent), ``log_scales``, ``quats``,
        ``object_quats``, ``opacity_logits``, ``features``, ``decoders``, ``sky``, ``offsets``.
    means_lr_final : float
        The centres' learning rate decays exponentially to this fraction of ``lr["means"]`` at
        step ``iterations`` (3DGS: 0.01); 1, the default, keeps it constant (``wcbench bench
        model``: the 3DGS decay cost 0.22 dB held-out at 800 steps, at the same time).
    sky_map : (int, int)
        (rows, columns) of each weather's sky environment map over elevation and azimuth.
    sky_window : bool
        The sky map spans the directions the training cameras see (plus a margin) rather than
        the whole sphere (``wcbench bench model``: a 256 x 512 window matched a whole-sphere
        512 x 2048 map, 27.79 against 27.81 dB held-out in 600-step runs).
    voxel_m, node_voxel_m : float
        Voxel of the lidar initialisation: background and objects (m).
    init_opacity : float
        Opacity every Gaussian starts with.
    cull_frustum : bool
        Drop background Gaussians outside every training frustum (off only to measure the saving).
    moving_threshold_m : float
        Tracks whose box moves more than this (m) are moving: posed per frame by their track (and
        masked as dynamic in the training views).
    static_nodes : bool
        Tracks that do not move (parked cars, cones) get a node too, held at their median box,
        their lidar Gaussians cut out of the background: every boxed object is editable
        (docs/design.md §7). On by default: on pandaset_002's default profile it costs 1.02x the
        training time and 0.04 dB held out, measured interleaved (docs/findings.md); off, they
        stay in the background, where `--edit` does not reach them.
    far_points : bool
        Add Gaussians far along the rays of pixels no lidar point reaches (distant structure).
    completion_points : bool
        Add Gaussians on the surfaces a view sees beyond its lidar, the ground plane below its lowest
        beam and the walls above its highest (:func:`~.build.completion_cloud`), so that they are
        Gaussians at their depth, not the sky map's (an edited weather's haze hides the sky).
    footprint_fill : bool
        Add opaque flat Gaussians on the fitted ground under every node's box where no lidar
        return saw it, coloured from the road around it
        (:func:`~wcbench.reference_model.scene_graph.footprints.fill_footprints`), so that a
        removed object leaves road, not a hole (issue 39).
    budget : int
        Most Gaussians the clones and splits may reach (the render speed depends on it); the lidar
        fill may add a few beyond.
    densify_from, densify_until, densify_interval : int
        Steps of the densification schedule.
    densify_grad : float
        Mean absolute 2D gradient (AbsGS, in normalised device coordinates) above which a
        Gaussian is cloned or split (gsplat's value for absolute gradients).
    prune_opacity : float
        Gaussians below this opacity are pruned at each densification.
    split_scale : float
        Gaussians larger than this fraction of the scene extent are split rather than cloned.
    holdout : tuple of int
        Frames left out of training (for held-out evaluation).
    seed : int
        Random seed of the initialisation and the optimisation.
    checkpoint_interval : int
        Steps between checkpoints (a killed training resumes from the last one).
    resolution_levels, resolution_interval : int
        Progressive resolution: the first ``resolution_interval`` steps train at 1/2^levels of the
        resolution, each next ``resolution_interval`` steps at twice the last, until the full one
        (nerfstudio's splatfacto schedule: 2 halvings, doubling every 3,000 steps; docs/workstation.md).
        0 levels: full resolution throughout (and the settings leave the cache key as it was).
    profile, ablation : str
        Names the settings came from (recorded).
    """

    width: int = 480
    height: int = 0
    iterations: int = 1600
    feature_dim: int = 32
    hidden: int = 32
    shared_decoder: bool = False
    ssim_weight: float = 0.2
    content_weight: float = 0.1
    content_interval: int = 4
    content_size: tuple[int, int] = (240, 135)
    depth_weight: float = 0.01
    opacity_weight: float = 0.05
    opacity_solid: bool = True
    opacity_lidar: float = 30.0
    opacity_sky: float = 1.0
    lidar_fill: bool = True
    deform_weight: float = 1.0
    weather_interval: int = 4
    weather_weight: float = 1.0
    through_haze: bool = True
    lr: dict[str, float] = field(default_factory=lambda: {
        "means": 1.6e-4, "log_scales": 5e-3, "quats": 1e-3, "object_quats": 1e-4, "opacity_logits": 3e-2,
        "features": 5e-3, "decoders": 2e-3, "sky": 2e-2, "offsets": 1e-3,
    })
    means_lr_final: float = 1.0
    sky_map: tuple[int, int] = (256, 512)
    sky_window: bool = True
    voxel_m: float = 0.2
    node_voxel_m: float = 0.12
    init_opacity: float = 0.1
    far_points: bool = True
    completion_points: bool = True
    footprint_fill: bool = True
    cull_frustum: bool = True
    moving_threshold_m: float = 0.5
    static_nodes: bool = True
    budget: int = 125_000
    densify_from: int = 200
    densify_until: int = 1200
    densify_interval: int = 100
    densify_grad: float = 8e-4
    prune_opacity: float = 0.005
    split_scale: float = 0.01
    holdout: tuple[int, ...] = ()
    seed: int = 0
    checkpoint_interval: int = 250
    resolution_levels: int = 0
    resolution_interval: int = 3000
    profile: str = "default"
    ablation: str = ""

    def size_for(self, scene_size: tuple[int, int]) -> tuple[int, int]:
        """(width, height) of the training views of a scene of ``scene_size`` (its aspect kept unless
        ``height`` is set)."""
        w, h = scene_size
        width = self.width or w
        return width, self.height or max(1, round(width * h / w))

    def resolution_divisor(self, step: int) -> int:
        """The factor (a power of 2, 1: full resolution) by which step ``step`` divides the training
        views' width and height (progressive resolution: ``resolution_levels``)."""
        return 2 ** max(0, self.resolution_levels - step // max(self.resolution_interval, 1))

    def scaled(self, fraction: float) -> TrainConfig:
        """The same training with ``fraction`` of the iterations, the densification schedule scaled alike
        (a shorter or longer budget on the same plan: ``wcbench bench model``'s iterations knob)."""
        if not fraction > 0:
            raise ValueError(f"fraction must be > 0, got {fraction}")

        def steps(n: int) -> int:
            return max(1, round(n * fraction))

        return replace(self, iterations=steps(self.iterations), densify_from=steps(self.densify_from),
                       densify_until=steps(self.densify_until), densify_interval=steps(self.densify_interval))

    def to_json(self) -> dict[str, Any]:
        """The settings as a JSON-ready dict (tuples as lists)."""
        d = asdict(self)
        d["content_size"] = list(self.content_size)
        d["sky_map"] = list(self.sky_map)
        d["holdout"] = list(self.holdout)
        if not self.resolution_levels:  # off: the keys of the trainings before the setting existed
            del d["resolution_levels"], d["resolution_interval"]
        return d

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_json` (unknown keys are an error)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(obj) - known)
        if unknown:
            raise ValueError(f"unknown training settings {unknown}; known: {sorted(known)}")
        obj = dict(obj)
        for key in ("content_size", "sky_map", "holdout"):
            if key in obj:
                obj[key] = tuple(obj[key])
        return cls(**obj)


#: Named settings: ``default`` is the measured trade-off at 480x270; ``quick`` trains small in
#: seconds for demos and tests.
PROFILES: dict[str, dict[str, Any]] = {
    "default": {},
    "quick": {
        "width": 240, "iterations": 300, "content_interval": 4, "content_size": (120, 68),
        "voxel_m": 0.3, "node_voxel_m": 0.15, "budget": 60_000, "densify_from": 60, "densify_until": 240,
        "densify_interval": 60, "checkpoint_interval": 100, "far_points": False,
        "weather_interval": 2,
    },
    # The paper's protocol (docs/workstation.md): the scene's native resolution, 30,000 Adam steps, the
    # progressive resolution of 3DGS trainers (1/4 for 3,000 steps, 1/2 for 3,000, then full), the
    # densification over the 3DGS schedule (from 500 to 15,000 every 100 steps), the content loss at
    # 1/4 of 1920x1080; 40k rain and 16k snow particles are the `paper` physics presets (`physics`).
    "paper": {
        "width": 0, "iterations": 30_000, "resolution_levels": 2, "resolution_interval": 3000,
        "densify_from": 500, "densify_until": 15_000, "densify_interval": 100, "content_size": (480, 270),
        "budget": 1_000_000, "checkpoint_interval": 1000,
    },
}

#: The physics presets a profile renders with unless the run names others (``physics`` option):
#: the paper's 40,000 raindrops and 16,000 snowflakes (weather/presets.toml, ``paper``).
PROFILE_PHYSICS: dict[str, dict[str, str]] = {"paper": {"rain": "paper", "snow": "paper"}}

#: The paper's ablations (Table 3): "w/o WGS" and "w/o L_cc".
ABLATIONS: dict[str, dict[str, Any]] = {
    "": {},
    "no-wgs": {"shared_decoder": True},
    "no-content-loss": {"content_weight": 0.0},
}


#: The bounds of every numeric training setting (``lr.KEY``: one learning rate); a field added to
#: :class:`TrainConfig` without one makes :func:`settings_options` fail (docs/guide.md, "Method options").
SETTING_RANGES: dict[str, Range] = {
    "width": Range(0), "height": Range(0), "iterations": Range(1), "feature_dim": Range(1), "hidden": Range(1),
    "ssim_weight": Range(0, 1), "content_weight": Range(0), "content_interval": Range(1),
    "content_size": Range(1), "depth_weight": Range(0), "opacity_weight": Range(0), "opacity_lidar": Range(0),
    "opacity_sky": Range(0),
    "deform_weight": Range(0),
    "weather_interval": Range(1), "weather_weight": Range(0),
    **{f"lr.{k}": Range(0, low_open=True) for k in ("means", "log_scales", "quats", "object_quats",
                                                    "opacity_logits", "features", "decoders", "sky", "offsets")},
    "means_lr_final": Range(0, 1, low_open=True), "sky_map": Range(1), "voxel_m": Range(0, low_open=True),
    "node_voxel_m": Range(0, low_open=True), "init_opacity": Range(0, 1, low_open=True, high_open=True),
    "moving_threshold_m": Range(0), "budget": Range(1), "densify_from": Range(0), "densify_until": Range(0),
    "densify_interval": Range(1), "densify_grad": Range(0, low_open=True), "prune_opacity": Range(0, 1, high_open=True),
    "split_scale": Range(0, low_open=True), "seed": Range(0), "checkpoint_interval": Range(1),
    "resolution_levels": Range(0, 8), "resolution_interval": Range(1),
}


@cache
def settings_options() -> dict[str, Option]:
    """The training settings a run may override (``settings.KEY``), derived from :class:`TrainConfig`'s
    fields, type hints and Attributes, bounded by :data:`SETTING_RANGES`. ``holdout``, ``profile`` and
    ``ablation`` are options of their own, not settings."""
    return options_from_dataclass(TrainConfig, ranges=SETTING_RANGES, skip=("holdout", "profile", "ablation"))


def make_config(profile: str = "default", *, ablation: str = "", **overrides: Any) -> TrainConfig:
    """The settings of a profile, an ablation and explicit overrides (in that order).

    Raises
    ------
    ValueError
        On an unknown profile or ablation; :class:`~wcbench.core.options.OptionError` (a ValueError)
        on an unknown setting or a value outside its declared type and range (:func:`settings_options`),
        except ``holdout``, which is checked against the scene.
    """
    if profile not in PROFILES:
        raise ValueError(f"unknown training profile {profile!r}; profiles: {sorted(PROFILES)}")
    if ablation not in ABLATIONS:
        raise ValueError(f"unknown ablation {ablation!r}; ablations: {sorted(a for a in ABLATIONS if a)}")
    holdout = overrides.pop("holdout", None)
    overrides = validate_options(settings_options(), overrides, path="settings", owner="settings")
    if holdout is not None:
        overrides["holdout"] = tuple(holdout)
    base = TrainConfig()
    lr = dict(base.lr)
    lr.update(overrides.pop("lr", {}))
    return replace(base, **{**PROFILES[profile], **ABLATIONS[ablation], **overrides, "lr": lr,
                            "profile": profile, "ablation": ablation})
