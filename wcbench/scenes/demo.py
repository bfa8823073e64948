"""A small procedural street scene the package builds itself (the ``demo`` scene set).

The camera drives along a straight street between two building facades at 8 m/s; every surface
has a smooth analytic texture, so the frames are exact functions of the pose and optical flow is
well defined. The scene is written in the drivestudio nuScenes layout (so it goes through the same
loader as real data), with lidar returns sampled on the visible surfaces.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from wcbench.core.paths import cache_dir

VERSION = 1  # bump when the generated content changes: the cache folder is keyed by it
WIDTH, HEIGHT, FOCAL = 320, 180, 200.0
N_FRAMES, FPS, SPEED = 12, 10.0, 8.0  # frames, Hz, m/s
CAM_HEIGHT, STREET_HALF_WIDTH, FACADE_HEIGHT, END_WALL = 1.6, 7.0, 14.0, 150.0
ROAD, BUILDING, SKY = 7, 41, 0  # PandaSet class ids, so class names match the real scene
_SUPERSAMPLE = 3


def _camera_to_world(t: int) -> np.ndarray:
    """OpenCV camera looking along +x in a z-up world (x right = -y, y down = -z)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    c2w[:3, 3] = [SPEED * t / FPS, 0.0, CAM_HEIGHT]
    return c2w


def _trace(c2w: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersect pixel rays with the street; return hit points [..., 3], depth t [...] and class [...]."""
    d_cam = np.stack([(u - WIDTH / 2) / FOCAL, (v - HEIGHT / 2) / FOCAL, np.ones_like(u)], -1)
    d = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    inf = np.full(u.shape, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[..., 2] < 0, -o[2] / d[..., 2], inf)
        t_left = np.where(d[..., 1] > 0, (STREET_HALF_WIDTH - o[1]) / d[..., 1], inf)
        t_right = np.where(d[..., 1] < 0, (-STREET_HALF_WIDTH - o[1]) / d[..., 1], inf)
        t_end = np.where(d[..., 0] > 0, (END_WALL - o[0]) / d[..., 0], inf)
    t_wall = np.minimum(np.minimum(t_left, t_right), t_end)
    z_wall = o[2] + t_wall * d[..., 2]
    t_wall = np.where((z_wall >= 0) & (z_wall <= FACADE_HEIGHT), t_wall, inf)
    t = np.minimum(t_ground, t_wall)
    cls = np.where(np.isinf(t), SKY, np.where(t_ground <= t_wall, ROAD, BUILDING))
    hit = o + np.where(np.isinf(t), 0.0, t)[..., None] * d
    return hit, t, cls


def _shade(hit: np.ndarray, t: np.ndarray, cls: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Analytic textures: asphalt with lane marks, facades with windows, a sky gradient."""
    x, y, z = hit[..., 0], hit[..., 1], hit[..., 2]
    rgb = np.zeros((*t.shape, 3))
    grain = 0.03 * np.sin(3.1 * x) * np.cos(2.3 * y)
    lane = ((np.abs(y) < 0.12) & (np.mod(x, 6.0) < 3.0)).astype(float)
    road = 0.32 + grain + 0.55 * lane
    rgb[cls == ROAD] = np.stack([road, road, road * 1.03], -1)[cls == ROAD]
    along = np.where(np.abs(np.abs(y) - STREET_HALF_WIDTH) < 1e-6, x, y)
    window = ((np.mod(along, 4.0) > 1.2) & (np.mod(along, 4.0) < 2.8) & (np.mod(z, 3.5) > 1.2)).astype(float)
    block = np.floor(along / 12.0)
    hue = 0.5 + 0.25 * np.sin(1.7 * block + np.sign(y))
    base = np.stack([0.55 + 0.2 * hue, 0.45 + 0.1 * np.cos(block), 0.35 + 0.15 * (1 - hue)], -1)
    facade = base * (1.0 - 0.6 * window[..., None]) + 0.05 * np.sin(0.9 * z)[..., None]
    rgb[cls == BUILDING] = facade[cls == BUILDING]
    sky = np.stack([0.45 + 0.3 * v / HEIGHT, 0.6 + 0.25 * v / HEIGHT, 0.95 * np.ones_like(v)], -1)
    rgb[cls == SKY] = sky[cls == SKY]
    return np.clip(rgb, 0.0, 1.0)


def render_frame(t: int) -> tuple[np.ndarray, np.ndarray]:
    """Render frame ``t``: uint8 RGB [H, W, 3] (3x3 supersampled) and lidar-like points [M, 3]."""
    s = _SUPERSAMPLE
    jj, ii = np.meshgrid(np.arange(WIDTH * s), np.arange(HEIGHT * s))
    u, v = (jj + 0.5) / s, (ii + 0.5) / s
    c2w = _camera_to_world(t)
    hit, depth, cls = _trace(c2w, u, v)
    rgb = _shade(hit, depth, cls, v).reshape(HEIGHT, s, WIDTH, s, 3).mean(axis=(1, 3))
    image = np.round(rgb * 255.0).astype(np.uint8)
    pts_mask = (cls != SKY)[::6, ::6] & (depth[::6, ::6] < 60.0)
    points = hit[::6, ::6][pts_mask]
    labels = cls[::6, ::6][pts_mask]
    return image, np.concatenate([points, labels[:, None]], axis=1)


def write_demo_scene(root: Path) -> None:
    """Write the whole scene in the drivestudio nuScenes layout into ``root`` (must not exist)."""
    for sub in ("images", "extrinsics", "intrinsics", "lidar", "lidar_pose", "lidar_semseg"):
        (root / sub).mkdir(parents=True)
    (root / "intrinsics" / "0.txt").write_text(
        f"{FOCAL} {FOCAL} {WIDTH / 2} {HEIGHT / 2} 0 0 0 0 0\n", encoding="utf-8"
    )
    for t in range(N_FRAMES):
        image, pts = render_frame(t)
        cv2.imwrite(str(root / "images" / f"{t:03d}_0.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        np.savetxt(root / "extrinsics" / f"{t:03d}_0.txt", _camera_to_world(t), fmt="%.9f")
        np.savetxt(root / "lidar_pose" / f"{t:03d}.txt", np.eye(4), fmt="%.1f")
        lidar = np.concatenate([pts[:, :3], np.full((len(pts), 1), 0.5)], 1).astype(np.float32)
        lidar.tofile(root / "lidar" / f"{t:03d}.bin")
        pts[:, 3].astype(np.uint8).tofile(root / "lidar_semseg" / f"{t:03d}.bin")
    (root / "timestamps.json").write_text(json.dumps([t / FPS for t in range(N_FRAMES)]), encoding="utf-8")
    (root / "classes.json").write_text(json.dumps({str(ROAD): "Road", str(BUILDING): "Building"}), encoding="utf-8")


def ensure_demo_scene() -> Path:
    """Build the demo scene once into the cache folder and return the folder holding it.

    Written into a temporary folder and renamed, so a killed build never leaves half a scene.
    """
    parent = cache_dir() / "scenes" / f"demo-v{VERSION}"
    root = parent / "demo_street"
    if (root / "timestamps.json").is_file():
        return parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".demo_street.", dir=parent))
    try:
        shutil.rmtree(tmp)
        write_demo_scene(tmp)
        try:
            os.replace(tmp, root)
        except OSError:
            if not (root / "timestamps.json").is_file():  # another process won the race only if complete
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return parent
