"""Writers of tiny scene folders laid out exactly as drivestudio's preprocessing writes them.

Each writer follows the write calls of drivestudio's ``datasets/<dataset>/<dataset>_preprocess.py``
(``np.savetxt`` of 4x4 poses and of the 9 intrinsics one per line, ``float32.tofile`` lidar,
``json.dump`` of ``instances_info.json`` keyed by the compact ids 0, 1, ... in first-met order)
with synthetic pixels and real calibration numbers, their source named beside them.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

#: Waymo Open Dataset FRONT camera of segment 11004685739714500220_2300_000_2320_000 (the frame of
#: the dataset's own tutorial, ``tutorial/frames``): ``camera_calibrations { name: FRONT }``,
#: intrinsic = fx fy cx cy k1 k2 p1 p2 k3, extrinsic = camera-to-vehicle (Waymo camera axes), 1920x1280.
WAYMO_FRONT_INTRINSICS = [2055.556149361639, 2055.556149361639, 939.6574698861468, 641.0721821943271,
                          0.03231600849798887, -0.3214124825527059, 0.0007932583953709973,
                          -0.0006257493541333847, 0.0]
WAYMO_FRONT_EXTRINSIC = np.array([
    [0.9998926849887427, -0.005993208400016058, 0.0133678704017097, 1.5389142447125008],
    [0.006042236521329663, 0.9999751560547995, -0.003630241176497072, -0.02363394083934774],
    [-0.013345781499156929, 0.003710623431877962, 0.999904056092345, 2.115270572975561],
    [0.0, 0.0, 0.0, 1.0],
])
WAYMO_FRONT_SIZE = (1920, 1280)
OPENCV_TO_WAYMO = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], float)

#: PandaSet ``front_camera`` intrinsics (pandaset-devkit ``camera.intrinsics`` of sequence 002:
#: fx, fy, cx, cy at 1920x1080; drivestudio writes zero distortion for PandaSet).
PANDASET_FRONT_INTRINSICS = (1970.0131, 1970.0091, 970.0002, 483.2988)
PANDASET_FRONT_SIZE = (1920, 1080)


def savetxt(path: Path, m: np.ndarray) -> None:
    """``np.savetxt`` with numpy's default format, as drivestudio calls it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, m)


def _jpg(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])


def _png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def write_instances(root: Path, objects: list[dict]) -> None:
    """``instances/instances_info.json`` and ``frame_instances.json`` as drivestudio writes them:
    keys are the compact ids in the order the objects are first met, ``id`` the dataset's own id.

    ``objects``: dicts with ``id``, ``class_name``, ``frames``, ``poses`` [M, 4, 4], ``sizes`` [M, 3].
    """
    info, frame_instances = {}, {}
    for n, obj in enumerate(objects):
        info[n] = {"id": obj["id"], "class_name": obj["class_name"], "frame_annotations": {
            "frame_idx": list(map(int, obj["frames"])),
            "obj_to_world": [np.asarray(p).tolist() for p in obj["poses"]],
            "box_size": [list(map(float, s)) for s in obj["sizes"]],
        }}
        for f in obj["frames"]:
            frame_instances.setdefault(int(f), []).append(n)
    (root / "instances").mkdir(parents=True, exist_ok=True)
    (root / "instances" / "instances_info.json").write_text(json.dumps(info, indent=4), encoding="utf-8")
    (root / "instances" / "frame_instances.json").write_text(json.dumps(frame_instances, indent=4), encoding="utf-8")


def _box(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, z], [0, 0, 0, 1]], float)


