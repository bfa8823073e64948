"""Benchmark suite ``streets``: does the weather hold on streets the project has not tuned on?

On every real scene beside the data (the four PandaSet cameras of ``pandaset_002``) and on the
harder synthetic street ``synth_hard_1`` (docs/design.md §3), this suite measures what a viewer
sees at once when the weather breaks (docs/design.md §7, "Scene analysis"; findings in
docs/findings.md):

* ``sky_<scene>``: the sky segmentation against the hand-drawn sky masks of three frames per
  scene (``tests/data/sky_masks/`` of the checkout or ``$WCBENCH_SKY_MASKS``, rules in its
  README): intersection over union of the pixels no trusted lidar return lands in (its ``error``;
  those pixels are void: a wire or a far mast the lidar hits covers a fraction of its pixel, which
  the masks call sky when under one half, the segmentation never), and of all pixels; the
  analysis' time.
* ``editor_<scene>`` and ``weathercity_<scene>`` (the latter outside ``--quick``: the ``default``
  profile's model, trained or loaded from the cache): over every frame of rain, snow and fog,
  **lidar-hit pixels shown as sky** (the sky's share of a pixel at least one half where a return
  lands: the editor's matte, WeatherCity's 1 - accumulated opacity), counted twice, for the returns
  the analysis trusts (:func:`~wcbench.reference_model.scene_analysis.analysis.solid_masks`: the
  frame's own sweep, the static returns of sweeps within two frames and every static return beyond
  20 m) and for every static return of every sweep, and of the trusted ones those with no pixel
  within one shown as anything but sky (:func:`hits_as_sky_apart`: the structure lost, not its edge
  drawn a pixel off the return); **clear-sky blue left** (pixels of the
  hand-drawn sky of the three masked frames that are of the clear sky's blue, CIELAB b* < -12,
  L* > 45, -20 < a* < 5, in the raw frame and still are; a blue sign or car keeps its paint); the
  **temporal flicker ratio** (mean absolute difference of consecutive frames, edited over raw); and
  the editor's milliseconds per 480 x 270 frame as a run of one weather pays them, the frame's
  surface maps included (median over frames and weathers, per weather, and the slowest frame; the
  scene's set-up separately).
* ``insert_<source>_<id>_into_<target>`` (outside ``--quick``, when both scenes ran): the README's
  insertion across scenes (:data:`INSERT`): the carried object's mean clear-colour error against
  its own model's (its ``error``; also the exemplars' before the refinement), the time to carry it,
  and the texture its other weathers add over its clear colours where it is opaque in one frame
  (the mean absolute Laplacian of the luminance, weather over clear; the object alone, no particles
  nor haze), with its Gaussians' 16 exemplars averaged and with one (docs/design.md §7, "Object
  editing").
* ``remove_<scene>`` (outside ``--quick``): :data:`REMOVE`, the README's removal, on the trained
  model, with the background it leaves filled (:mod:`wcbench.reference_model.editing.vacated`) and
  as trained: in every frame's clear render, over the removed nodes' silhouettes (the hull of their
  Gaussians), the share of the pixels below the horizon where the background is see-through
  (accumulated opacity under one half: the sky shows there) and the share whose colour stayed
  nearer the car's there (the unedited render's) than the mean colour of a ring 8 px wide around
  the silhouettes (its ``error``, filled); the Gaussians refilled, the ground laid and the time.
* ``synth_hard``: on the harder truth, the editor's and the raw frames' PSNR against the truth per
  weather, over all pixels and inside the clear frames' cast shadows (``truth/masks/shadow``);
  outside ``--quick`` also WeatherCity's main job (``quick`` profile) there, PSNR and LPIPS per
  weather next to the raw frames'; with the analysis' sun and lidar reach.

Times are from the machine it runs on; they move with its load (the report records it).
"""

from __future__ import annotations

