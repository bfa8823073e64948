"""A hand-made street for object removal: a road seen by three cameras, a parked car 10 m ahead, the
ground under and behind it never learned and a strip behind it stained with the car's red
(tests of :mod:`wcbench.reference_model.editing.vacated` and of ``bench streets``' removal case)."""

from __future__ import annotations

import math

import numpy as np
import torch

from wcbench.reference_model.model.decoders import WeatherDecoders, color_logits
from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.objects import RigidObject
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.model.sky import SkyModel

UP = np.array([0.0, 0.0, 1.0])
WIDTH, HEIGHT = 160, 90
K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 45.0], [0.0, 0.0, 1.0]])
#: A parked car 10 m ahead of the cameras (x forward, z up), 4.5 x 1.8 x 1.5 m, on the ground.
CAR_AT, CAR_SIZE = np.array([10.0, 0.0, 0.75]), np.array([4.5, 1.8, 1.5])
ROAD, RED = np.array([0.35, 0.35, 0.38]), np.array([0.9, 0.1, 0.1])


def camera(y: float) -> np.ndarray:
    """World-to-camera of a camera 1.6 m above the ground at (0, y) looking along +x (OpenCV axes)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    c2w[:3, 3] = [0.0, y, 1.6]
    return np.linalg.inv(c2w)


CAMERAS = [(k, camera(y), K, WIDTH, HEIGHT) for k, y in enumerate((0.0, 0.3, 0.6))]


def params(means: np.ndarray, colors: np.ndarray, scale: float) -> GaussianParams:
    n = len(means)
    features = torch.zeros(n, 8)
    features[:, :3] = color_logits(torch.from_numpy(np.asarray(colors, np.float32)))
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    return GaussianParams(means=torch.from_numpy(np.asarray(means, np.float32)),
                          log_scales=torch.full((n, 3), math.log(scale)), quats=quats,
                          opacity_logits=torch.full((n,), GaussianParams.opacity_logit(0.95)), features=features)


def parked_car() -> RigidObject:
    g = np.random.default_rng(1)
    local = (g.random((300, 3)) - 0.5) * CAR_SIZE
    pose = np.eye(4)
    pose[:3, 3] = CAR_AT
    return RigidObject(params(local, np.tile(RED, (300, 1)), 0.2), track_id="7", class_name="Car",
                       frames=np.arange(3), object_to_world=np.tile(pose, (3, 1, 1)), box_size=CAR_SIZE, n_frames=3)


def scene() -> tuple[WeatherCityModel, np.ndarray]:
    """A road the cameras see but for the car's shadow: the ground under and behind the car has no
    Gaussian (nothing was learned there), and a strip of ground just behind it took the car's red
    (trained on its pixels); returns the model and which background rows are that strip."""
    x, y = np.meshgrid(np.arange(2.0, 30.0, 0.25), np.arange(-6.0, 6.0, 0.25))
    ground = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    # seen from (0, y, 1.6) over the car's top, the road reappears where the ray over its far top
    # edge meets the ground: about 1.6 / (1.6 - 1.5) * 12.25 m away, beyond the scene
    shadow = (ground[:, 0] > CAR_AT[0] - 2.5) & (np.abs(ground[:, 1]) < 1.4)
    behind = (ground[:, 0] > CAR_AT[0] + 2.5) & (ground[:, 0] < CAR_AT[0] + 4.0)
    stained = shadow & behind & (np.abs(ground[:, 1]) < 0.8)
    keep = ~shadow | stained
    means = ground[keep]
    colors = np.where(stained[keep, None], RED, ROAD)
    weathers = ("clear", "rain")
    model = WeatherCityModel(params(means, colors, 0.2), [parked_car()], [], WeatherDecoders(weathers, feature_dim=8,
                             hidden=8), SkyModel(weathers, up=UP, heading=np.array([1.0, 0.0, 0.0]), rows=4, cols=8))
    return model, stained[keep]
