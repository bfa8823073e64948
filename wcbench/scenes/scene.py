"""The data model: cameras, frames, scenes and scene sets.

Conventions (docs/design.md §2):

* Cameras use **OpenCV axes** (x right, y down, z forward); ``camera_to_world`` is a 4x4 matrix.
  Pixel (i, j) covers [i, i+1) x [j, j+1), so its center is at (i + 0.5, j + 0.5).
* World coordinates are metres, re-based so that the first camera sits at the origin (float32
  keeps millimetres there); ``Scene.world_offset`` is where that origin was in the source frame,
  ``Scene.up`` the unit up vector (gravity points along ``-up``).
* Images are uint8 sRGB on disk and float32 RGB in [0, 1] in memory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.reference_model.transforms import lidar_depth

FloatArray = np.ndarray  # float32 or float64 numpy array; shapes in the docstrings


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes
    ----------
    K : ndarray [3, 3] float64
        Intrinsics in pixels (fx, fy, cx, cy with the pixel-center convention above).
    width, height : int
        Image size in pixels.
    camera_to_world : ndarray [4, 4] float64
        Pose in OpenCV axes.
    distortion : ndarray [5] float64
        OpenCV distortion (k1, k2, p1, p2, k3); zeros when the images are undistorted.
    """

    K: FloatArray
    width: int
    height: int
    camera_to_world: FloatArray
    distortion: FloatArray = field(default_factory=lambda: np.zeros(5))

    @property
    def world_to_camera(self) -> FloatArray:
        """[4, 4] inverse of the pose (a rigid transform, inverted in closed form)."""
        R = self.camera_to_world[:3, :3]
        t = self.camera_to_world[:3, 3]
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ t
        return out

    @property
    def center(self) -> FloatArray:
        """[3] camera position in world coordinates (metres)."""
        return np.asarray(self.camera_to_world[:3, 3])

    def project(self, points_world: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Project world points to pixels.

        Parameters
        ----------
        points_world : ndarray [N, 3]
            Points in world coordinates (metres).

        Returns
        -------
        uv : ndarray [N, 2]
            Pixel coordinates (x right, y down; pixel centers at +0.5). Undefined where z <= 0.
        z : ndarray [N]
            Depth along the optical axis (metres).
        """
        pts = np.asarray(points_world, dtype=np.float64)
        w2c = self.world_to_camera
        # three axpy-style columns: a tall-skinny [N,3] @ [3,3] goes through threaded BLAS and is
        # several times slower for lidar-sized N
        x, y, z = (pts[:, 0] * w2c[i, 0] + pts[:, 1] * w2c[i, 1] + pts[:, 2] * w2c[i, 2] + w2c[i, 3] for i in range(3))
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([x / z * self.K[0, 0] + self.K[0, 2], y / z * self.K[1, 1] + self.K[1, 2]], axis=1)
        return uv, z


@dataclass(frozen=True)
class Frame:
    """One camera frame of a scene.

    Attributes
    ----------
    index : int
        Frame number within the scene, from 0.
    timestamp : float
        Seconds (source clock).
    camera : Camera
    image_path : Path
        The frame's image (uint8 sRGB on disk) as the camera model sees it: the source file, or its
        undistorted copy when the source lens has distortion (docs/design.md §3).
    lidar_path : Path or None
        The lidar sweep of this frame, if any; decoded by the scene's loader.
    sky_mask_path, dynamic_mask_path : Path or None
        Optional masks (uint8, nonzero = sky / dynamic), undistorted like the image.
    source_image_path : Path or None
        The source file when ``image_path`` is an undistorted copy of it, else ``None``.
    """

    index: int
    timestamp: float
    camera: Camera
    image_path: Path
    lidar_path: Path | None = None
    sky_mask_path: Path | None = None
    dynamic_mask_path: Path | None = None
    source_image_path: Path | None = None


@dataclass(frozen=True)
class ObjectTrack:
    """A tracked object: its class and per-frame box.

    Attributes
    ----------
    id : str
        drivestudio's compact instance id (``"0"``, ``"1"``, ... in the order its preprocessing met
        the objects): the id ``--edit ... ids=`` names.
    class_name : str
        The shared class (:data:`wcbench.core.classes.CLASSES`: vehicle, pedestrian, cyclist, ...).
    frames : ndarray [M] int
        Frame indices where the object is annotated.
    object_to_world : ndarray [M, 4, 4] float64
        Box pose per annotated frame (box x axis along the length, z up).
    box_size : ndarray [M, 3] float64
        Box length, width, height (metres).
    source_id : str
        The dataset's own id (Waymo label id, nuScenes instance token, PandaSet uuid); ``""`` if none.
    source_class : str
        The dataset's own class name (``Vehicle``, ``vehicle.car``, ``Car``); ``""`` if none.
    """

    id: str
    class_name: str
    frames: np.ndarray
    object_to_world: FloatArray
    box_size: FloatArray
    source_id: str = ""
    source_class: str = ""

    def corners(self, k: int) -> FloatArray:
        """[8, 3] world corners of the box at annotation ``k`` (not frame index)."""
        half = self.box_size[k] / 2.0
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        local = signs * half
        T = self.object_to_world[k]
        return local @ T[:3, :3].T + T[:3, 3]


@dataclass(frozen=True)
class LidarSweep:
    """Lidar points of one frame in (re-based) world coordinates.

    Attributes
    ----------
    points : ndarray [N, 3] float32
        World positions (metres).
    origins : ndarray [N, 3] float32 or None
        Sensor origin per point (world), when the format stores it.
    labels : ndarray [N] int or None
        Semantic class per point, when the format has it (scene-specific class ids).
    """

    points: FloatArray
    origins: FloatArray | None = None
    labels: np.ndarray | None = None


@dataclass
class Scene:
    """A driving scene: frames of one camera, lidar, tracked objects.

    Attributes
    ----------
    id : str
    frames : list[Frame]
    tracks : list[ObjectTrack]
    up : ndarray [3]
        Unit up vector in world coordinates.
    world_offset : ndarray [3]
        Source-frame position of the re-based origin (add it to get source coordinates back).
    source_format : str
        The loader that produced the scene ("drivestudio_nuscenes", ...).
    root : Path
        The scene folder on disk.
    lidar_loader : callable
        ``lidar_loader(frame) -> LidarSweep`` (already in re-based world coordinates).
    class_names : dict[int, str]
        Names of the lidar semantic classes, if any.
    references : dict[str, list[Path]]
        Ground-truth frames per weather, when the scene has them (synthetic scenes). The raw
        frames are always the reference for ``clear``.
    edit_truths : list of EditTruth
        The scene's editing truth (synthetic scenes: ``truth/edits/``, docs/design.md §3).
    facts : dict
        What the source says of the scene, JSON-serialisable, for results to carry: e.g.
        ``source_weather`` (Waymo's ``frame_info.json``), ``source_weather_flag`` (set when the
        source scene is not clear), ``frame_rate_hz``, ``undistorted`` (the lens coefficients
        removed on load), ``lidar_crop_x_m`` (docs/design.md §3).
    """

    id: str
    frames: list[Frame]
    tracks: list[ObjectTrack]
    up: FloatArray
    world_offset: FloatArray
    source_format: str
    root: Path
    lidar_loader: Callable[[Frame], LidarSweep] | None = None
    class_names: dict[int, str] = field(default_factory=dict)
    references: dict[str, list[Path]] = field(default_factory=dict)
    facts: dict[str, Any] = field(default_factory=dict)
    edit_truths: list[EditTruth] = field(default_factory=list)

    def edit_truth(self, edits: Any) -> EditTruth | None:
        """The editing truth made by exactly ``edits`` (``--edit``'s JSON forms, as a run's
        ``info.json`` records them), or ``None`` when the scene has none for them."""
        key = edits_key(edits)
        return next((t for t in self.edit_truths if key is not None and edits_key([t.edit]) == key), None)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the frames (all frames of a scene share one camera size)."""
        cam = self.frames[0].camera
        return cam.width, cam.height

    def lidar(self, frame: int | Frame) -> LidarSweep | None:
        """The lidar sweep of a frame in world coordinates, or ``None`` if the frame has none."""
        f = self.frames[frame] if isinstance(frame, int) else frame
        if f.lidar_path is None or self.lidar_loader is None:
            return None
        return self.lidar_loader(f)

    def all_lidar_points(self) -> FloatArray:
        """[N, 3] float32 world points of every sweep, concatenated in frame order."""
        sweeps = [s.points for f in self.frames if (s := self.lidar(f)) is not None]
        if not sweeps:
            return np.zeros((0, 3), np.float32)
        return np.concatenate(sweeps).astype(np.float32, copy=False)

    def lidar_depth(self, frame: int) -> FloatArray:
        """[H, W] float32 sparse depth (metres along z) from the frame's own sweep; 0 = no return.

        Where several points hit one pixel the nearest wins
        (:func:`wcbench.reference_model.transforms.lidar_depth`).
        """
        f = self.frames[frame]
        cam = f.camera
        sweep = self.lidar(f)
        if sweep is None:
            return np.zeros((cam.height, cam.width), np.float32)
        return lidar_depth(sweep.points, cam.world_to_camera, cam.K, cam.width, cam.height)

    def reference_paths(self, weather: str) -> list[Path] | None:
        """Ground-truth image paths for ``weather``, or ``None`` when the scene has no truth."""
        if weather == "clear":
            return [f.image_path for f in self.frames]
        return self.references.get(weather)

    @cached_property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return float(self.frames[-1].timestamp - self.frames[0].timestamp) if self.frames else 0.0