def _texture(w: int, h: int, seed: int) -> np.ndarray:
    """Smooth synthetic street-like pixels: sky above the horizon, grey road below, soft blobs."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    sky = yy < h * 0.45
    img[sky] = (150, 190, 235)
    img[~sky] = (90, 90, 95)
    for _ in range(6):
        cx, cy, r = rng.uniform(0, w), rng.uniform(h * 0.3, h), rng.uniform(w * 0.05, w * 0.15)
        col = rng.uniform(40, 220, 3)
        a = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * r * r))[..., None]
        img = img * (1 - a) + col * a
    return np.clip(img, 0, 255).astype(np.uint8)


def write_pandaset_scene(root: Path, *, n_frames: int = 4, scale: float = 1 / 20, seed: int = 0) -> dict:
    """A scene folder as drivestudio's ``pandaset_preprocess.py`` writes it, for camera 0 only.

    PandaSet's front camera intrinsics scaled by ``scale`` (96x54 px at 1/20, as drivestudio scales
    K with its load size); a vehicle driving along world +x at 5 m/s from a far origin; lidar: a
    ground grid and a facade in the ego (lidar) frame, N x 5 float32 (xyz, intensity, lidar id);
    moving objects with PandaSet uuids and labels: Car, Pedestrian, Bicycle, Pickup Truck, Car
    (drivestudio's ids 0-4).
    """
    w, h = round(PANDASET_FRONT_SIZE[0] * scale), round(PANDASET_FRONT_SIZE[1] * scale)
    fx, fy, cx, cy = (v * scale for v in PANDASET_FRONT_INTRINSICS)
    savetxt(root / "intrinsics" / "0.txt", np.array([fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0, 0.0]))
    origin = np.array([4000.0, -1200.0, 30.0])
    # PandaSet cameras use OpenCV axes: camera z forward = world +x, y down = world -z
    cam_axes = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(2.0, 40.0, 0.8), np.arange(-8.0, 8.0, 0.8))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    fy_, fz_ = np.meshgrid(np.arange(-8.0, 8.0, 0.5), np.arange(0.0, 8.0, 0.5))
    facade = np.stack([np.full(fy_.size, 40.0), fy_.ravel(), fz_.ravel()], 1)
    world_static = np.concatenate([ground, facade])  # relative to the start, z up
    egos = []
    for t in range(n_frames):
        ego = np.eye(4)
        ego[:3, 3] = origin + np.array([0.5 * t, 0.0, 0.0])  # 5 m/s at 10 Hz
        egos.append(ego)
        savetxt(root / "ego_pose" / f"{t:03d}.txt", ego)
        c2w = np.eye(4)
        c2w[:3, :3] = cam_axes
        c2w[:3, 3] = ego[:3, 3] + [0.0, 0.0, 1.6]
        savetxt(root / "extrinsics" / f"{t:03d}_0.txt", c2w)
        _jpg(root / "images" / f"{t:03d}_0.jpg", _texture(w, h, seed + t))
        pts_world = world_static + origin
        pts_ego = pts_world - ego[:3, 3]
        lidar = np.column_stack([pts_ego, rng.uniform(0, 255, len(pts_ego)), np.zeros(len(pts_ego))])
        (root / "lidar").mkdir(exist_ok=True)
        lidar.astype(np.float32).tofile(root / "lidar" / f"{t:03d}.bin")
        for group in ("all", "human", "vehicle"):
            _png(root / "dynamic_masks" / group / f"{t:03d}_0.png", np.zeros((h, w), np.uint8))
    (root / "sky_masks").mkdir(exist_ok=True)  # drivestudio creates it empty
    frames = list(range(n_frames))
    def track(uuid: str, name: str, start: tuple[float, float, float], step: tuple[float, float, float],
              size: list[float]) -> dict:
        at = [origin + np.array(start) + t * np.array(step) for t in frames]
        return {"id": uuid, "class_name": name, "frames": frames, "poses": [_box(*p) for p in at],
                "sizes": [size] * n_frames}

    objects = [  # PandaSet cuboid uuids and labels; drivestudio numbers them 0, 1, 2 in this order
        track("7b1c1e04-52a6-4c5e-9d1e-0e6f2b1f9a11", "Car", (12.0, 2.0, 0.8), (0.8, 0, 0), [4.5, 1.9, 1.6]),
        track("c3f0a8d2-1b7e-4f0c-8a55-6d2e9b7c4e22", "Pedestrian", (9.0, -4.0, 0.9), (0, 0.14, 0), [0.6, 0.6, 1.8]),
        track("0e9d7c6b-5a4f-4e3d-9c2b-1a0f9e8d7c33", "Bicycle", (20.0, -2.5, 0.8), (0.5, 0, 0), [1.8, 0.6, 1.6]),
        track("5d4c3b2a-1908-4f7e-8d6c-5b4a39281706", "Pickup Truck", (26.0, 3.0, 0.9), (-0.9, 0, 0), [5.3, 2.0, 1.8]),
        track("a1b2c3d4-e5f6-4a7b-8c9d-0e1f2a3b4c5d", "Car", (16.0, -1.0, 0.8), (0.6, 0, 0), [4.4, 1.8, 1.5]),
    ]
    write_instances(root, objects)
    return {"egos": egos, "K": np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), "size": (w, h)}


def waymo_front_K() -> tuple[np.ndarray, np.ndarray]:
    """K [3, 3] and OpenCV distortion [5] (k1 k2 p1 p2 k3) of :data:`WAYMO_FRONT_INTRINSICS`."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = WAYMO_FRONT_INTRINSICS
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), np.array([k1, k2, p1, p2, k3])


def write_waymo_scene(root: Path, *, n_frames: int = 2, points_vehicle: np.ndarray | None = None,
                      image: np.ndarray | None = None, mask: np.ndarray | None = None,
                      weather: str | None = None, lidar_extra: np.ndarray | None = None) -> None:
    """A drivestudio Waymo folder for camera 0 with the real FRONT calibration: ``image`` (or
    black) as every frame, ``mask`` as ``dynamic_masks/all``, lidar = ``points_vehicle`` [N, 3]
    (vehicle frame, N x 14 with origins at the roof), ``frame_info.json`` when ``weather`` is given
    (as ``save_interested_labels`` writes it)."""
    w, h = WAYMO_FRONT_SIZE
    savetxt(root / "intrinsics" / "0.txt", np.array(WAYMO_FRONT_INTRINSICS))
    savetxt(root / "extrinsics" / "0.txt", WAYMO_FRONT_EXTRINSIC)
    pts = np.zeros((0, 3)) if points_vehicle is None else np.asarray(points_vehicle, float)
    for t in range(n_frames):
        ego = np.eye(4)
        ego[:3, 3] = [8000.0 + 1.0 * t, 300.0, -12.0]
        savetxt(root / "ego_pose" / f"{t:03d}.txt", ego)
        _jpg(root / "images" / f"{t:03d}_0.jpg", np.zeros((h, w, 3), np.uint8) if image is None else image)
        if mask is not None:
            _png(root / "dynamic_masks" / "all" / f"{t:03d}_0.png", mask)
        lidar = np.zeros((len(pts), 14), np.float32)
        lidar[:, 0:3] = [0.0, 0.0, 2.2]
        lidar[:, 3:6] = pts
        (root / "lidar").mkdir(exist_ok=True)
        lidar.tofile(root / "lidar" / f"{t:03d}.bin")
    if weather is not None:
        (root / "frame_info.json").write_text(json.dumps(
            {"time_of_day": "Day", "location": "location_sf", "weather": weather, "TYPE_VEHICLE": 3}), encoding="utf-8")
