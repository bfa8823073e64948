"""Render a scene under physics-driven weather, before any training.

The scene is the lidar initialisation of the reference model (static Gaussians plus one rigid
node per moving object, colored from the images); rain and snow particles are rasterized with it
and fog is composed on top (docs/design.md §7). Frames go to the prediction layout
``OUT/<method>/<scene>/<weather>/{frame:03d}.png`` with an ``info.json`` (method, version,
parameters, timings, per-frame sha256), plus ``OUT/<method>/<scene>/<weather>.mp4`` for a sequence.

Examples::

    wcbench render --scenes pandaset_002 --weathers rain --preset heavy --out renders
    wcbench render --scenes ../shared/data/pandaset_002 --weathers fog --visibility 60 --out renders
    wcbench render --scenes pandaset_002 --weathers snow --wind 4,20,30 --frames 0-9 --out renders
    wcbench render --scenes pandaset_002 --weathers rain snow fog --out renders      # each as the scene requests
    wcbench render --method weathercity --scenes pandaset_002 --weathers rain --preset heavy --scale 0.5 \\
        --edit "remove class=Car" --out renders

A finished folder rendered with the same settings is left alone; one rendered with other settings
is kept unless ``--overwrite``. A killed render resumes (frames are pure functions of the seed).

With ``--method weathercity`` the scene is the trained WeatherCity model instead (trained first,
or loaded from the cache; the method options ``--method-option``, ``--profile``, ``--supervision``,
``--jitter``, ``--ablation``, ``--holdout`` and ``--edit`` as for ``run``), rendered at any size.

The weather options (``--preset``, ``--rate``, ``--visibility``...) apply to every edited weather
of ``--weathers`` (``clear`` has none to set); without any, each weather is the scene's requested
one, as ``run`` renders it (the method's ``physics="auto"``: a ``synth_*`` scene's recorded rate,
visibility and wind, else the presets). render hands them to the method as its ``physics`` option,
so ``--method-option physics=...`` is refused. The particle seed is ``--seed``, never the truth's
(docs/design.md §4).

``render`` is a front of the units of work ``wcbench run`` renders through: the same method, seed,
weather and size give the same frames either way: both take ``--frames`` and ``--scale`` or
``--width/--height`` and default to the method's own size (``lidar-init``: a quarter of the
scene's, 480x270 for 1920x1080), and both record the size and settings in info.json. A render of
some frames is scored as it is by ``wcbench evaluate`` (its info.json lists the frames and size).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from wcbench.cli.common import (
    add_deprecated_alias,
    add_frame_and_size_arguments,
    add_method_options,
    add_offline_argument,
    add_output_argument,
    add_progress_argument,
    add_scene_arguments,
    add_weathers_argument,
    checked_method_options,
    method_name,
    method_options_from,
    parse_frame_spec,
    size_request_from,
    weathers_from,
)
from wcbench.core.errors import InputError
from wcbench.core.frame_ranges import frames_outside
from wcbench.core.weathers import WEATHERS

HELP = "render a scene under rain, snow or fog (lidar-initialised Gaussians + weather physics)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``wcbench render``."""
    add_scene_arguments(parser)
    add_output_argument(parser, required=True, help="output root of the prediction layout")
    add_weathers_argument(parser, help="weathers to render (required), each with the weather options below")
    add_deprecated_alias(parser, "--weather", use="--weathers", dest="weathers", metavar="WEATHER",
                         convert=lambda value: [value])
    parser.add_argument(
        "--preset",
        default=None,
        help="preset of the weathers (rain: light moderate heavy paper; snow: light heavy paper; "
        "fog: light moderate dense paper)",
    )
    parser.add_argument("--rate", type=float, default=None, help="rain/snow rate in mm/h (liquid water)")
    parser.add_argument("--count", type=int, default=None, help="fixed particle count instead of a rate")
    parser.add_argument(
        "--visibility",
        type=float,
        default=None,
        help="fog visibility in metres (beta = 2.996 / V); with rain/snow: the haze",
    )
    parser.add_argument("--fog-density", type=float, default=None, help="fog extinction beta in 1/m")
    parser.add_argument("--fog-color", default=None, help="fog color R,G,B in [0, 1]")
    parser.add_argument(
        "--fog-mode",
        choices=("exact", "postprocess"),
        default="exact",
        help="per-Gaussian Beer-Lambert (exact) or the paper's depth-map post-process",
    )
    parser.add_argument("--wind", default=None, help="wind MAGNITUDE,TILT,AZIMUTH (m/s, degrees, degrees)")
    parser.add_argument(
        "--exposure", type=float, default=None, help="camera exposure in seconds (rain streaks)"
    )
    parser.add_argument("--seed", type=int, default=0, help="particle seed")
    add_frame_and_size_arguments(parser, size_help="size of the rendered frames (default: the method's own, "
                                                   "as `run`: 480x270 for 1920x1080 with lidar-init)")
    parser.add_argument("--voxel", type=float, default=None,
                        help="voxel size of the lidar initialisation (m; default: the method's, 0.2)")
    parser.add_argument(
        "--init-frames", default=None, help="frames whose lidar sweeps build the scene (default: all)"
    )
    parser.add_argument(
        "--method", default="lidar-init", type=method_name,
        help="runnable method drawing physics weather on a reconstructed scene (default: lidar-init)",
    )
    parser.add_argument("--no-video", action="store_true", help="do not write the mp4")
    parser.add_argument(
        "--overwrite", action="store_true", help="replace a folder rendered with other settings"
    )
    add_offline_argument(parser)
    add_progress_argument(parser)
    add_method_options(parser)