import math
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.methods import get_method
from wcbench.methods.physical_editor import raw_frame
from wcbench.methods.scene_training import train_scene
from wcbench.methods.weather_spec import resolve_physics
from wcbench.methods.weathercity import WeatherCityMethod, scene_ground
from wcbench.metrics.temporal.flicker import temporal_flicker
from wcbench.reference_model.appearance.editor import WeatherEditor
from wcbench.reference_model.editing.edits import parse_edits, placement_for
from wcbench.reference_model.editing.transfer import box_heights, carried_features, placed_objects
from wcbench.reference_model.editing.vacated import object_cover, vacated_background
from wcbench.reference_model.model.scene_model import BACKGROUND, Placement
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.rasterizer import rasterize_image
from wcbench.reference_model.scene_analysis.analysis import analyse_scene, any_sweep_masks
from wcbench.reference_model.scene_analysis.views import resample_mask
from wcbench.reference_model.training.config import make_config
from wcbench.reference_model.weather.renderer import scale_camera
from wcbench.scenes.loaders import load_scene
from wcbench.scenes.sets import get_scene_set
from wcbench.units import RenderSettings

__all__ = ["REAL_SCENES", "SKY_MASKS_ENV", "clear_sky_blue", "hits_as_sky_apart", "run", "sky_masks_folder"]

#: The real scenes the suite looks for under the data root.
REAL_SCENES = ("pandaset_002", "pandaset_002_back", "pandaset_002_front_right", "pandaset_002_right")
EDITED = ("rain", "snow", "fog")
#: Frames of the hand-drawn sky masks.
MASK_FRAMES = (5, 15, 25)
#: The README's removal: every car of a camera's model.
REMOVE: dict[str, Any] = {"scene": "pandaset_002", "edit": "remove class=Car"}
#: The README's insertion across scenes: a car of one camera's model set down on another's street
#: (``insert scene=SOURCE id=ID at=X,Y,YAW``), looked at in one frame.
INSERT: dict[str, Any] = {"source": "pandaset_002_back", "id": "42", "target": "pandaset_002",
                          "at": (12.46, 16.71, 137.8), "frame": 20}


#: Where the hand-drawn sky masks are, when not in the checkout the package runs from.
SKY_MASKS_ENV = "WCBENCH_SKY_MASKS"


def sky_masks_folder() -> Path:
    """The hand-drawn sky masks (test data, not part of the installed package): ``$WCBENCH_SKY_MASKS``
    when set, else ``tests/data/sky_masks`` of the source checkout the package runs from (an
    editable install), else of the working directory (an installed package run from a clone)."""
    given = os.environ.get(SKY_MASKS_ENV)
    if given:
        return Path(given)
    checkout = Path(__file__).resolve().parents[2] / "tests" / "data" / "sky_masks"
    return checkout if checkout.is_dir() else Path.cwd() / "tests" / "data" / "sky_masks"


def clear_sky_blue(image: np.ndarray) -> np.ndarray:
    """[H, W] bool: pixels of the clear sky's blue (CIELAB b* < -12, L* > 45, -20 < a* < 5) in a
    display-RGB image [H, W, 3] in [0, 1]."""
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    return (lab[..., 2] < -12.0) & (lab[..., 0] > 45.0) & (lab[..., 1] > -20.0) & (lab[..., 1] < 5.0)


def _iou(a: np.ndarray, b: np.ndarray, where: np.ndarray | None = None) -> tuple[int, int]:
    """(intersection, union) of two masks, over ``where``."""
    if where is not None:
        a, b = a & where, b & where
    return int((a & b).sum()), int((a | b).sum())


def _sky_case(name: str, scene: Any, masks: Path) -> BenchCase:
    start = time.perf_counter()
    analysis = analyse_scene(scene)
    seconds = time.perf_counter() - start
    per_frame, inter, union, inter_out, union_out = {}, 0, 0, 0, 0
    for k in MASK_FRAMES:
        path = masks / name / f"{k:03d}.png"
        truth = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if truth is None:
            raise RuntimeError(f"{path}: a hand-drawn sky mask was expected")
        t = resample_mask(truth > 127, analysis.views.size)
        p = analysis.sky.masks[k]
        i, u = _iou(t, p)
        io, uo = _iou(t, p, ~analysis.solid[k])
        inter, union, inter_out, union_out = inter + i, union + u, inter_out + io, union_out + uo
        per_frame[str(k)] = {"iou": round(i / u, 4) if u else None,
                             "iou_outside_lidar": round(io / uo, 4) if uo else None,
                             "false_sky_px": int((p & ~t).sum()), "missed_sky_px": int((t & ~p).sum()),
                             "truth_sky_fraction": round(float(t.mean()), 4)}
    iou = inter / union if union else 1.0
    iou_out = inter_out / union_out if union_out else 1.0
    # the pixels a trusted return lands in are void, as an ignore label is in segmentation benchmarks:
    # they are never sky by the lidar, and a thin structure in them is sky by the masks' coverage rule
    # (docs/design.md §7, "Sky"); `iou` keeps every pixel for comparison
    return BenchCase(name=f"sky_{name}", knob="scene", value=name, time_ms=1e3 * seconds, error=1.0 - iou_out,
                     error_unit="1 - IoU vs hand-drawn masks, lidar-hit pixels void",
                     extra={"iou": round(iou, 4), "iou_outside_lidar": round(iou_out, 4), "frames": per_frame,
                            "analysis": analysis.facts})


def _every_sweep_hits(analysis: Any) -> list[np.ndarray]:
    """Per frame, the pixels every static return of every sweep (and the frame's own) lands in (the
    analysis' own :func:`~wcbench.reference_model.scene_analysis.analysis.any_sweep_masks`)."""
    return any_sweep_masks(analysis.views, analysis.returns)


def _hand_sky(name: str, size: tuple[int, int], n_frames: int) -> list[np.ndarray]:
    """Per frame, the hand-drawn sky at ``size`` (all false on the frames without a mask)."""
    out = [np.zeros((size[1], size[0]), bool) for _ in range(n_frames)]
    for k in MASK_FRAMES:
        mask = cv2.imread(str(sky_masks_folder() / name / f"{k:03d}.png"), cv2.IMREAD_GRAYSCALE)
        if mask is not None and k < n_frames:
            out[k] = resample_mask(mask > 127, size)
    return out


def hits_as_sky_apart(sky: np.ndarray, hits: np.ndarray) -> np.ndarray:
    """[H, W] bool: the lidar-hit pixels (``hits`` [H, W] bool) shown as sky (``sky`` [H, W] bool)
    with no pixel within one (their 3 x 3 neighbourhood) shown as anything else: the structure the
    return hit is lost, not its edge drawn a pixel off the return (the lidar's beam and its
    registration to the camera put a thin structure's returns up to a pixel beside it, where the
    image shows the sky: docs/findings.md)."""
    sky = np.asarray(sky, bool)
    beside = cv2.dilate((~sky).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return sky & np.asarray(hits, bool) & ~beside


def _weather_checks(raws: list[np.ndarray], edits: dict[str, list[np.ndarray]], skies: list[np.ndarray],
                    solid: list[np.ndarray], every: list[np.ndarray], hand_sky: list[np.ndarray]) -> dict[str, Any]:
    """Lidar-hit pixels shown as sky, clear-sky blue left in the hand-drawn sky and flicker ratios of
    edited frames."""
    raw_stack = np.stack(raws)
    raw_flicker = temporal_flicker(raw_stack)
    blue_raw = [clear_sky_blue(r) & h for r, h in zip(raws, hand_sky)]
    out: dict[str, Any] = {
        "lidar_hits_as_sky": int(sum((s & h).sum() for s, h in zip(skies, solid))),
        "lidar_hits_as_sky_apart": int(sum(hits_as_sky_apart(s, h).sum() for s, h in zip(skies, solid))),
        "lidar_hits_as_sky_every_sweep": int(sum((s & h).sum() for s, h in zip(skies, every))),
        "frames_with_lidar_hits_as_sky": int(sum(bool((s & h).any()) for s, h in zip(skies, solid))),
    }
    for w, seq in edits.items():
        out[f"clear_sky_blue_left_{w}"] = int(sum((b & clear_sky_blue(e)).sum() for b, e in zip(blue_raw, seq)))
        out[f"flicker_ratio_{w}"] = round(temporal_flicker(np.stack(seq)) / raw_flicker, 4) if raw_flicker > 0 else None
    out["clear_sky_blue_in_raw_sky"] = int(sum(b.sum() for b in blue_raw))
    return out


def _editor_case(name: str, scene: Any) -> tuple[BenchCase, Any]:
    analysis = analyse_scene(scene)
    start = time.perf_counter()
    editor = WeatherEditor(scene, analysis=analysis)
    setup = time.perf_counter() - start
    size = analysis.views.size
    physics = resolve_physics(scene, "auto")
    raws = [raw_frame(scene, k, size) for k in range(len(scene))]
    cameras = [scale_camera(scene.frames[k].camera, *size) for k in range(len(scene))]
    edits: dict[str, list[np.ndarray]] = {w: [] for w in EDITED}
    times: dict[str, list[float]] = {w: [] for w in EDITED}
    # one weather after the other, as a run of one weather edits: every frame pays for its surface
    # maps (the editor keeps only the last view's), the time a user asking for that weather waits
    for w in EDITED:
        for k, (raw, camera) in enumerate(zip(raws, cameras)):
            t0 = time.perf_counter()
            image, _ = editor.edit(raw, k, camera, physics[w])
            times[w].append(1e3 * (time.perf_counter() - t0))
            edits[w].append(image)
    skies = [editor.maps(k, camera, raw, fields=()).sky_alpha >= 0.5
             for k, (raw, camera) in enumerate(zip(raws, cameras))]
    checks = _weather_checks(raws, edits, skies, analysis.solid, _every_sweep_hits(analysis),
                             _hand_sky(name, size, len(scene)))
    every = [t for w in EDITED for t in times[w]]
    ms = statistics.median(every)
    return BenchCase(name=f"editor_{name}", knob="scene", value=name, time_ms=ms, error=None, error_unit="-",
                     extra={"ms_per_frame_median": round(ms, 1), "ms_per_frame_mean": round(float(np.mean(every)), 1),
                            **{f"ms_per_frame_median_{w}": round(statistics.median(times[w]), 1) for w in EDITED},
                            "ms_per_frame_max": round(max(every), 1),
                            "setup_s": round(setup, 2), "size": list(size), **checks}), analysis


def _weathercity_case(name: str, scene: Any, analysis: Any) -> tuple[BenchCase, Any]:
    start = time.perf_counter()
    config = make_config("default")
    method = WeatherCityMethod(profile="default")
    model, _, facts = train_scene(scene, config, physics=method.training_physics(scene), show_progress=False,
                                  log=lambda *_: None)
    method.use_model(scene, model, facts)
    train_s = time.perf_counter() - start
    size = analysis.views.size
    raws, skies = [], []
    edits: dict[str, list[np.ndarray]] = {w: [] for w in EDITED}
    with torch.no_grad():
        for k in range(len(scene)):
            raws.append(raw_frame(scene, k, size))
            cam = scale_camera(scene.frames[k].camera, *size)
            grid = model.sky.grid(torch.from_numpy(view_directions(cam.camera_to_world, cam.K, *size)))
            render = model.render(k, np.asarray(cam.world_to_camera), np.asarray(cam.K), size[0], size[1], ["clear"],
                                  sky_grid=grid)
            skies.append(1.0 - render.alpha.numpy() >= 0.5)
    for w in EDITED:
        method.prepare(scene, w, seed=0)
        for k in range(len(scene)):
            image, _ = method.render_frame(scene, w, k, seed=0)
            edits[w].append(cv2.resize(image, size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
                            if (image.shape[1], image.shape[0]) != size else image.astype(np.float32) / 255.0)
    checks = _weather_checks(raws, edits, skies, analysis.solid, _every_sweep_hits(analysis),
                             _hand_sky(name, size, len(scene)))
    return BenchCase(name=f"weathercity_{name}", knob="scene", value=name, time_ms=1e3 * train_s, error=None,
                     error_unit="-", extra={"holdout": facts.get("holdout"), **checks,
                                            "train_seconds": facts.get("train_seconds")}), model


def _texture(image: np.ndarray, mask: np.ndarray) -> float:
    """Mean absolute Laplacian of the luminance of ``image`` [H, W, 3] over ``mask``."""
    gray = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2GRAY)
    return float(np.abs(cv2.Laplacian(gray, cv2.CV_32F))[mask].mean())


def _insert_case(target: Any, model: Any, sources: dict[str, Any]) -> BenchCase:
    """:data:`INSERT`, the README's insertion: the carried object's fit, and how much texture its
    decoded weathers add over its clear colours where it is opaque in frame 20 (the object alone,
    480 x 270, no particles nor haze), with the 16 exemplars a Gaussian averages and with one."""
    source_name, track, at = INSERT["source"], INSERT["id"], INSERT["at"]
    edits = parse_edits(f"insert scene={source_name} id={track} at={','.join(str(v) for v in at)}")
    start = time.perf_counter()
    objects, keys, facts = placed_objects(edits, model, n_frames=len(target), up=np.asarray(target.up, np.float64),
                                          ground=scene_ground(target), sources=sources)
    seconds = time.perf_counter() - start
    placed = model.with_objects(objects)
    key, (fit,) = keys[0], facts
    cam = scale_camera(target.frames[INSERT["frame"]].camera, 480, 270)
    grid = placed.sky.grid(torch.from_numpy(view_directions(cam.camera_to_world, cam.K, 480, 270)))
    alone = Placement(hidden={BACKGROUND} | {k for k in placed.objects() if k != key})
    ratios: dict[str, Any] = {}
    for label, neighbours in (("", 16), ("_one_exemplar", 1)):
        if neighbours != 16:
            obj = sources[source_name].objects()[f"rigid:{track}"]
            with torch.no_grad():
                colors = sources[source_name].decoders(obj.gaussians.features, ["clear"])
            feats, _ = carried_features(colors, box_heights(obj), model, class_name=obj.class_name,
                                        neighbours=neighbours)
            with torch.no_grad():
                placed.objects()[key].gaussians.features.copy_(feats)
        with torch.no_grad():
            out = placed.render(INSERT["frame"], np.asarray(cam.world_to_camera), np.asarray(cam.K), 480, 270,
                                ["clear", *EDITED], sky_grid=grid, placement=alone)
        opaque = cv2.erode((out.alpha.numpy() > 0.95).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        clear = _texture(out.image("clear").numpy(), opaque)
        ratios.update({f"texture_ratio_{w}{label}": round(_texture(out.image(w).numpy(), opaque) / clear, 3)
                       for w in EDITED})
        ratios[f"opaque_px{label}"] = int(opaque.sum())
    return BenchCase(name=f"insert_{source_name}_{track}_into_{target.id}", knob="scene", value=target.id,
                     time_ms=1e3 * seconds, error=fit["clear_error"], error_unit="mean |clear - own clear| in [0, 1]",
                     extra={"edit": edits[0].to_json(), "frame": INSERT["frame"], "exemplars": fit["exemplars"],
                            "clear_error_exemplars": fit["clear_error_exemplars"], "clear_error": fit["clear_error"],
                            "gaussians": fit["gaussians"], **ratios})


def _remove_case(scene: Any, model: Any) -> BenchCase:
    """:data:`REMOVE` on ``scene``'s trained ``model``: what the removal leaves in every frame's clear
    render at 480 x 270, filled and as trained (the module docstring)."""
    place = placement_for(parse_edits(REMOVE["edit"]), model.objects())
    gone_keys = sorted(place.hidden)
    size = (480, 270)
    cams = [scale_camera(f.camera, *size) for f in scene.frames]
    cameras = [(k, np.asarray(c.world_to_camera), np.asarray(c.K), c.width, c.height) for k, c in enumerate(cams)]
    up = np.asarray(scene.up, np.float64)
    start = time.perf_counter()
    filled, facts = vacated_background(model, gone_keys, cameras, up=up)
    seconds = time.perf_counter() - start
    gone = [model.objects()[k] for k in gone_keys]
    ring_kernel = np.ones((17, 17), np.uint8)
    counts = {label: {"below": 0, "see_through": 0, "pixels": 0, "car_like": 0} for label in ("filled", "as_trained")}
    with torch.no_grad():
        for k, cam in enumerate(cams):
            silhouette = np.isfinite(object_cover(gone, k, cameras[k][1], cameras[k][2], *size))
            if not silhouette.any():
                continue
            rays = view_directions(cam.camera_to_world, cam.K, *size)
            below = silhouette & (rays @ up.astype(np.float32) < 0)
            ring = cv2.dilate(silhouette.astype(np.uint8), ring_kernel).astype(bool) & ~silhouette
            grid = model.sky.grid(torch.from_numpy(rays))
            args = (k, np.asarray(cam.world_to_camera), np.asarray(cam.K), *size, ["clear"])
            car = model.render(*args, sky_grid=grid, depth=False, rasterizer=rasterize_image).images.numpy()
            for label, m in (("filled", filled), ("as_trained", model)):
                out = m.render(*args, sky_grid=grid, depth=False, rasterizer=rasterize_image, placement=place)
                image, alpha = out.images.numpy(), out.alpha.numpy()
                c = counts[label]
                c["below"] += int(below.sum())
                c["see_through"] += int((below & (alpha < 0.5)).sum())
                c["pixels"] += int(silhouette.sum())
                if ring.any():
                    around = image[ring].mean(0)
                    near_car = np.linalg.norm(image - car, axis=-1) < np.linalg.norm(image - around, axis=-1)
                    c["car_like"] += int((near_car & silhouette).sum())
    share = {label: {"see_through_below_horizon": round(c["see_through"] / max(c["below"], 1), 4),
                     "car_like": round(c["car_like"] / max(c["pixels"], 1), 4)} for label, c in counts.items()}
    return BenchCase(name=f"remove_{scene.id}", knob="scene", value=scene.id, time_ms=1e3 * seconds,
                     error=share["filled"]["car_like"], error_unit="share of the removed silhouettes' pixels nearer "
                     "the car's colour than the ring around them's", extra={
                         "edit": REMOVE["edit"], "removed_nodes": len(gone_keys), "size": list(size), **facts,
                         **{f"{key}_{label}": v for label, d in share.items() for key, v in d.items()},
                         "silhouette_px": counts["filled"]["pixels"]})


def _masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    if not mask.any():
        return None
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask].astype(np.float64)) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def _synth_hard_case(quick: bool) -> BenchCase:
    scene = get_scene_set("synth_hard_1").scenes[0].load()
    analysis = analyse_scene(scene)
    editor = WeatherEditor(scene, analysis=analysis)
    physics = resolve_physics(scene, "auto")
    size = scene.image_size
    psnr: dict[str, list[float]] = {}
    shadow: dict[str, list[float]] = {}
    for k in range(len(scene)):
        raw = raw_frame(scene, k, size)
        camera = scale_camera(scene.frames[k].camera, *size)
        mask_path = Path(scene.root) / "truth" / "masks" / "shadow" / f"{k:03d}_0.png"
        mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
        in_shadow = mask > 127 if mask is not None else np.zeros(raw.shape[:2], bool)
        for w in EDITED:
            truth = cv2.cvtColor(cv2.imread(str(scene.references[w][k])), cv2.COLOR_BGR2RGB).astype(np.float32) / 255
            edited, _ = editor.edit(raw, k, camera, physics[w])
            for who, image in (("editor", edited), ("raw", raw)):
                whole = _masked_psnr(image, truth, np.ones(raw.shape[:2], bool))
                psnr.setdefault(f"{who}_{w}", []).append(whole if whole is not None else 0.0)
                value = _masked_psnr(image, truth, in_shadow)
                if value is not None:
                    shadow.setdefault(f"{who}_{w}", []).append(value)
    extra: dict[str, Any] = {f"psnr_{k}": round(float(np.mean(v)), 3) for k, v in psnr.items()}
    extra.update({f"psnr_in_shadow_{k}": round(float(np.mean(v)), 3) for k, v in shadow.items()})
    extra["sun"] = analysis.sun.facts
    extra["lidar_reach"] = analysis.facts.get("lidar_reach")
    if not quick:
        with tempfile.TemporaryDirectory(prefix="wcbench-streets-") as tmp:
            for label, name, options in (("identity", "identity", {}), ("weathercity", "weathercity",
                                                                         {"profile": "quick"})):
                cfg = EvaluateConfig(method=name, scenes="synth_hard_1", predictions=Path(tmp) / "pred" / label,
                                     out=Path(tmp) / "res" / label, weathers=["clear", *EDITED],
                                     metrics=["psnr", "ssim", "lpips"],
                                     render=RenderSettings(seed=0, show_progress=False), show_progress=False)
                doc = evaluate(cfg, method=get_method(name, **options)).results
                for w, outs in next(iter(doc["results"].values())).items():
                    for metric in ("psnr", "lpips"):
                        extra[f"{metric}_{label}_{w}"] = outs.get(metric, {}).get("value")
                if label == "weathercity":
                    extra.update(_weathercity_shadow_psnr(Path(tmp) / "pred" / label, scene))
    return BenchCase(name="synth_hard", knob="scene", value="synth_hard_1", time_ms=None,
                     error=None, error_unit="-", extra=extra)


