"""The lidar's time offset to the camera (Levinson & Thrun 2013's edge alignment, register.py)."""

from __future__ import annotations

import numpy as np

from wcbench.reference_model.scene_analysis.motion import LidarReturns
from wcbench.reference_model.scene_analysis.register import LidarTimeOffset, fit_time_offset
from wcbench.reference_model.scene_analysis.views import AnalysisViews

W, H, F = 480, 270, 8
K = np.array([[230.0, 0.0, 240.0], [0.0, 230.0, 135.0], [0.0, 0.0, 1.0]])
SPEED, STEP_S = 5.0, 0.1  # the camera drives along its own x axis (a camera looking sideways)
#: Dark poles (world x of the centre, depth z, m) 0.3 m wide against a bright sky.
POLES = [(-1.0, 4.0), (0.8, 6.0), (2.5, 5.0), (4.0, 8.0), (5.5, 4.5), (7.0, 7.0)]
HALF, TOP, BOTTOM = 0.15, -3.0, 2.0


def _scene(offset_s: float) -> tuple[AnalysisViews, LidarReturns]:
    """Frames of the poles and their sweeps, each sweep registered ``offset_s`` late (returns moved
    by +v offset_s)."""
    images, poses, points = [], [], {}
    for k in range(F):
        x0 = SPEED * STEP_S * k
        pose = np.eye(4)
        pose[0, 3] = x0
        poses.append(pose)
        img = np.empty((H, W, 3), np.float32)
        img[:] = (0.75, 0.83, 0.95)
        for px, pz in sorted(POLES, key=lambda p: -p[1]):
            u0, u1 = (K[0, 0] * (px - HALF - x0) / pz + K[0, 2], K[0, 0] * (px + HALF - x0) / pz + K[0, 2])
            v0, v1 = K[1, 1] * TOP / pz + K[1, 2], K[1, 1] * BOTTOM / pz + K[1, 2]
            cols = slice(max(0, int(np.ceil(u0 - 0.5))), max(0, int(np.ceil(u1 - 0.5))))
            rows = slice(max(0, int(np.ceil(v0 - 0.5))), max(0, int(np.ceil(v1 - 0.5))))
            img[rows, cols] = (0.22, 0.2, 0.18)
        images.append(img)
        # scan lines every 2 degrees, returns every 0.4 degrees, from the camera's centre
        el, az = np.meshgrid(np.radians(np.arange(-30, 30, 2.0)), np.radians(np.arange(-50, 50, 0.4)), indexing="ij")
        d = np.stack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)], -1).reshape(-1, 3)
        best = np.full(len(d), np.inf)
        for px, pz in POLES:
            t = pz / d[:, 2]
            x, y = x0 + t * d[:, 0], t * d[:, 1]
            hit = (np.abs(x - px) <= HALF) & (y >= TOP) & (y <= BOTTOM) & (t < best)
            best[hit] = t[hit]
        found = np.isfinite(best)
        pts = np.array([x0, 0.0, 0.0]) + best[found, None] * d[found]
        points[k] = pts + np.array([SPEED, 0.0, 0.0]) * offset_s
    views = AnalysisViews(size=(W, H), images=images, K=[K] * F, camera_to_world=poses,
                          up=np.array([0.0, -1.0, 0.0]), times=np.arange(F) * STEP_S)
    zeros = {k: np.zeros(len(p), bool) for k, p in points.items()}
    return views, LidarReturns(points=points, dynamic=zeros, tracked=dict(zeros), noise=dict(zeros))


def test_a_known_offset_is_recovered_and_undone() -> None:
    views, returns = _scene(0.03)
    found = fit_time_offset(views, returns)
    assert found.facts["kept"], found.facts
    assert abs(found.seconds - 0.03) <= 0.01, found.facts
    # applied, the returns land back where the poles are (within a centimetre per 0.005 s step)
    truth = _scene(0.0)[1]
    moved = found.apply(views, returns)
    assert max(np.abs(moved.points[k] - truth.points[k]).max() for k in truth.points) <= SPEED * 0.01


def test_registered_returns_stay_put() -> None:
    views, returns = _scene(0.0)
    found = fit_time_offset(views, returns)
    assert abs(found.seconds) <= 0.005, found.facts
    assert LidarTimeOffset(0.0).apply(views, returns) is returns


def test_a_flat_objective_keeps_the_given_poses() -> None:
    # a standing camera: no time offset moves anything, so there is no evidence for one
    views, returns = _scene(0.03)
    views.camera_to_world = [np.eye(4)] * F
    found = fit_time_offset(views, returns)
    assert found.seconds == 0.0 and not found.facts["kept"], found.facts