def parse_frames(frames: tuple[int, ...] | None, n: int) -> list[int]:
    """The frames of ``--frames`` (all when not given), checked against a scene of ``n`` frames.

    Raises
    ------
    InputError
        On an index outside [0, n).
    """
    if frames is None:
        return list(range(n))
    bad = [k for k in frames if not 0 <= k < n]
    if bad:
        raise InputError(frames_outside(bad, n, option="--frames"))
    return sorted(frames)


def _floats(text: str | None, count: int, option: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise InputError(f"{option}: expected {count} comma-separated numbers, got {text!r}")
    return values


def _weather(args: argparse.Namespace, kind: str) -> Any:
    """The physics :class:`Weather` of ``kind`` the weather options of ``args`` describe.

    Raises
    ------
    InputError
        On malformed ``--wind``/``--fog-color`` or Weather fields ``kind`` refuses (a preset it lacks).
    """
    from wcbench.reference_model.weather.conditions import Weather
    from wcbench.reference_model.weather.particles import Wind

    wind = _floats(args.wind, 3, "--wind")
    fog_color = _floats(args.fog_color, 3, "--fog-color")
    try:
        return Weather(
            kind=kind,
            preset=args.preset,
            rate_mm_h=args.rate,
            count=args.count,
            visibility_m=args.visibility,
            fog_density=args.fog_density,
            fog_color=fog_color,  # type: ignore[arg-type]
            wind=Wind(*wind) if wind else Wind(),
            seed=args.seed,
            exposure_s=args.exposure,
            fog_mode=args.fog_mode,
        )
    except ValueError as exc:
        raise InputError(f"weather {kind}: {exc}") from None


def _weathers(args: argparse.Namespace) -> list[str]:
    """The weathers of ``--weathers`` (or the deprecated ``--weather``).

    Raises
    ------
    InputError
        When none is given; UnknownNameError on an unknown weather.
    """
    kinds = weathers_from(args.weathers)
    if not kinds:
        raise InputError(f"--weathers is required: one or more of {', '.join(WEATHERS)}, e.g. --weathers rain")
    return list(dict.fromkeys(kinds))


#: The weather options of ``render`` (any of them given: the weathers are built from them).
_WEATHER_FLAGS = ("preset", "rate", "count", "visibility", "fog_density", "fog_color", "wind", "exposure")


def _weather_flags(args: argparse.Namespace) -> list[str]:
    """The weather options ``args`` give, spelled as on the command line (``--preset``)."""
    given = [f"--{flag.replace('_', '-')}" for flag in _WEATHER_FLAGS if getattr(args, flag) is not None]
    return given + (["--fog-mode"] if args.fog_mode != "exact" else [])


def _method_options(args: argparse.Namespace, n_frames: int) -> dict[str, Any]:
    """Options of the method: the physics of the weathers (``"auto"`` when no weather option is
    given, as ``run`` renders them), and the scene settings that were given."""
    options: dict[str, Any] = {"physics": {kind: _weather(args, kind) for kind in _weathers(args)
                                           if kind != "clear"} if _weather_flags(args) else "auto"}
    if args.voxel is not None:
        options["voxel_m"] = args.voxel
    if args.init_frames is not None:
        options["init_frames"] = parse_frames(tuple(parse_frame_spec(args.init_frames)), n_frames)
    return options


def run(args: argparse.Namespace) -> int:
    """Render every selected scene through the units of work ``run`` uses; return 0."""
    from wcbench.core.models.fetch import fetch_missing, is_offline
    from wcbench.core.storage import check_writable_folder
    from wcbench.methods import get_method, method_options, renamed_method_options, validate_method_options
    from wcbench.methods.weather_spec import OPTION
    from wcbench.scenes.sets import data_root_from, resolve_scenes
    from wcbench.units import RenderSettings, WorkUnit

    get_method(args.method)  # an unknown name fails before any scene is loaded
    if OPTION not in method_options(args.method):  # render hands the --weathers physics to the method's option
        raise InputError(f"--method {args.method}: method {args.method!r} takes no option {OPTION}: render draws "
                         f"the --weathers physics with a method that takes it (see `wcbench methods show NAME`)")
    raw = method_options_from(args)
    own = {OPTION: "auto", **({"voxel_m": args.voxel} if args.voxel is not None else {}),
           **({"init_frames": []} if args.init_frames is not None else {})}  # render's own, set per scene
    renamed = renamed_method_options(args.method)
    clash = sorted(key for key in raw if renamed.get(key, key) in own)  # named as given (an old name too)
    if clash:
        raise InputError(f"--method-option {', '.join(clash)}: set by render's own options "
                         "(--weathers/--preset..., --voxel, --init-frames)")
    given = checked_method_options(args, args.method, raw)
    validate_method_options(args.method, {**own, **given})  # every option checked before any scene is loaded
    kinds = _weathers(args)
    flags = _weather_flags(args)
    if flags and kinds == ["clear"]:  # said here, not as the physics of a weather nobody asked for
        raise InputError(f"{', '.join(flags)}: --weathers clear has no weather to set; the weather options "
                         "apply to rain, snow and fog")
    for kind in kinds:  # bad weather options fail before any scene is loaded or folder made
        _weather(args, kind)
    check_writable_folder(args.out)
    size = size_request_from(args)
    settings_base = {"seed": args.seed, "overwrite": args.overwrite, "video": not args.no_video,
                     "show_progress": not args.no_progress}
    tried: set[str] = set()
    for ref in resolve_scenes(args.scenes, data_root=data_root_from(args.data_root)):
        scene = ref.load()
        options = _method_options(args, len(scene))
        method = get_method(args.method, **options, **given)
        method.request_size(size)  # type: ignore[attr-defined]  # runnable: the unit renders it
        # the weights the method reads, fetched before it trains as `run` and `train` fetch them: a model
        # trained without its content loss here would be another model than the one `run` trains
        needed = set(getattr(method, "required_models", tuple)()) - tried
        if needed:
            fetch_missing(sorted(needed), offline=is_offline(args.offline))
            tried |= needed
        settings = RenderSettings(frames=tuple(parse_frames(args.frames, len(scene))), **settings_base)
        for kind in kinds:
            unit = WorkUnit(method, scene, kind, Path(args.out) / method.info.name / scene.id)
            info = unit.render(settings)
            print(
                f"{info['status']}: {unit.root / unit.weather} ({len(info['frames'])} frames, "
                f"{info['timings']['median_frame_ms']:.1f} ms/frame median)"
            )
    return 0