def _weathercity_shadow_psnr(predictions: Path, scene: Any) -> dict[str, Any]:
    """WeatherCity's PSNR inside the clear frames' cast shadows, per weather, from its rendered frames."""
    out: dict[str, Any] = {}
    for w in EDITED:
        values = []
        for k in range(len(scene)):
            frame = next(iter(predictions.rglob(f"{w}/{k:03d}.png")), None)
            mask = cv2.imread(str(Path(scene.root) / "truth" / "masks" / "shadow" / f"{k:03d}_0.png"),
                              cv2.IMREAD_GRAYSCALE)
            if frame is None or mask is None:
                continue
            image = cv2.cvtColor(cv2.imread(str(frame)), cv2.COLOR_BGR2RGB).astype(np.float32) / 255
            truth = cv2.cvtColor(cv2.imread(str(scene.references[w][k])), cv2.COLOR_BGR2RGB).astype(np.float32) / 255
            if image.shape != truth.shape:
                image = cv2.resize(image, (truth.shape[1], truth.shape[0]), interpolation=cv2.INTER_CUBIC)
            value = _masked_psnr(image, truth, mask > 127)
            if value is not None:
                values.append(value)
        out[f"psnr_in_shadow_weathercity_{w}"] = round(float(np.mean(values)), 3) if values else None
    return out


