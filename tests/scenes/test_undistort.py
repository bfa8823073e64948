"""Waymo lens distortion is removed on load: images and masks become pinhole images with K kept,
so a lidar point projects (pinhole, Camera.project) to where cv2.projectPoints puts it on the raw
image, carried over by the undistortion (docs/design.md §3)."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from drivestudio_fixtures import (
    OPENCV_TO_WAYMO,
    WAYMO_FRONT_EXTRINSIC,
    WAYMO_FRONT_SIZE,
    waymo_front_K,
    write_waymo_scene,
)

from wcbench.scenes.loaders import load_scene
from wcbench.scenes.undistort import undistort_image, undistort_maps

SIGMA_PX = 1.5
HALF_WINDOW = 7


def _targets() -> np.ndarray:
    """[N, 2] pinhole pixels (wcbench continuous coordinates) across the frame, corners included."""
    w, h = WAYMO_FRONT_SIZE
    m = 16.0
    xs, ys = [m, w * 0.25, w / 2, w * 0.75, w - m], [m, h * 0.3, h / 2, h * 0.7, h - m]
    return np.array([(x, y) for x in xs for y in ys])


def _points_for(targets: np.ndarray, depth_m: float = 20.0) -> np.ndarray:
    """Vehicle-frame points [N, 3] whose pinhole projections are ``targets``."""
    K, _ = waymo_front_K()
    x = (targets[:, 0] - K[0, 2]) / K[0, 0] * depth_m
    y = (targets[:, 1] - K[1, 2]) / K[1, 1] * depth_m
    cam = np.column_stack([x, y, np.full(len(x), depth_m), np.ones(len(x))])  # OpenCV camera axes
    cam_to_vehicle = WAYMO_FRONT_EXTRINSIC @ OPENCV_TO_WAYMO
    return (cam @ cam_to_vehicle.T)[:, :3]


def _raw_pixels(points_vehicle: np.ndarray) -> np.ndarray:
    """cv2.projectPoints of the points onto the raw (distorted) FRONT image, K as published."""
    K, dist = waymo_front_K()
    vehicle_to_cam = np.linalg.inv(WAYMO_FRONT_EXTRINSIC @ OPENCV_TO_WAYMO)
    rvec, _ = cv2.Rodrigues(vehicle_to_cam[:3, :3])
    pts = np.ascontiguousarray(points_vehicle, np.float64).reshape(-1, 1, 3)
    uv, _ = cv2.projectPoints(pts, rvec, np.ascontiguousarray(vehicle_to_cam[:3, 3]), K, dist)
    return uv.reshape(-1, 2)


def _draw_blobs(uv: np.ndarray) -> np.ndarray:
    """A black 1920x1280 frame with a Gaussian dot centred at each continuous pixel ``uv``."""
    w, h = WAYMO_FRONT_SIZE
    img = np.zeros((h, w), np.float32)
    for u, v in uv:
        i0, j0 = int(u) - HALF_WINDOW, int(v) - HALF_WINDOW
        ii, jj = np.meshgrid(np.arange(i0, i0 + 2 * HALF_WINDOW + 1), np.arange(j0, j0 + 2 * HALF_WINDOW + 1))
        img[jj, ii] += np.exp(-((ii + 0.5 - u) ** 2 + (jj + 0.5 - v) ** 2) / (2 * SIGMA_PX ** 2))
    return np.clip(img * 255, 0, 255).astype(np.uint8)


def _centroid(gray: np.ndarray, u: float, v: float) -> np.ndarray:
    i0, j0 = int(u) - HALF_WINDOW, int(v) - HALF_WINDOW
    win = gray[j0:j0 + 2 * HALF_WINDOW + 1, i0:i0 + 2 * HALF_WINDOW + 1].astype(np.float64)
    jj, ii = np.mgrid[j0:j0 + win.shape[0], i0:i0 + win.shape[1]]
    return np.array([(win * (ii + 0.5)).sum(), (win * (jj + 0.5)).sum()]) / win.sum()


@pytest.fixture(scope="module")
def front_scene(tmp_path_factory):
    targets = _targets()
    points = _points_for(targets)
    raw_uv = _raw_pixels(points)
    dots = _draw_blobs(raw_uv)
    root = tmp_path_factory.mktemp("waymo") / "011"
    write_waymo_scene(root, n_frames=1, points_vehicle=points, image=np.repeat(dots[..., None], 3, axis=2),
                      mask=np.where(dots > 8, 255, 0).astype(np.uint8), weather="sunny")
    return load_scene(root), targets, raw_uv


def test_lidar_projects_onto_the_undistorted_image_within_half_a_pixel(front_scene):
    scene, targets, raw_uv = front_scene
    frame = scene.frames[0]
    assert frame.source_image_path is not None and frame.image_path != frame.source_image_path
    np.testing.assert_array_equal(frame.camera.distortion, 0.0)
    np.testing.assert_allclose(frame.camera.K, waymo_front_K()[0])  # K kept, as drivestudio does
    uv, z = frame.camera.project(scene.lidar(0).points)
    assert np.all(z > 0)
    np.testing.assert_allclose(uv, targets, atol=1e-3)
    # the raw image puts the corner points far away (the distortion this fixes) ...
    assert np.abs(raw_uv - targets).max() > 20.0
    # ... and each dot, drawn at cv2.projectPoints' raw pixel, lands where the pinhole projects
    gray = cv2.imread(str(frame.image_path), cv2.IMREAD_GRAYSCALE)
    assert gray.shape == (WAYMO_FRONT_SIZE[1], WAYMO_FRONT_SIZE[0])
    err = np.array([np.linalg.norm(_centroid(gray, u, v) - (u, v)) for u, v in uv])
    assert err.max() < 0.5, f"worst {err.max():.3f} px at {uv[err.argmax()]}"
    # the mask went through the same map (nearest neighbour: it stays binary)
    mask = cv2.imread(str(frame.dynamic_mask_path), cv2.IMREAD_GRAYSCALE)
    assert set(np.unique(mask)) <= {0, 255}
    mask_err = np.array([np.linalg.norm(_centroid(mask, u, v) - (u, v)) for u, v in uv])
    assert mask_err.max() < 1.0


def test_undistortion_matches_cv2_undistort_and_is_cached(front_scene):
    scene, _, _ = front_scene
    K, dist = waymo_front_K()
    raw = cv2.imread(str(scene.frames[0].source_image_path))
    ours = undistort_image(raw, K, dist)
    K_cv = K.copy()
    K_cv[:2, 2] -= 0.5  # OpenCV puts pixel centres at integers (undistort.py)
    ref = cv2.undistort(raw, K_cv, dist)
    assert np.abs(ours.astype(int) - ref.astype(int)).mean() < 0.5
    a = undistort_maps(K, dist, WAYMO_FRONT_SIZE)
    assert undistort_maps(K, dist, WAYMO_FRONT_SIZE)[0] is a[0]  # built once per camera
    # a second load reuses the written copies
    mtime = scene.frames[0].image_path.stat().st_mtime_ns
    again = load_scene(scene.root)
    assert again.frames[0].image_path == scene.frames[0].image_path
    assert again.frames[0].image_path.stat().st_mtime_ns == mtime
    assert again.facts["undistorted"]["k2"] == pytest.approx(-0.3214124825527059)
    assert again.facts["source_weather"] == "clear"


def test_undistort_cost_per_frame_is_small():
    """The remap of a 1920x1280 frame with cached maps; the figure in docs/design.md §3."""
    K, dist = waymo_front_K()
    img = np.random.default_rng(0).integers(0, 255, (1280, 1920, 3), dtype=np.uint8)
    undistort_image(img, K, dist)
    t0 = time.perf_counter()
    for _ in range(5):
        undistort_image(img, K, dist)
    ms = (time.perf_counter() - t0) / 5 * 1000
    assert ms < 200  # a loose bound for shared CI machines; ~5-10 ms measured
