"""Loaders for processed driving scenes on disk.

Three layouts of drivestudio/OmniRe (the format WeatherCity trains on) are read, each as
drivestudio's own preprocessing writes it (docs/design.md §3):

``drivestudio_waymo`` (``processed/training/NNN/``)
    ``images/{t:03d}_{cam}.jpg``, ``ego_pose/{t:03d}.txt`` (4x4 vehicle-to-world),
    ``extrinsics/{cam}.txt`` (4x4 camera-to-vehicle in *Waymo camera axes*: x forward, y left,
    z up), ``intrinsics/{cam}.txt`` (fx fy cx cy k1 k2 p1 p2 k3), ``lidar/{t:03d}.bin`` (float32
    N x 14 in the vehicle frame of frame t: origin 3, xyz 3, flow 3, flow class, ground,
    intensity, elongation, laser id), optional ``sky_masks/{t:03d}_{cam}.png`` and
    ``dynamic_masks/all/{t:03d}_{cam}.png``, ``instances/*.json``.
``drivestudio_nuscenes`` (``processed_10Hz/<split>/NNN/``; also ``pandaset_002``)
    ``images/{t:03d}_{cam}.jpg``, ``extrinsics/{t:03d}_{cam}.txt`` (4x4 camera-to-world, OpenCV
    axes), ``intrinsics/{cam}.txt``, ``lidar/{t:03d}.bin`` (float32 N x 4: xyz + intensity in the
    lidar frame) with ``lidar_pose/{t:03d}.txt`` (lidar-to-world), optional
    ``lidar_semseg/{t:03d}.bin`` (uint8 per point) + ``classes.json``, ``timestamps.json``.
``drivestudio_pandaset`` (``processed/NNN/``)
    ``images/{t:03d}_{cam}.jpg``, ``extrinsics/{t:03d}_{cam}.txt`` (4x4 camera-to-world, OpenCV
    axes), ``intrinsics/{cam}.txt``, ``ego_pose/{t:03d}.txt`` (lidar-to-world: PandaSet has no ego
    pose), ``lidar/{t:03d}.bin`` (float32 N x 5 in that frame: xyz, intensity, lidar id).

drivestudio's Argoverse 2 and nuPlan layouts also hold ``ego_pose/`` and per-camera extrinsics;
they are recognised and refused by name (:func:`detect_format`).

All layouts also share: ``instances/instances_info.json`` (keys are drivestudio's compact instance
ids ``"0"``, ``"1"``, ... which become the track ids; the dataset's own id and class name are kept
as ``source_id`` and ``source_class``; ``class_name`` is the shared class of
:mod:`wcbench.core.classes`), ``dynamic_masks/all/`` or, preferred when present as drivestudio
does, ``fine_dynamic_masks/all/``. Lens distortion is removed on load (:mod:`.undistort`).

All are in a global z-up frame on disk; the loaders re-base every scene so that the first
camera sits at the origin (see :mod:`wcbench.scenes.scene`).

Either layout may hold ground truth per weather (the synthetic scenes of :mod:`wcbench.scenes.synth`
do): ``truth/{weather}/{t:03d}_{cam}.png`` (or ``.jpg``) for ``rain``, ``snow`` or ``fog`` fills
``Scene.references[weather]``. A truth folder must hold a frame, of the scene's image size, for
every selected frame; a partial one is an input error naming the missing files. Editing truth
(frames with tracked objects removed or moved, and the edited region's masks) is listed in
``truth/edits/edits.json`` and fills ``Scene.edit_truths`` (docs/design.md §3).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.classes import canonical_class
from wcbench.core.errors import InputError
from wcbench.core.image_io import image_size
from wcbench.core.validation import expect_dict, finite_number, read_json
from wcbench.core.weathers import EDITED_WEATHERS
from wcbench.scenes.scene import (
    Camera,
    EditTruth,
    Frame,
    LidarSweep,
    ObjectTrack,
    Scene,
    check_finite_matrix,
)
from wcbench.scenes.undistort import copy_folder, has_distortion, undistorted_copy

#: Maps OpenCV camera axes (x right, y down, z forward) to Waymo camera axes (x forward, y left,
#: z up): camera_to_world_opencv = ego_to_world @ camera_to_ego_waymo @ OPENCV_TO_WAYMO.
OPENCV_TO_WAYMO = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
Z_UP = np.array([0.0, 0.0, 1.0])
_FRAME_RATE_HZ = 10.0  # Waymo, PandaSet and interpolated nuScenes folders are 10 Hz
#: drivestudio keeps Waymo lidar points whose vehicle-frame x lies in this open interval (m): its
#: Waymo configs' truncated_min_range / truncated_max_range, which drop the returns behind the car
#: that no front-facing camera sees.
WAYMO_LIDAR_CROP_X_M = (-2.0, 80.0)
#: drivestudio's nuScenes preprocessing names its output ``processed`` at the keyframe rate (2 Hz,
#: no interpolation) and ``processed_{2(N+1)}Hz`` with N interpolated frames between keyframes.
_NUSCENES_PROCESSED = re.compile(r"^processed(?:_(\d+(?:\.\d+)?)Hz)?$")
_NUSCENES_KEYFRAME_HZ = 2.0
#: Waymo frame_info.json "weather" values (context.stats.weather) that mean clear weather.
_CLEAR_SOURCE_WEATHER = {"sunny": "clear", "clear": "clear"}
_warned: set[tuple[str, str]] = set()
_IMAGE_EXTS = (".jpg", ".jpeg", ".png")
#: Bounds of plausible scene numbers (docs/design.md §9): focal lengths and principal points in
#: pixels, distortion coefficients, translations in metres. Outside them a float32 cast or a
#: projection would overflow or vanish (fx = 1e-300 becomes 0 in float32).
_FOCAL_PX = (1e-3, 1e7)
_PIXEL_BOUND = 1e7
_DISTORTION_BOUND = 1e3
_TRANSLATION_M = 1e8
#: A pose's rotation block must be a rotation to this tolerance (|R^T R - I| and |det R - 1|).
_ROTATION_TOL = 1e-3


def read_matrix(path: Path, *, what: str, shape: tuple[int, ...] = (4, 4)) -> np.ndarray:
    """Read a whitespace-separated text matrix, checking shape and finiteness.

    Raises
    ------
    InputError
        If the file is missing, unparsable (or not UTF-8), of the wrong size or holds NaN/Inf.
    """
    if not path.is_file():
        raise InputError(f"{path}: missing {what} file (expected {int(np.prod(shape))} numbers)")
    try:
        values = np.array(path.read_text(encoding="utf-8").split(), dtype=np.float64)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: {what} is not a list of numbers ({exc})") from None
    if values.size != int(np.prod(shape)):
        raise InputError(f"{path}: expected {int(np.prod(shape))} numbers for {what}, found {values.size}")
    return check_finite_matrix(values.reshape(shape), what=what, path=path, shape=shape)


def read_pose(path: Path, *, what: str) -> np.ndarray:
    """Read a 4x4 rigid transform: a rotation block (orthonormal, det +1), a translation within
    :data:`_TRANSLATION_M` metres and the last row ``0 0 0 1``.

    Raises
    ------
    InputError
        As :func:`read_matrix`, or when the matrix is not a rigid transform.
    """
    m = read_matrix(path, what=what)
    R = m[:3, :3]
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{path}: {what} must end with the row 0 0 0 1, got {m[3].tolist()}")
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > _ROTATION_TOL or abs(det - 1.0) > _ROTATION_TOL:
        raise InputError(
            f"{path}: {what} has a rotation block that is not a rotation (|R^T R - I| = {err:.3g}, det = {det:.3g}); "
            "expected an orthonormal matrix with determinant +1"
        )
    if np.abs(m[:3, 3]).max() > _TRANSLATION_M:
        raise InputError(f"{path}: {what} translation {m[:3, 3].tolist()} is beyond {_TRANSLATION_M:g} m")
    return m


def read_intrinsics(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read ``fx fy cx cy k1 k2 p1 p2 k3``; return K [3, 3] and distortion [5].

    Raises
    ------
    InputError
        As :func:`read_matrix`, or when a focal length, principal point or distortion coefficient
        is outside its plausible range (checked in float64, before any float32 cast).
    """
    v = read_matrix(path, what="intrinsics (fx fy cx cy k1 k2 p1 p2 k3)", shape=(9,))
    for name, x in zip(("fx", "fy"), v[:2]):
        finite_number(x, path=path, field=f"focal length {name} (px)", low=_FOCAL_PX[0], high=_FOCAL_PX[1])
    for name, x in zip(("cx", "cy"), v[2:4]):
        finite_number(x, path=path, field=f"principal point {name} (px)", low=-_PIXEL_BOUND, high=_PIXEL_BOUND)
    for name, x in zip(("k1", "k2", "p1", "p2", "k3"), v[4:9]):
        finite_number(x, path=path, field=f"distortion {name}", low=-_DISTORTION_BOUND, high=_DISTORTION_BOUND)
    fx, fy, cx, cy = v[:4]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, v[4:9].copy()