def run(*, data_root: Path | None, quick: bool = False) -> BenchReport:
    """Run the suite (see the module docstring).

    Parameters
    ----------
    data_root : Path or None
        Folder holding the real scenes (:data:`REAL_SCENES`); those missing are named in the notes.
    quick : bool
        A smoke run: the sky and editor cases of the first real scene found, the synthetic case
        without WeatherCity.

    Returns
    -------
    BenchReport
    """
    report = BenchReport(suite="streets")
    masks = sky_masks_folder()
    found = [n for n in REAL_SCENES if data_root is not None and (Path(data_root) / n / "images").is_dir()]
    missing = [n for n in REAL_SCENES if n not in found]
    if missing:
        report.stand_ins.append(f"real scenes not found under {data_root}: {', '.join(missing)}")
    if quick:
        found = found[:1]
    models: dict[str, Any] = {}
    scenes: dict[str, Any] = {}
    for name in found:
        scene = load_scene(Path(data_root) / name) if data_root is not None else None
        assert scene is not None
        if (masks / name).is_dir():
            report.cases.append(_sky_case(name, scene, masks))
        else:
            report.notes.append(f"{masks / name}: no hand-drawn sky masks; sky_{name} not measured")
        case, analysis = _editor_case(name, scene)
        report.cases.append(case)
        if not quick:
            case, models[name] = _weathercity_case(name, scene, analysis)
            report.cases.append(case)
            scenes[name] = scene
    if REMOVE["scene"] in models:
        report.cases.append(_remove_case(scenes[REMOVE["scene"]], models[REMOVE["scene"]]))
    if INSERT["source"] in models and INSERT["target"] in models:
        report.cases.append(_insert_case(scenes[INSERT["target"]], models[INSERT["target"]],
                                         {INSERT["source"]: models[INSERT["source"]]}))
    report.cases.append(_synth_hard_case(quick))
    report.notes.append("lidar_hits_as_sky counts the returns the analysis trusts (the frame's own sweep, static "
                        "returns of sweeps within two frames, every static return beyond 20 m); "
                        "lidar_hits_as_sky_every_sweep every static return of every sweep; "
                        "lidar_hits_as_sky_apart those of lidar_hits_as_sky with no pixel within one shown as "
                        "anything but sky (the structure lost, not its edge a pixel off the return)")
    return report
