"""Writers of small scene folders and prediction folders for tests."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

OPENCV_TO_WAYMO = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], float)


def write_matrix(path: Path, m: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.atleast_2d(m), fmt="%.9f")


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def make_waymo_scene(root: Path, *, n_frames: int = 4, size: tuple[int, int] = (64, 48),
                     origin: tuple[float, float, float] = (1000.0, -2000.0, 50.0)) -> dict:
    """A drivestudio Waymo folder: the vehicle drives along world +x from a far origin; camera 0
    sits 1.5 m above the vehicle origin looking forward (Waymo camera axes); one lidar point per
    frame 10 m ahead of the vehicle and one car box around it."""
    w, h = size
    rng = np.random.default_rng(0)
    fx = fy = 50.0
    write_matrix(root / "intrinsics" / "0.txt", np.array([[fx, fy, w / 2, h / 2, 0, 0, 0, 0, 0]]))
    cam_to_ego = np.eye(4)
    cam_to_ego[:3, 3] = [0.0, 0.0, 1.5]  # Waymo camera axes = vehicle axes, raised 1.5 m
    write_matrix(root / "extrinsics" / "0.txt", cam_to_ego)
    egos = []
    for t in range(n_frames):
        ego = np.eye(4)
        ego[:3, 3] = np.array(origin) + np.array([2.0 * t, 0.0, 0.0])
        egos.append(ego)
        write_matrix(root / "ego_pose" / f"{t:03d}.txt", ego)
        write_rgb(root / "images" / f"{t:03d}_0.jpg", rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
        lidar = np.zeros((1, 14), np.float32)
        lidar[0, 3:6] = [10.0, 0.0, 1.5]  # 10 m ahead, at camera height, vehicle frame of t
        (root / "lidar").mkdir(exist_ok=True)
        lidar.tofile(root / "lidar" / f"{t:03d}.bin")
    return {"egos": egos, "cam_to_ego": cam_to_ego, "K": np.array([[fx, 0, w / 2], [0, fy, h / 2], [0, 0, 1]])}


def write_prediction_folder(scene, root: Path, weathers: list[str], *, transform=None) -> Path:
    """Write the scene's raw frames (optionally transformed) as <root>/<weather>/{frame:03d}.png."""
    for w in weathers:
        for f in scene.frames:
            img = cv2.imread(str(f.image_path))
            if transform is not None:
                img = transform(img, f.index, w)
            (root / w).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / w / f"{f.index:03d}.png"), img)
    return root


def copy_scene(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst
