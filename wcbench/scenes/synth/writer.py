"""Writing a synthetic scene in drivestudio's Waymo layout with its truth beside it, and the cache
of generated scenes, one folder per profile (docs/design.md §3)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import to_uint8
from wcbench.core.paths import cache_dir
from wcbench.core.progress import announce
from wcbench.core.storage import dumps_json
from wcbench.scenes.loaders import OPENCV_TO_WAYMO
from wcbench.scenes.scene import Camera
from wcbench.scenes.synth.content import Content, build_content
from wcbench.scenes.synth.edit_truth import read_edit_record, write_edit_truth
from wcbench.scenes.synth.geometry import rigid_transform
from wcbench.scenes.synth.layout import (
    FOCAL,
    FPS,
    GLOBAL_ORIGIN,
    HARD_SCENES,
    HEIGHT,
    MARKER,
    N_FRAMES,
    SCENES,
    SPEED,
    TRUTH_WEATHERS,
    WIDTH,
    SynthSpec,
)
from wcbench.scenes.synth.lidar import lidar_sweep
from wcbench.scenes.synth.truth import TruthRenderer, reference_model

__all__ = ["ensure_synth_1", "ensure_synth_3", "ensure_synth_hard_1", "ensure_synth_scenes", "write_synth_scene"]


def _png(path: Path, image: np.ndarray) -> None:
    """Write uint8 RGB [H, W, 3] or a uint8 mask [H, W] as PNG (OpenCV's encoder is deterministic)."""
    img = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    path.write_bytes(buf.tobytes())


def _savetxt(path: Path, values: np.ndarray) -> None:
    """A matrix as text in numpy's default format (as drivestudio writes it): fixed, so deterministic."""
    np.savetxt(path, values, fmt="%.18e")


def _dynamic_masks(content: Content, k: int, camera: Camera, lidar_world: np.ndarray, shift: np.ndarray
                   ) -> dict[str, np.ndarray]:
    """drivestudio's dynamic masks of frame ``k``: per class group, the 2D bounding rectangle of the
    projected box corners of tracked objects moving faster than 1 m/s, skipping objects with a
    corner behind the camera or without a lidar point in their box (occluded). Untracked movers
    have no box, so no mask."""
    masks = {g: np.zeros((HEIGHT, WIDTH), np.uint8) for g in ("all", "human", "vehicle")}
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    for m in content.movers:
        if not m.tracked or np.linalg.norm(m.velocity[k][:2]) <= 1.0:
            continue
        T = m.poses[k]
        local = (lidar_world - T[:3, 3]) @ T[:3, :3]
        if not np.any(np.all(np.abs(local) <= m.size / 2, axis=1)):
            continue
        corners = (signs * m.size / 2) @ T[:3, :3].T + T[:3, 3] - shift
        uv, z = camera.project(corners)
        if not np.all(z > 0):
            continue
        u = np.clip(uv[:, 0], 0, WIDTH)
        v = np.clip(uv[:, 1], 0, HEIGHT)
        if u.max() - u.min() == 0 or v.max() - v.min() == 0:
            continue
        group = "human" if m.class_name == "Pedestrian" else "vehicle"
        for g in ("all", group):
            masks[g][int(v.min()):int(v.max()), int(u.min()):int(u.max())] = 255
    return masks


def _cameras(content: Content) -> tuple[list[Camera], np.ndarray]:
    """Every frame's camera where the loaders put the scene (the first camera at the origin,
    docs/design.md §2, so a method using the same physics and seed sees the same particles), and
    the street coordinates of that origin [3]."""
    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    c2w = [e @ content.camera_to_vehicle @ OPENCV_TO_WAYMO for e in content.ego]
    shift = c2w[0][:3, 3].copy()
    cameras = []
    for k in range(N_FRAMES):
        pose = c2w[k].copy()
        pose[:3, 3] -= shift
        cameras.append(Camera(K=K, width=WIDTH, height=HEIGHT, camera_to_world=pose))
    return cameras, shift


def _extend_with_edit_truth(root: Path, spec: SynthSpec) -> None:
    """Write the editing truth (``truth/edits/``) into a complete cached scene that lacks it or has
    another version of it, leaving every other file as it is; written in a temporary folder and
    renamed into place, so a killed run leaves no half edit truth. Without torch the scene is left
    as it is (it loads without editing truth)."""
    folder = root / "truth" / "edits"
    if read_edit_record(folder) is not None:
        return
    try:
        reference_model()
    except InputError:
        return  # a cached scene loads without torch (docs/design.md §3); its edits have no truth until then
    announce(f"adding the editing truth to the synthetic scene {root} (first use only)")
    n_frames = int(json.loads((root / MARKER).read_text(encoding="utf-8"))["frames"])
    content = build_content(spec)
    cameras, shift = _cameras(content)
    times = np.arange(N_FRAMES) / FPS
    tmp = Path(tempfile.mkdtemp(prefix=".edits.", dir=root / "truth"))
    try:
        write_edit_truth(tmp, content, cameras, times, shift, TruthRenderer(content, cameras, times, shift),
                         n_frames=n_frames)
        if folder.exists() and read_edit_record(folder) is None:
            shutil.rmtree(folder)  # an older version's
        try:
            os.replace(tmp, folder)
        except OSError:
            if read_edit_record(folder) is None:  # another process won the race only if complete
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_synth_scene(root: Path, scene: int | SynthSpec, *, n_frames: int = N_FRAMES) -> dict[str, Any]:
    """Generate a synthetic scene into ``root`` in drivestudio's Waymo layout, with truth frames.

    Writes ``images/{t:03d}_0.png``, ``ego_pose/{t:03d}.txt``, ``extrinsics/0.txt``,
    ``intrinsics/0.txt``, ``lidar/{t:03d}.bin``, ``sky_masks/{t:03d}_0.png`` (when the profile ships
    them), ``dynamic_masks/{all,human,vehicle}/{t:03d}_0.png``, ``instances/instances_info.json``
    and ``frame_instances.json`` (tracked objects only), ``truth/{rain,snow,fog}/{t:03d}_0.png``,
    ``truth/masks/{sky,shadow,movers}/{t:03d}_0.png`` (when the profile has truth masks),
    ``truth/weather.json``, the editing truth ``truth/edits/`` (:mod:`.edit_truth`) and, last,
    ``synth.json`` (docs/design.md §3).

    Parameters
    ----------
    root : Path
        Folder to write into; created if missing, must hold no scene yet.
    scene : int or SynthSpec
        The scene: a number in :data:`SCENES` (v1), or any spec (:data:`HARD_SCENES`...).
    n_frames : int
        Frames to write (the first ones; fewer only for quick checks: the scene sets use all).

    Returns
    -------
    dict
        What was written: Gaussian counts (static, moving, per frame), lidar points per frame,
        pedestrian, presets (the contents of ``synth.json``).

    Raises
    ------
    InputError
        Without torch (the reference model renders the frames).
    """
    spec = SCENES[scene] if isinstance(scene, int) else scene
    profile = spec.profile
    content = build_content(spec)
    root = Path(root)
    masks = ("sky", "shadow", "movers") if profile.truth_masks else ()
    sky_masks = ("sky_masks",) if profile.sky_masks else ()
    for sub in ("images", "ego_pose", "extrinsics", "intrinsics", "lidar", *sky_masks, "dynamic_masks/all",
                "dynamic_masks/human", "dynamic_masks/vehicle", "instances", *(f"truth/{w}" for w in TRUTH_WEATHERS),
                *(f"truth/masks/{m}" for m in masks)):
        (root / sub).mkdir(parents=True, exist_ok=True)

    _savetxt(root / "intrinsics" / "0.txt", np.array([FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, 0, 0, 0, 0, 0], float))
    _savetxt(root / "extrinsics" / "0.txt", content.camera_to_vehicle)
    global_offset = rigid_transform(np.eye(3), GLOBAL_ORIGIN)
    cameras, shift = _cameras(content)
    times = np.arange(N_FRAMES) / FPS
    truth = TruthRenderer(content, cameras, times, shift)

    counts: dict[str, list[int]] = {"lidar_points": [], "gaussians": []}
    for k, cam in enumerate(cameras[:n_frames]):
        rendered = truth.frame(k)
        for w, frame in rendered.frames.items():
            image = to_uint8(np.asarray(frame.image, np.float64))  # float64 math: the bytes VERSION 1 shipped
            if w == "clear":
                _png(root / "images" / f"{k:03d}_0.png", image)
                if profile.sky_masks:
                    _png(root / "sky_masks" / f"{k:03d}_0.png", np.where(frame.alpha < 0.5, 255, 0).astype(np.uint8))
            else:
                _png(root / "truth" / w / f"{k:03d}_0.png", image)
        for name, mask in rendered.masks.items():
            _png(root / "truth" / "masks" / name / f"{k:03d}_0.png", mask)
        _savetxt(root / "ego_pose" / f"{k:03d}.txt", global_offset @ content.ego[k])
        sweep = lidar_sweep(content, k)
        sweep.tofile(root / "lidar" / f"{k:03d}.bin")
        world = sweep[:, 3:6].astype(np.float64) @ content.ego[k][:3, :3].T + content.ego[k][:3, 3]
        for group, mask in _dynamic_masks(content, k, cam, world, shift).items():
            _png(root / "dynamic_masks" / group / f"{k:03d}_0.png", mask)
        counts["lidar_points"].append(len(sweep))
        counts["gaussians"].append(rendered.gaussians)

    instances: dict[str, Any] = {}
    frame_instances: dict[str, list[int]] = {str(k): [] for k in range(n_frames)}
    for n, m in enumerate(m for m in content.movers if m.tracked):
        instances[str(n)] = {
            "id": f"{spec.folder}_{m.id}",
            "class_name": m.class_name,
            "frame_annotations": {
                "frame_idx": list(range(n_frames)),
                "obj_to_world": [(global_offset @ p).tolist() for p in m.poses[:n_frames]],
                "box_size": [m.size.tolist()] * n_frames,
            },
        }
        for k in range(n_frames):
            frame_instances[str(k)].append(n)
    (root / "instances" / "instances_info.json").write_text(json.dumps(instances, indent=4), encoding="utf-8")
    (root / "instances" / "frame_instances.json").write_text(json.dumps(frame_instances, indent=4),
                                                             encoding="utf-8")

    (root / "truth" / "weather.json").write_text(dumps_json(truth.record()), encoding="utf-8")
    write_edit_truth(root / "truth" / "edits", content, cameras, times, shift, truth, n_frames=n_frames)

    moving = [m for m in content.movers if m.moving]
    summary: dict[str, Any] = {
        "version": profile.version, "scene": spec.folder, "seed": spec.seed, "curvature_per_m": spec.curvature,
        "pedestrian": spec.pedestrian, "moving_objects": [m.id for m in moving],
        "parked_cars": sum(not m.moving for m in content.movers),
        "frames": n_frames, "fps": FPS, "image_size": [WIDTH, HEIGHT], "focal_px": FOCAL, "speed_m_s": SPEED,
        "gaussians": {"static": len(content.static), "per_frame": counts["gaussians"][0],
                      "moving": counts["gaussians"][0] - len(content.static)},
        "lidar_points": counts["lidar_points"], "truth_weathers": TRUTH_WEATHERS,
        "global_origin_m": GLOBAL_ORIGIN.tolist(),
    }
    if profile != SCENES[0].profile:  # what v1's scenes do not have; their marker stays as it was
        summary.update({
            "profile": profile.cache, "untracked_moving_objects": [m.id for m in moving if not m.tracked],
            "lidar": asdict(profile.lidar), "sun": asdict(profile.sun) if profile.sun else None,
            "sky_masks_shipped": profile.sky_masks, "truth_masks": list(masks),
        })
    (root / MARKER).write_text(dumps_json(summary), encoding="utf-8")
    return summary


def _ensure(specs: tuple[SynthSpec, ...]) -> Path:
    """Build the scenes ``specs`` (of one profile) once into their cache folder; return the folder.

    Each scene is written into a temporary folder and renamed into place, so a killed build never
    leaves half a scene and concurrent builders race safely (the loser finds the winner's scene).

    Raises
    ------
    InputError
        When a scene must be generated and torch is missing, or an incomplete folder is in the way.
    """
    parent = cache_dir() / "scenes" / specs[0].profile.cache
    for spec in specs:
        root = parent / spec.folder
        if (root / MARKER).is_file():
            _extend_with_edit_truth(root, spec)  # a scene cached before the editing truth existed
            continue
        reference_model()  # fail before any work when torch is missing
        announce(f"generating the synthetic scene {root} (first use only)")  # a folder: sets name the scene
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=parent))
        try:
            write_synth_scene(tmp, spec)
            try:
                os.replace(tmp, root)
            except OSError:
                if not (root / MARKER).is_file():  # another process won the race only if complete
                    raise InputError(f"{root}: an incomplete synthetic scene is in the way; delete the folder "
                                     "and it is generated again") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return parent


def ensure_synth_scenes(count: int) -> Path:
    """Build v1 synthetic scenes 0 .. ``count`` - 1 once into the cache folder; return the folder holding them
    (see :func:`_ensure`).

    Parameters
    ----------
    count : int
        Number of scenes (1 to ``len(SCENES)``).

    Returns
    -------
    Path
        ``<cache>/scenes/synth-v{VERSION}``; scene k is its sub-folder ``synth_{k:03d}``.

    Raises
    ------
    InputError
        When a scene must be generated and torch is missing, or an incomplete folder is in the way.
    """
    return _ensure(SCENES[:count])


def ensure_synth_1() -> Path:
    """Generator of the ``synth_1`` set: scene 0 (see :func:`ensure_synth_scenes`)."""
    return ensure_synth_scenes(1)


def ensure_synth_3() -> Path:
    """Generator of the ``synth_3`` set: scenes 0-2 (see :func:`ensure_synth_scenes`)."""
    return ensure_synth_scenes(3)


def ensure_synth_hard_1() -> Path:
    """Generator of the ``synth_hard_1`` set: ``<cache>/scenes/synth-hard-v2``, holding ``synth_hard_000``
    (see :func:`_ensure`)."""
    return _ensure(HARD_SCENES[:1])