#: Farthest plausible lidar return (m) from its sensor: automotive lidars reach 200-300 m; a point
#: beyond a kilometre is a corrupt value, not a measurement.
MAX_LIDAR_RANGE_M = 1000.0


def _read_lidar(path: Path, columns: int, *, finite: tuple[int, ...], point: tuple[int, int, int],
                origin: tuple[int, int, int] | None = None) -> np.ndarray:
    """The float32 [N, columns] points of a lidar file; the ``finite`` columns must be finite and
    every ``point`` (columns x, y, z in the sensor's or vehicle's frame) within
    :data:`MAX_LIDAR_RANGE_M` of its ``origin`` columns (of the frame's origin when there are none)."""
    if path.stat().st_size % (4 * columns):
        raise InputError(
            f"{path}: lidar file of {path.stat().st_size} bytes is not a whole number of points of "
            f"{columns} float32 values"
        )
    pts = np.fromfile(path, dtype=np.float32).reshape(-1, columns)
    bad = ~np.isfinite(pts[:, list(finite)]).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: {int(bad.sum())} of {len(pts)} lidar points have NaN or Inf coordinates")
    xyz = pts[:, list(point)].astype(np.float64)
    if origin is not None:
        xyz -= pts[:, list(origin)]
    far = np.einsum("ij,ij->i", xyz, xyz) > MAX_LIDAR_RANGE_M ** 2
    if far.any():
        worst = float(np.sqrt(np.einsum("ij,ij->i", xyz[far], xyz[far]).max()))
        raise InputError(f"{path}: {int(far.sum())} of {len(pts)} lidar points lie beyond "
                         f"{MAX_LIDAR_RANGE_M:g} m of the sensor (up to {worst:.3g} m), farther than any lidar "
                         "measures: the file is corrupt")
    return pts


