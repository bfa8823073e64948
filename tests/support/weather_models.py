"""A small hand-made WeatherCity scene graph: a textured wall, one car that drives, a sky.

The camera sits at the origin in OpenCV axes (x right, y down, z forward) and sees a wall of
Gaussians 10 m ahead and a car of Gaussians 6 m ahead that moves 1 m to the right per frame.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from wcbench.reference_model.model.decoders import WeatherDecoders, color_logits
from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.objects import RigidObject
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.model.sky import SkyModel, view_directions

WIDTH, HEIGHT, FOCAL = 96, 64, 80.0
K = np.array([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]], np.float64)
WORLD_TO_CAMERA = np.eye(4)
CAR_DEPTH = 6.0
N_FRAMES = 3


def _params(means: np.ndarray, colors: np.ndarray, scale: float, *, feature_dim: int = 8,
            seed: int = 0) -> GaussianParams:
    n = len(means)
    gen = torch.Generator().manual_seed(seed)
    features = torch.randn(n, feature_dim, generator=gen) * 0.1
    features[:, :3] = color_logits(torch.from_numpy(colors.astype(np.float32)))
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    return GaussianParams(
        means=torch.from_numpy(means.astype(np.float32)),
        log_scales=torch.full((n, 3), math.log(scale)),
        quats=quats,
        opacity_logits=torch.full((n,), GaussianParams.opacity_logit(0.95)),
        features=features,
    )


def wall(n_side: int = 24, depth: float = 10.0) -> GaussianParams:
    """A textured wall of n_side^2 Gaussians covering the view at ``depth`` m."""
    half_w, half_h = depth * WIDTH / (2 * FOCAL) * 1.1, depth * HEIGHT / (2 * FOCAL) * 1.1
    xs, ys = np.meshgrid(np.linspace(-half_w, half_w, n_side), np.linspace(-half_h, half_h, n_side))
    means = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, depth)], 1)
    colors = np.stack([0.5 + 0.4 * np.sin(xs.ravel()), 0.5 + 0.4 * np.cos(ys.ravel()),
                       np.full(xs.size, 0.3)], 1)
    spacing = 2 * half_w / (n_side - 1)
    return _params(means, colors, 0.7 * spacing, seed=1)


def car(n: int = 64) -> GaussianParams:
    """A red 1.6 m x 1 m x 1.6 m block of Gaussians in its box frame."""
    g = np.random.default_rng(2)
    means = (g.random((n, 3)) - 0.5) * np.array([1.6, 1.0, 1.6])
    colors = np.tile([[0.9, 0.1, 0.1]], (n, 1))
    return _params(means, colors, 0.25, seed=3)


def car_poses(n_frames: int = N_FRAMES) -> np.ndarray:
    """[n_frames, 4, 4] box poses: 6 m ahead, moving 1 m right per frame from x = -1 m."""
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    poses[:, 0, 3] = np.arange(n_frames) - 1.0
    poses[:, 2, 3] = CAR_DEPTH
    return poses


def make_model(weathers: tuple[str, ...] = ("clear", "rain", "fog"), *, shared: bool = False,
               with_car: bool = True) -> WeatherCityModel:
    """The hand-made scene graph with decoders for ``weathers`` (identity-initialised)."""
    rigid = []
    if with_car:
        rigid.append(RigidObject(car(), track_id="5", class_name="Car", frames=np.arange(N_FRAMES),
                                 object_to_world=car_poses(), box_size=np.array([1.6, 1.0, 1.6]),
                                 n_frames=N_FRAMES))
    decoders = WeatherDecoders(weathers, feature_dim=8, hidden=16, shared=shared)
    sky = SkyModel(weathers, up=np.array([0.0, -1.0, 0.0]), heading=np.array([0.0, 0.0, 1.0]), rows=8, cols=16,
                   shared=shared)
    return WeatherCityModel(wall(), rigid, [], decoders, sky)


def sky_grid(model: WeatherCityModel) -> torch.Tensor:
    """The sky lookup grid of the fixed camera."""
    dirs = view_directions(np.linalg.inv(WORLD_TO_CAMERA), K, WIDTH, HEIGHT)
    return model.sky.grid(torch.from_numpy(dirs))
