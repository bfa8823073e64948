"""Render a scene under physics-driven weather, before any training.

The scene is the lidar initialisation of the reference model (static Gaussians plus one rigid
node per moving object, colored from the images); rain and snow particles are rasterized with it
and fog is composed on top (DESIGN §7). Frames go to the prediction layout
``OUT/<method>/<scene>/<weather>/{frame:03d}.png`` with an ``info.json`` (method, version,
parameters, timings, per-frame sha256), plus ``OUT/<method>/<scene>/<weather>.mp4`` for a sequence.

Examples::

    wcbench render --scenes pandaset_002 --weather rain --preset heavy --out renders
    wcbench render --scenes ../shared/data/pandaset_002 --weather fog --visibility 60 --out renders
    wcbench render --scenes pandaset_002 --weather snow --wind 4,20,30 --frames 0-9 --out renders

A finished folder rendered with the same settings is left alone; one rendered with other settings
is kept unless ``--overwrite``. A killed render resumes (frames are pure functions of the seed).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

HELP = "render a scene under rain, snow or fog (lidar-initialised Gaussians + weather physics)"

#: Bumped when the rendering of an unchanged input changes.
RENDER_VERSION = "1"
_STATE_FILE = ".render_state.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``wcbench render``."""
    from wcbench.cli.common import add_progress_argument, add_scene_arguments

    add_scene_arguments(parser)
    parser.add_argument("--out", type=Path, required=True, help="output root of the prediction layout")
    parser.add_argument("--weather", required=True, choices=("clear", "rain", "snow", "fog"))
    parser.add_argument(
        "--preset",
        default=None,
        help="preset of the weather (rain: light moderate heavy paper; snow: light heavy paper; "
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
    parser.add_argument("--frames", default=None, help="frames to render: 17, 0-9, 0,5,10 (default: all)")
    size = parser.add_mutually_exclusive_group()
    size.add_argument(
        "--scale",
        type=float,
        default=None,
        help="resolution as a fraction of the scene's (default 0.25: 480x270 for 1920x1080)",
    )
    size.add_argument("--width", type=int, default=None, help="output width in px (with --height)")
    parser.add_argument("--height", type=int, default=None, help="output height in px (with --width)")
    parser.add_argument("--voxel", type=float, default=0.2, help="voxel size of the lidar initialisation (m)")
    parser.add_argument(
        "--init-frames", default=None, help="frames whose lidar sweeps build the scene (default: all)"
    )
    parser.add_argument(
        "--method", default="lidar_init", help="method name in the output layout (default: lidar_init)"
    )
    parser.add_argument("--no-video", action="store_true", help="do not write the mp4")
    parser.add_argument(
        "--overwrite", action="store_true", help="replace a folder rendered with other settings"
    )
    add_progress_argument(parser)


def parse_frames(spec: str | None, n: int) -> list[int]:
    """Frame indices of ``--frames`` (``17``, ``0-9``, ``0,5,10``; ranges inclusive), sorted.

    Raises
    ------
    InputError
        On a malformed spec or an index outside [0, n).
    """
    from wcbench.errors import InputError

    if spec is None:
        return list(range(n))
    out: set[int] = set()
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                out.update(range(lo, hi + 1))
            else:
                out.add(int(part))
        except ValueError:
            raise InputError(f"--frames: cannot parse {part!r}; use e.g. 17, 0-9 or 0,5,10") from None
    bad = sorted(k for k in out if not 0 <= k < n)
    if bad:
        raise InputError(f"--frames: {bad} outside the scene's frames 0-{n - 1}")
    if not out:
        raise InputError(f"--frames: {spec!r} selects no frame")
    return sorted(out)


def _floats(text: str | None, count: int, option: str) -> tuple[float, ...] | None:
    from wcbench.errors import InputError

    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise InputError(f"{option}: expected {count} comma-separated numbers, got {text!r}")
    return values


def _weather(args: argparse.Namespace) -> Any:
    from wcbench.errors import InputError
    from wcbench.reference_model.particles import Wind
    from wcbench.reference_model.weather import Weather

    wind = _floats(args.wind, 3, "--wind")
    fog_color = _floats(args.fog_color, 3, "--fog-color")
    try:
        return Weather(
            kind=args.weather,
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
        raise InputError(f"weather: {exc}") from None


def _resolution(args: argparse.Namespace, width: int, height: int) -> tuple[int, int]:
    from wcbench.errors import InputError

    if args.width is not None or args.height is not None:
        if args.width is None or args.height is None or args.width < 1 or args.height < 1:
            raise InputError("--width and --height go together and must be positive")
        return int(args.width), int(args.height)
    scale = 0.25 if args.scale is None else float(args.scale)
    if not 0 < scale <= 4:
        raise InputError(f"--scale must be in (0, 4], got {scale}")
    return max(1, round(width * scale)), max(1, round(height * scale))


def run(args: argparse.Namespace) -> int:
    """Render every selected scene; return 0."""
    from wcbench.scene_sets import data_root_from, resolve_scenes

    weather = _weather(args)
    refs = resolve_scenes(args.scenes, data_root=data_root_from(args.data_root))
    for ref in refs:
        scene = ref.load()
        info = render_scene(scene, weather, args)
        print(
            f"{info['status']}: {info['folder']} ({len(info['frames'])} frames, "
            f"{info['timings']['median_frame_ms']:.1f} ms/frame median)"
        )
    return 0


def render_scene(scene: Any, weather: Any, args: argparse.Namespace) -> dict[str, Any]:
    """Render the selected frames of one scene.

    Returns the ``info.json`` content plus ``status`` ("rendered" or "up to date") and ``folder``.
    """
    import json

    import numpy as np

    from wcbench import __version__
    from wcbench.errors import InputError, ResultsExistError
    from wcbench.image_io import to_uint8, write_mp4, write_png
    from wcbench.predictions import INFO_FILE, canonical_frame_path
    from wcbench.progress import progress
    from wcbench.reference_model.lidar_init import estimate_sky_color, init_scene_from_lidar
    from wcbench.reference_model.weather import WeatherRenderer, camera_velocity, scale_camera
    from wcbench.storage import atomic_write_json, sha256_file, sha256_json
    from wcbench.timing import FrameTimer

    n = len(scene.frames)
    frames = parse_frames(args.frames, n)
    init_frames = parse_frames(args.init_frames, n) if args.init_frames else None
    width, height = _resolution(args, *scene.image_size)
    out_dir = Path(args.out) / args.method / scene.id / weather.kind
    video_path = out_dir.parent / f"{weather.kind}.mp4"
    init_options = {"voxel_m": float(args.voxel), "frames": init_frames, "rigid_nodes": True}
    parameters = {
        "weather": weather.to_json(),
        "resolution": [width, height],
        "frames": frames,
        "init": init_options,
    }
    key = sha256_json(
        {
            "method": args.method,
            "version": RENDER_VERSION,
            "scene": scene.id,
            "parameters": parameters,
            "sources": [str(f.image_path) for f in scene.frames],
        }
    )

    info_path = out_dir / INFO_FILE
    if info_path.is_file():
        old = json.loads(info_path.read_text(encoding="utf-8"))
        if old.get("key") == key and all(
            (out_dir / f["file"]).is_file() and sha256_file(out_dir / f["file"]) == f["sha256"]
            for f in old.get("frames", [])
        ):
            return {**old, "status": "up to date", "folder": str(out_dir)}
        if not args.overwrite:
            raise ResultsExistError(
                f"{out_dir}: holds a finished render with other settings (method {old.get('method')!r}, "
                f"parameters {old.get('parameters', {}).get('weather')}); pass --overwrite to replace it "
                "or choose another --out"
            )
    state_path = out_dir / _STATE_FILE
    state: dict[str, Any] = {"key": key, "frames": {}}
    if state_path.is_file():
        try:
            loaded = json.loads(state_path.read_text(encoding="utf-8"))
            if loaded.get("key") == key:
                state = loaded
        except json.JSONDecodeError:
            pass  # never torn (atomic writes); an edited file is ignored
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.overwrite:
        for stale in out_dir.glob("*.png"):
            if stale.name not in {canonical_frame_path(out_dir, k).name for k in frames}:
                stale.unlink()

    try:
        gaussians = init_scene_from_lidar(scene, voxel_m=args.voxel, frames=init_frames)
    except ValueError as exc:
        raise InputError(f"{scene.root}: cannot initialise Gaussians from lidar: {exc}") from None
    background = estimate_sky_color(scene)
    first = scene.frames[0].camera
    renderer = WeatherRenderer(
        gaussians.static,
        weather,
        up=scene.up,
        heading=first.camera_to_world[:3, 2],
        anchor=first.center,
        background=background,
    )
    centers = np.stack([f.camera.center for f in scene.frames])
    times = np.array([f.timestamp for f in scene.frames], np.float64)
    timer = FrameTimer(warmup=1)
    frame_infos: dict[int, dict[str, Any]] = {}
    images: dict[int, np.ndarray] = {}
    for k in progress(
        frames,
        desc=f"render {scene.id} {weather.kind}",
        total=len(frames),
        enabled=not args.no_progress and len(frames) > 1,
    ):
        path = canonical_frame_path(out_dir, k)
        done = state["frames"].get(str(k))
        if done and path.is_file() and sha256_file(path) == done["sha256"]:
            timer.frame_ms.append(done["ms"])
            frame_infos[k] = done["info"]
            continue
        cam = scale_camera(scene.frames[k].camera, width, height)
        with timer.frame():
            frame = renderer.render(
                cam,
                float(times[k] - times[0]),
                camera_velocity=camera_velocity(centers, times, k),
                gaussians=gaussians.at_frame(k),
            )
            image = to_uint8(frame.image)
        write_png(path, image)
        images[k] = image
        frame_infos[k] = {**frame.info, "timings_ms": frame.timings_ms}
        state["frames"][str(k)] = {
            "sha256": sha256_file(path),
            "ms": timer.frame_ms[-1],
            "info": frame_infos[k],
        }
        atomic_write_json(state_path, state)

    if len(frames) > 1 and not args.no_video:
        from wcbench.image_io import read_rgb8

        seq = [images[k] if k in images else read_rgb8(canonical_frame_path(out_dir, k)) for k in frames]
        fps = _frame_rate(times[frames])
        write_mp4(video_path, seq, fps=fps)
    info = {
        "method": args.method,
        "version": f"{__version__}+render{RENDER_VERSION}",
        "scene": scene.id,
        "weather": weather.kind,
        "seed": int(weather.seed),
        "key": key,
        "parameters": {
            **parameters,
            "renderer": renderer.info(),
            "scene_gaussians": {
                "static": len(gaussians.static),
                "rigid_nodes": len(gaussians.nodes),
                "total": len(gaussians),
            },
        },
        "timings": timer.summary(width=width, height=height),
        "frames": [
            {
                "file": canonical_frame_path(out_dir, k).name,
                "index": k,
                "sha256": state["frames"][str(k)]["sha256"],
                "info": frame_infos[k],
            }
            for k in frames
        ],
        "video": video_path.name if video_path.is_file() and len(frames) > 1 and not args.no_video else None,
    }
    atomic_write_json(info_path, info)
    state_path.unlink(missing_ok=True)
    return {**info, "status": "rendered", "folder": str(out_dir)}


def _frame_rate(times: Any) -> float:
    """Frames per second of a sequence from its timestamps (10 when they are not increasing)."""
    import numpy as np

    dt = np.diff(np.asarray(times, np.float64))
    if len(dt) == 0 or not np.all(dt > 0):
        return 10.0
    return float(min(max(1.0 / np.median(dt), 1.0), 120.0))