def _find_frames(root: Path, camera: int) -> dict[int, Path]:
    images = root / "images"
    if not images.is_dir():
        raise InputError(f"{root}: no images/ folder (expected images/{{t:03d}}_{camera}.jpg)")
    pat = re.compile(rf"^(\d+)_{camera}$")
    frames: dict[int, Path] = {}
    for p in images.iterdir():
        m = pat.match(p.stem)
        if m and p.suffix.lower() in _IMAGE_EXTS:
            frames[int(m.group(1))] = p
    if not frames:
        raise InputError(f"{images}: no images for camera {camera} (expected {{t:03d}}_{camera}.jpg)")
    return frames


def _select(frames: dict[int, Path], start: int, count: int | None, root: Path) -> list[int]:
    indices = sorted(frames)
    wanted = [t for t in indices if t >= start]
    if count is not None:
        expect = list(range(start, start + count))
        missing = [t for t in expect if t not in frames]
        if missing:
            raise InputError(
                f"{root}: frames {missing} are missing (the scene spec asks for {count} frames from {start}; "
                f"found {len(indices)} images, indices {indices[0]}..{indices[-1]})"
            )
        return expect
    gaps = [t for t in range(wanted[0], wanted[-1] + 1) if t not in frames] if wanted else []
    if gaps:
        raise InputError(f"{root}/images: frame numbering has gaps at {gaps}")
    if not wanted:
        raise InputError(f"{root}: no frames from index {start}")
    return wanted


def _camera_frames(
    root: Path, camera: int, start: int, count: int | None
) -> tuple[dict[int, Path], list[int], np.ndarray, np.ndarray]:
    """The images of ``camera``, the selected frame numbers, and the camera's K and distortion."""
    images = _find_frames(root, camera)
    indices = _select(images, start, count, root)
    K, dist = read_intrinsics(root / "intrinsics" / f"{camera}.txt")
    return images, indices, K, dist