def edits_key(edits: Any) -> tuple[Any, ...] | None:
    """A comparable form of a list of object edits in ``--edit``'s JSON form (``op``, ``ids``/``id``,
    ``class``, ``except``, ``by``): ids and classes as sorted sets, ``by`` rounded to the micrometre;
    ``None`` when ``edits`` is not such a list."""
    if not isinstance(edits, list) or not edits:
        return None
    out = []
    for e in edits:
        if not isinstance(e, dict) or "op" not in e:
            return None

        def names(v: Any) -> tuple[str, ...]:
            items = v.split(",") if isinstance(v, str) else (v if isinstance(v, list) else [v])
            return tuple(sorted({str(x).strip().lower() for x in items if str(x).strip()}))

        try:
            by = None if e.get("by") is None else tuple(round(float(v), 6) for v in e["by"])
        except (TypeError, ValueError):
            return None
        out.append((str(e["op"]), names(e.get("ids", [])) + names(e.get("id", [])), names(e.get("class", [])),
                    names(e.get("except", [])), by))
    return tuple(out)


@dataclass(frozen=True)
class EditTruth:
    """Frames of a scene with objects edited, and the edited region (docs/design.md §3).

    Attributes
    ----------
    name : str
        Its folder under ``truth/edits/``.
    edit : dict
        The edit in ``--edit``'s JSON form (``op``, ``ids``, ``by``).
    references : dict of str to list of Path
        Per weather (``clear`` included), the edited truth frames, one per selected frame.
    masks : list of Path
        Per selected frame, a uint8 mask: 255 in the edited region.
    """

    name: str
    edit: dict[str, Any]
    references: dict[str, list[Path]]
    masks: list[Path]


def check_finite_matrix(m: np.ndarray, *, what: str, path: Path, shape: tuple[int, ...]) -> np.ndarray:
    """Return ``m`` as float64 after checking its shape and finiteness; raise ``InputError`` naming ``path``."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != shape:
        raise InputError(f"{path}: expected {what} of shape {shape}, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise InputError(f"{path}: {what} has non-finite values (NaN or Inf): {m.tolist()}")
    return m