def _lidar_to_world(path: Path, columns: int, pose_path: Path, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A sweep stored in its lidar's frame (float32 [N, columns], xyz in columns 0-2) moved to the world
    with its lidar-to-world pose file: the float64 points [N, 3] and sensor position [3], both re-based
    by ``offset``."""
    pts = _read_lidar(path, columns, finite=(0, 1, 2), point=(0, 1, 2))
    pose = read_pose(pose_path, what="lidar-to-world pose")
    origin = pose[:3, 3] - offset
    return pts[:, :3].astype(np.float64) @ pose[:3, :3].T + origin, origin


def _warn_once(root: Path, what: str, message: str) -> None:
    """A ``UserWarning`` the first time this process meets ``what`` of the scene folder ``root``."""
    key = (str(root), what)
    if key not in _warned:
        _warned.add(key)
        warnings.warn(message, UserWarning, stacklevel=3)


def nuscenes_frame_rate(root: Path) -> float | None:
    """The frame rate (Hz) of a drivestudio nuScenes folder from its path, or ``None``.

    drivestudio writes ``processed_{R}Hz/<split>/NNN`` when it interpolates frames between the
    2 Hz keyframes, and ``processed/<split>/NNN`` (keyframes only, 2 Hz) when it does not; the
    ``processed*`` folder is the scene folder's grandparent (parent of the split).
    """
    for parent in root.resolve().parents[:3]:
        m = _NUSCENES_PROCESSED.match(parent.name)
        if m:
            return float(m.group(1)) if m.group(1) else _NUSCENES_KEYFRAME_HZ
    return None


def _timestamps(root: Path, indices: list[int], rate_hz: float = _FRAME_RATE_HZ) -> list[float]:
    path = root / "timestamps.json"
    if not path.is_file():
        return [t / rate_hz for t in indices]
    raw = read_json(path, what="timestamps")
    expected = f"one timestamp (seconds) per frame for frames {indices[0]}..{indices[-1]}: a list or {{frame: seconds}}"
    if not isinstance(raw, (list, dict)):
        raise InputError(f"{path}: expected {expected}")
    values = []
    for t in indices:
        if isinstance(raw, list):
            value = raw[t] if t < len(raw) else None
        else:
            value = raw.get(str(t), raw.get(f"{t:03d}"))
        if value is None:
            raise InputError(f"{path}: no timestamp for frame {t}; expected {expected}")
        values.append(finite_number(value, path=path, field=f"timestamp of frame {t}"))
    back = [t for t, a, b in zip(indices[1:], values, values[1:]) if b <= a]
    if back:
        raise InputError(f"{path}: timestamps must increase from frame to frame; they do not at frames {back}")
    return values


def _track_ids(path: Path, keys: list[str]) -> list[str]:
    """drivestudio's compact instance ids for the keys of ``instances_info.json``.

    drivestudio's preprocessing numbers the instances 0, 1, ... in the order it first meets them
    and writes those numbers as the keys; files keyed otherwise (raw ids) get the same numbering by
    file order, which is the order they were met in.
    """
    if all(k.isdigit() for k in keys):
        ids = [str(int(k)) for k in keys]
        if len(set(ids)) != len(ids):
            raise InputError(f"{path}: instance keys {keys} repeat a number; expected drivestudio's ids 0, 1, ...")
        return ids
    return [str(n) for n in range(len(keys))]


def _read_tracks(root: Path, index_map: dict[int, int], offset: np.ndarray) -> list[ObjectTrack]:
    path = root / "instances" / "instances_info.json"
    if not path.is_file():
        return []
    info = expect_dict(read_json(path, what="instances"), path=path, what="a JSON object {instance id: instance}")
    tracks = []
    for track_id, (key, obj) in zip(_track_ids(path, list(info)), info.items()):
        obj = expect_dict(obj, path=path, field=f"instance {key}")
        ann = expect_dict(obj.get("frame_annotations"), path=path, field=f"instance {key} frame_annotations")
        try:
            frames = np.asarray(ann["frame_idx"], dtype=np.int64)
            poses = np.asarray(ann["obj_to_world"], dtype=np.float64).reshape(-1, 4, 4)
            sizes = np.asarray(ann["box_size"], dtype=np.float64).reshape(-1, 3)
        except (KeyError, ValueError, TypeError):
            raise InputError(
                f"{path}: instance {key} needs frame_annotations.frame_idx (integers), obj_to_world (4x4 "
                "matrices) and box_size (3 numbers each)"
            ) from None
        if not (len(frames) == len(poses) == len(sizes)):
            raise InputError(f"{path}: instance {key} has mismatched annotation lengths")
        keep = np.array([int(f) in index_map for f in frames], dtype=bool)
        if not keep.any():
            continue
        if not (np.all(np.isfinite(poses[keep])) and np.all(np.isfinite(sizes[keep]))):
            raise InputError(f"{path}: instance {key} has non-finite box poses or sizes")
        if np.any(sizes[keep] <= 0) or np.abs(poses[keep][:, :3, 3]).max() > _TRANSLATION_M:
            raise InputError(f"{path}: instance {key} has box sizes <= 0 or positions beyond {_TRANSLATION_M:g} m")
        poses = poses[keep].copy()
        poses[:, :3, 3] -= offset
        source_class = str(obj.get("class_name", "unknown"))
        tracks.append(
            ObjectTrack(
                id=track_id,
                class_name=canonical_class(source_class),
                frames=np.array([index_map[int(f)] for f in frames[keep]], dtype=np.int64),
                object_to_world=poses,
                box_size=sizes[keep],
                source_id=str(obj.get("id", key)),
                source_class=source_class,
            )
        )
    return tracks


def _class_names(root: Path) -> dict[int, str]:
    path = root / "classes.json"
    if not path.is_file():
        return {}
    raw = expect_dict(read_json(path, what="class names"), path=path, what="a JSON object {class id: name}")
    try:
        if not all(isinstance(v, str) for v in raw.values()):
            raise ValueError
        return {int(k): v for k, v in raw.items()}
    except ValueError:
        raise InputError(f"{path}: expected a JSON object {{class id (integer): name (string)}}") from None


def _optional(path: Path) -> Path | None:
    return path if path.is_file() else None


def _dynamic_mask(root: Path, t: int, camera: int, fine: bool) -> Path | None:
    """The frame's dynamic mask: ``fine_dynamic_masks/all/`` when the scene has that folder (as
    drivestudio prefers it), else ``dynamic_masks/all/``; a frame missing from the fine folder
    falls back to its coarse mask."""
    name = f"{t:03d}_{camera}.png"
    if fine and (p := root / "fine_dynamic_masks" / "all" / name).is_file():
        return p
    return _optional(root / "dynamic_masks" / "all" / name)


def _edit_truths(root: Path, indices: list[int], camera: int) -> list[EditTruth]:
    """The editing truth of ``truth/edits/edits.json`` (:mod:`wcbench.scenes.synth.edit_truth`): per
    edit ``<name>/{clear,rain,snow,fog}/{t:03d}_{cam}.png`` and ``<name>/mask/{t:03d}_{cam}.png``.
    An edit missing a selected frame's file is left out (a scene cut beyond the frames it was
    rendered for has no editing truth there)."""
    folder = root / "truth" / "edits"
    path = folder / "edits.json"
    if not path.is_file():
        return []
    record = expect_dict(read_json(path, what="editing truth"), path=path, what="a JSON object with 'edits'")
    out = []
    for item in record.get("edits") or []:
        item = expect_dict(item, path=path, field="edits[]")
        name = str(item.get("name", ""))
        names = {w: [folder / name / w / f"{t:03d}_{camera}.png" for t in indices]
                 for w in ("clear", *EDITED_WEATHERS, "mask")}
        if not name or not all(p.is_file() for paths in names.values() for p in paths):
            continue
        edit = {k: item[k] for k in ("op", "ids", "class", "except", "by") if item.get(k) is not None}
        masks = names.pop("mask")
        out.append(EditTruth(name=name, edit=edit, references=names, masks=masks))
    return out


def _references(root: Path, indices: list[int], camera: int, size: tuple[int, int]) -> dict[str, list[Path]]:
    """Ground-truth frames per edited weather from ``truth/<weather>/{t:03d}_{cam}.png``, one per
    selected frame in order; weathers without a folder have none.

    Raises
    ------
    InputError
        A truth folder lacks frames (every missing file is named) or holds one of another size.
    """
    out: dict[str, list[Path]] = {}
    for weather in EDITED_WEATHERS:
        folder = root / "truth" / weather
        if not folder.is_dir():
            continue
        paths, missing = [], []
        for t in indices:
            found = next((p for ext in _IMAGE_EXTS if (p := folder / f"{t:03d}_{camera}{ext}").is_file()), None)
            if found is None:
                missing.append(f"{t:03d}_{camera}.png")
            else:
                paths.append(found)
        if missing:
            raise InputError(
                f"{folder}: the {weather} ground truth must hold a frame for every selected frame "
                f"({indices[0]}..{indices[-1]}); {len(missing)} missing: {', '.join(missing)}"
            )
        for p in paths:
            if image_size(p) != size:
                raise InputError(f"{p}: ground-truth frame is {image_size(p)}, the scene's frames are {size}")
        out[weather] = paths
    return out


def _source_weather(root: Path) -> dict[str, Any]:
    """Facts from Waymo's ``frame_info.json`` (drivestudio copies the segment's
    ``context.stats``: weather, time of day, location); a source scene that is not clear is
    flagged in the facts and warned about once, since its frames are not clear-weather input."""
    path = root / "frame_info.json"
    if not path.is_file():
        return {}
    info = expect_dict(read_json(path, what="frame info"), path=path, what="a JSON object (drivestudio frame_info)")
    facts: dict[str, Any] = {}
    for key in ("time_of_day", "location"):
        if isinstance(info.get(key), str):
            facts[f"source_{key}"] = info[key]
    raw = info.get("weather")
    if not isinstance(raw, str) or not raw.strip():
        return facts
    weather = _CLEAR_SOURCE_WEATHER.get(raw.strip().lower(), raw.strip().lower())
    facts["source_weather"] = weather
    if weather != "clear":
        flag = (f"{path}: the source scene was recorded in '{raw}' weather, not clear: its frames are not "
                "clear-weather input, and edits to other weathers start from wet or rainy pixels")
        facts["source_weather_flag"] = flag
        _warn_once(root, "weather", flag)
    return facts


def _build_scene(
    root: Path,
    *,
    scene_id: str | None,
    source_format: str,
    indices: list[int],
    images: dict[int, Path],
    c2w: list[np.ndarray],
    K: np.ndarray,
    dist: np.ndarray,
    lidar_paths: list[Path | None],
    lidar_reader: Callable[[Frame, np.ndarray], LidarSweep],
    camera: int,
    rate_hz: float = _FRAME_RATE_HZ,
    facts: dict[str, Any] | None = None,
) -> Scene:
    width, height = image_size(images[indices[0]])
    for t in indices[1:]:
        if image_size(images[t]) != (width, height):
            raise InputError(
                f"{images[t]}: image is {image_size(images[t])}, expected {(width, height)} like frame {indices[0]}"
            )
    facts = dict(facts or {})
    offset = c2w[0][:3, 3].copy()
    times = _timestamps(root, indices, rate_hz)
    fine = (root / "fine_dynamic_masks").is_dir()
    if fine:
        facts["dynamic_masks"] = "fine_dynamic_masks"
    references = _references(root, indices, camera, (width, height))
    edit_truths = _edit_truths(root, indices, camera)
    undistort = has_distortion(dist)
    folder = copy_folder(root, K, dist, (width, height)) if undistort else root

    def pinhole(path: Path | None, *, mask: bool = False) -> Path | None:
        # drivestudio undistorts images and masks before any pinhole use (docs/design.md §3)
        if path is None or not undistort:
            return path
        return undistorted_copy(path, root, folder, K, dist, mask=mask)

    if undistort:
        facts["undistorted"] = dict(zip(("k1", "k2", "p1", "p2", "k3"), map(float, dist)))
        references = {w: [p for p in (pinhole(q) for q in paths) if p is not None] for w, paths in references.items()}
        edit_truths = [EditTruth(t.name, t.edit, {w: [p for p in (pinhole(q) for q in paths) if p is not None]
                                                  for w, paths in t.references.items()},
                                 [p for p in (pinhole(q, mask=True) for q in t.masks) if p is not None])
                       for t in edit_truths]
    frames = []
    for k, t in enumerate(indices):
        pose = c2w[k].copy()
        pose[:3, 3] -= offset
        cam = Camera(K=K, width=width, height=height, camera_to_world=pose, distortion=np.zeros(5))
        image = pinhole(images[t])
        assert image is not None
        frames.append(
            Frame(
                index=k,
                timestamp=times[k],
                camera=cam,
                image_path=image,
                lidar_path=lidar_paths[k],
                sky_mask_path=pinhole(_optional(root / "sky_masks" / f"{t:03d}_{camera}.png"), mask=True),
                dynamic_mask_path=pinhole(_dynamic_mask(root, t, camera, fine), mask=True),
                source_image_path=images[t] if undistort else None,
            )
        )
    index_map = {t: k for k, t in enumerate(indices)}
    if not (root / "timestamps.json").is_file():
        facts.setdefault("frame_rate_hz", rate_hz)
    return Scene(
        id=scene_id or root.name,
        frames=frames,
        tracks=_read_tracks(root, index_map, offset),
        up=Z_UP.copy(),
        world_offset=offset,
        source_format=source_format,
        root=root,
        lidar_loader=lambda f: lidar_reader(f, offset),
        class_names=_class_names(root),
        references=references,
        facts=facts,
        edit_truths=edit_truths,
    )


def load_nuscenes_layout(
    root: Path, *, scene_id: str | None = None, camera: int = 0, start: int = 0, count: int | None = None
) -> Scene:
    """Load a drivestudio nuScenes-style scene folder (also ``pandaset_002``).

    Frame times come from ``timestamps.json`` when the folder has one. drivestudio writes none (it
    counts frames), so the rate comes from the folder's path (:func:`nuscenes_frame_rate`:
    ``processed/`` is 2 Hz keyframes, ``processed_10Hz/`` 10 Hz); a path that tells nothing is
    taken as 10 Hz with a warning, once per folder.

    Parameters
    ----------
    root : Path
        The scene folder (``.../processed_10Hz/mini/000``).
    scene_id : str, optional
        Id used in outputs; defaults to the folder name.
    camera : int
        Camera id in the file names.
    start, count : int
        First frame and number of frames (``None``: all from ``start``).

    Returns
    -------
    Scene
        Re-based to the first camera, z up.
    """
    images, indices, K, dist = _camera_frames(root, camera, start, count)
    c2w = [read_pose(root / "extrinsics" / f"{t:03d}_{camera}.txt", what="camera-to-world pose") for t in indices]
    lidar_paths = [_optional(root / "lidar" / f"{t:03d}.bin") for t in indices]
    semseg = root / "lidar_semseg"
    orig = dict(zip(range(len(indices)), indices))
    rate = _FRAME_RATE_HZ
    facts: dict[str, Any] = {}
    if not (root / "timestamps.json").is_file():
        found = nuscenes_frame_rate(root)
        if found is None:
            facts["frame_rate_assumed"] = True
            _warn_once(root, "rate", f"{root}: no timestamps.json and no drivestudio 'processed[_NHz]' folder "
                       f"in its path: frame times assume {_FRAME_RATE_HZ:g} Hz (drivestudio's processed_10Hz); "
                       "a folder processed without interpolation is 2 Hz: keep it under 'processed/' or add "
                       "timestamps.json")
        else:
            rate = found

    def read(frame: Frame, offset: np.ndarray) -> LidarSweep:
        assert frame.lidar_path is not None
        t = orig[frame.index]
        world, _ = _lidar_to_world(frame.lidar_path, 4, root / "lidar_pose" / f"{t:03d}.txt", offset)
        labels = None
        label_path = semseg / f"{t:03d}.bin"
        if label_path.is_file():
            labels = np.fromfile(label_path, dtype=np.uint8)
            if labels.size != len(world):
                raise InputError(f"{label_path}: {labels.size} labels for {len(world)} lidar points")
        return LidarSweep(points=world.astype(np.float32), labels=labels)

    return _build_scene(
        root, scene_id=scene_id, source_format="drivestudio_nuscenes", indices=indices, images=images,
        c2w=c2w, K=K, dist=dist, lidar_paths=lidar_paths, lidar_reader=read, camera=camera, rate_hz=rate,
        facts=facts,
    )


def load_waymo_layout(
    root: Path, *, scene_id: str | None = None, camera: int = 0, start: int = 0, count: int | None = None
) -> Scene:
    """Load a drivestudio processed Waymo scene folder (``processed/training/NNN``).

    Camera extrinsics are camera-to-vehicle in Waymo axes and are converted to OpenCV axes
    (:data:`OPENCV_TO_WAYMO`); lidar points are in the vehicle frame of their own frame and, as
    drivestudio keeps them, only those with vehicle-frame x in :data:`WAYMO_LIDAR_CROP_X_M`.
    Images and masks are undistorted with the camera's coefficients (:mod:`.undistort`).
    ``frame_info.json`` gives the source weather (``Scene.facts``). Parameters as
    :func:`load_nuscenes_layout`.

    Raises
    ------
    InputError
        Also when the folder is drivestudio's Argoverse 2 or nuPlan layout, which look alike.
    """
    refuse_unread_layouts(root)
    images, indices, K, dist = _camera_frames(root, camera, start, count)
    cam_to_ego = read_pose(root / "extrinsics" / f"{camera}.txt", what="camera-to-vehicle extrinsics")
    ego = [read_pose(root / "ego_pose" / f"{t:03d}.txt", what="vehicle-to-world pose") for t in indices]
    c2w = [e @ cam_to_ego @ OPENCV_TO_WAYMO for e in ego]
    lidar_paths = [_optional(root / "lidar" / f"{t:03d}.bin") for t in indices]
    lo, hi = WAYMO_LIDAR_CROP_X_M

    def read(frame: Frame, offset: np.ndarray) -> LidarSweep:
        assert frame.lidar_path is not None
        pts = _read_lidar(frame.lidar_path, 14, finite=(0, 1, 2, 3, 4, 5), point=(3, 4, 5),
                          origin=(0, 1, 2)).astype(np.float64)
        pts = pts[(pts[:, 3] > lo) & (pts[:, 3] < hi)]
        pose = ego[frame.index]
        R, tr = pose[:3, :3], pose[:3, 3] - offset
        return LidarSweep(
            points=(pts[:, 3:6] @ R.T + tr).astype(np.float32),
            origins=(pts[:, 0:3] @ R.T + tr).astype(np.float32),
        )

    facts = {"lidar_crop_x_m": list(WAYMO_LIDAR_CROP_X_M), **_source_weather(root)}
    return _build_scene(
        root, scene_id=scene_id, source_format="drivestudio_waymo", indices=indices, images=images,
        c2w=c2w, K=K, dist=dist, lidar_paths=lidar_paths, lidar_reader=read, camera=camera, facts=facts,
    )


def load_pandaset_layout(
    root: Path, *, scene_id: str | None = None, camera: int = 0, start: int = 0, count: int | None = None
) -> Scene:
    """Load a scene folder written by drivestudio's PandaSet preprocessing (``processed/NNN``).

    ``extrinsics/{t:03d}_{cam}.txt`` is the camera-to-world pose of each frame in OpenCV axes
    (PandaSet's own camera axes; drivestudio's OPENCV2DATASET is the identity); ``ego_pose/`` holds
    the lidar-to-world pose, with which the float32 N x 5 lidar points (xyz in that frame,
    intensity, lidar id 0 = 360-degree, 1 = front) move to the world. drivestudio crops no
    PandaSet lidar and writes no timestamps: frames are 10 Hz (PandaSet's rate). Parameters as
    :func:`load_nuscenes_layout`.
    """
    images, indices, K, dist = _camera_frames(root, camera, start, count)
    c2w = [read_pose(root / "extrinsics" / f"{t:03d}_{camera}.txt", what="camera-to-world pose") for t in indices]
    lidar_paths = [_optional(root / "lidar" / f"{t:03d}.bin") for t in indices]
    orig = dict(zip(range(len(indices)), indices))

    def read(frame: Frame, offset: np.ndarray) -> LidarSweep:
        assert frame.lidar_path is not None
        t = orig[frame.index]
        world, origin = _lidar_to_world(frame.lidar_path, 5, root / "ego_pose" / f"{t:03d}.txt", offset)
        return LidarSweep(points=world.astype(np.float32), origins=np.broadcast_to(
            origin.astype(np.float32), world.shape).copy())

    return _build_scene(
        root, scene_id=scene_id, source_format="drivestudio_pandaset", indices=indices, images=images,
        c2w=c2w, K=K, dist=dist, lidar_paths=lidar_paths, lidar_reader=read, camera=camera,
    )


LOADERS: dict[str, Callable[..., Scene]] = {
    "drivestudio_waymo": load_waymo_layout,
    "drivestudio_nuscenes": load_nuscenes_layout,
    "drivestudio_pandaset": load_pandaset_layout,
}

#: nuPlan log names, which drivestudio's nuPlan preprocessing uses as scene folder names.
_NUPLAN_LOG = re.compile(r"^\d{4}\.\d{2}\.\d{2}\.\d{2}\.\d{2}\.\d{2}_veh-\d+")


def _camera_ids(root: Path) -> set[int]:
    images = root / "images"
    if not images.is_dir():
        return set()
    pat = re.compile(r"^\d+_(\d+)$")
    return {int(m.group(1)) for p in images.iterdir() if (m := pat.match(p.stem))}


def _unread_layout(root: Path) -> str | None:
    """Which of drivestudio's unread layouts (``ego_pose/`` + ``extrinsics/{cam}.txt`` like Waymo)
    the folder is, from what tells them apart: nuPlan's 8 cameras (ids 0-7) and log-named folders,
    Argoverse 2's 7 ring cameras (ids 0-6; Waymo has 5), and camera-to-vehicle extrinsics in OpenCV
    axes (camera y pointing down; Waymo's camera axes have z up)."""
    cams = _camera_ids(root)
    if 7 in cams or _NUPLAN_LOG.match(root.name):
        return "nuPlan"
    if cams & {5, 6}:
        return "Argoverse 2"
    ext = root / "extrinsics" / f"{min(cams) if cams else 0}.txt"
    if ext.is_file():
        try:
            R = np.array(ext.read_text(encoding="utf-8").split(), dtype=np.float64).reshape(4, 4)[:3, :3]
        except (ValueError, UnicodeDecodeError):
            return None  # the Waymo loader names the malformed file
        if R[2, 1] < -0.5 and abs(R[2, 2]) < 0.5:
            return "Argoverse 2 or nuPlan"
    return None


def refuse_unread_layouts(root: Path) -> None:
    """Raise when ``root`` is drivestudio's Argoverse 2 or nuPlan layout, which wcbench does not
    read yet: they share Waymo's folder names, and read as Waymo they would fail later on a
    misleading file or, worse, load with wrong camera axes.

    Raises
    ------
    InputError
        Naming the layout.
    """
    layout = _unread_layout(root)
    if layout is not None:
        raise InputError(
            f"{root}: this is drivestudio's {layout} processed layout, which wcbench does not read yet "
            "(readable: drivestudio's Waymo, nuScenes and PandaSet layouts; docs/design.md §3)"
        )


def detect_format(root: Path) -> str:
    """Guess the layout of a scene folder from the files it holds.

    ``ego_pose/`` with per-frame ``extrinsics/{t:03d}_{cam}.txt`` is PandaSet; per-frame
    extrinsics alone nuScenes; ``ego_pose/`` with per-camera ``extrinsics/{cam}.txt`` is Waymo,
    unless it is Argoverse 2 or nuPlan (:func:`refuse_unread_layouts`).

    Raises
    ------
    InputError
        If the folder is missing, is a layout not read yet, or matches no known layout.
    """
    if not root.is_dir():
        raise InputError(f"{root}: scene folder does not exist")
    per_frame = (root / "extrinsics").is_dir() and any((root / "extrinsics").glob("[0-9][0-9][0-9]_*.txt"))
    if (root / "ego_pose").is_dir():
        if per_frame:
            return "drivestudio_pandaset"
        refuse_unread_layouts(root)
        return "drivestudio_waymo"
    if per_frame:
        return "drivestudio_nuscenes"
    raise InputError(
        f"{root}: not a processed scene folder: expected images/ and either ego_pose/ + extrinsics/{{cam}}.txt "
        "(drivestudio Waymo), ego_pose/ + extrinsics/{t:03d}_{cam}.txt (drivestudio PandaSet) or "
        "extrinsics/{t:03d}_{cam}.txt + lidar_pose/ (drivestudio nuScenes)"
    )


def load_scene(
    path: str | Path,
    *,
    format: str | None = None,
    scene_id: str | None = None,
    camera: int = 0,
    start: int = 0,
    count: int | None = None,
) -> Scene:
    """Load a processed scene folder, detecting its layout unless ``format`` is given.

    Parameters
    ----------
    path : str or Path
        The scene folder.
    format : {"drivestudio_waymo", "drivestudio_nuscenes", "drivestudio_pandaset"}, optional
    scene_id : str, optional
        Id used in outputs; defaults to the folder name.
    camera, start, count
        Camera id, first frame, number of frames (``None``: all).

    Returns
    -------
    Scene
    """
    root = Path(path)
    fmt = format or detect_format(root)
    if fmt not in LOADERS:
        raise InputError(f"unknown scene format {fmt!r}; known: {sorted(LOADERS)}")
    if not root.is_dir():
        raise InputError(f"{root}: scene folder does not exist")
    return LOADERS[fmt](root, scene_id=scene_id, camera=camera, start=start, count=count)
