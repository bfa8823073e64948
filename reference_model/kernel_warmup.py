"""Compile every numba kernel ahead of use (``wcbench compile``).

The kernels are compiled on their first call and cached by numba beside their source (or under
``NUMBA_CACHE_DIR``); a fresh install's first render otherwise waits for the compilation. Running
each kernel once on a tiny input here moves that wait to set-up time, with a message, and a later
process loads the cached machine code in a fraction of the time (``wcbench bench raster``
measures both: ``start_cold`` and ``start_warm``). Once every step has run, a stamp file in the
wcbench cache says so (:func:`kernels_stamp`): ``wcbench run`` and ``wcbench train`` read it to
decide whether to compile in a second process while they work (docs/design.md §8).
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import llvmlite.binding
import numba
import numpy as np
import torch

from wcbench.core.errors import OutputError
from wcbench.core.paths import cache_dir
from wcbench.core.storage import atomic_write_json
from wcbench.reference_model._numba_backend import load_numba_kernels, numba_error
from wcbench.reference_model.model.sky import SkyModel
from wcbench.reference_model.raster.rasterizer import rasterize, rasterize_image
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.training.losses import training_ssim
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.renderer import WeatherRenderer

__all__ = ["KERNEL_MODULES", "compile_kernels", "kernels_compiled", "kernels_stamp"]

#: The kernel modules (inside ``wcbench.reference_model``).
KERNEL_MODULES = ("raster.kernels", "weather.particle_kernels", "weather.fog_kernels", "training.ssim_kernels",
                  "model.sky_kernels", "appearance.shell_kernels", "appearance.reflection_kernels",
                  "appearance.shading_kernels")


@dataclass(frozen=True)
class _Camera:
    """What :meth:`WeatherRenderer.render` reads of a camera: at the origin, looking along +z."""

    K: np.ndarray
    width: int
    height: int
    camera_to_world: np.ndarray

    @property
    def world_to_camera(self) -> np.ndarray:
        return np.linalg.inv(self.camera_to_world)

    @property
    def center(self) -> np.ndarray:
        return self.camera_to_world[:3, 3]


def _tiny_wall() -> GaussianCloud:
    g = np.linspace(-1.0, 1.0, 6)
    x, y = np.meshgrid(g, g)
    n = x.size
    return GaussianCloud(means=np.stack([x.ravel(), y.ravel(), np.full(n, 4.0)], 1),
                         quats=np.tile([1.0, 0, 0, 0], (n, 1)), scales=np.full((n, 3), 0.2),
                         opacities=np.full(n, 0.9), colors=np.full((n, 3), 0.5))


def _raster() -> None:
    wall = _tiny_wall()
    means, quats, scales, opacities, colors = (
        torch.tensor(a, dtype=torch.float32, requires_grad=True)
        for a in (wall.means, wall.quats, wall.scales, wall.opacities, wall.colors))
    K = torch.tensor([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]])
    # Each channel count is its own kernel variant: RGB with and without depth, and the weather step
    # of the default training (four weathers and three hazes: 15 channels, with depth).
    weather_colors = colors.detach().repeat(1, 5).requires_grad_(True)
    for c, depth in ((colors, True), (colors, False), (weather_colors, True)):
        out = rasterize(means, quats, scales, opacities, c, torch.eye(4), K, 32, 24, render_depth=depth,
                        absgrad=True, backend="numba")
        loss = out.color.sum() + out.alpha.sum() + (out.depth.sum() if out.depth is not None else 0.0)
        loss.backward()
    # the physical editor's inference renders: the surface maps (normal and four fields: 7
    # channels) and the mirror's distance (one dummy channel), both with depth
    with torch.no_grad():
        for channels in (7, 1):
            rasterize_image(means.detach(), quats.detach(), scales.detach(), opacities.detach(),
                            torch.rand(len(means), channels), torch.eye(4), K, 32, 24, backend="numba")


def _weather() -> None:
    cam = _Camera(K=np.array([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]]), width=32, height=24,
                 camera_to_world=np.eye(4))
    up = np.array([0.0, -1.0, 0.0])
    for weather in (Weather(kind="rain", preset="paper", visibility_m=200.0, fog_mode="exact"),
                    Weather(kind="snow", preset="paper"),
                    Weather(kind="fog", visibility_m=50.0),
                    Weather(kind="fog", visibility_m=50.0, fog_mode="postprocess")):
        # the training rasterizer (lidar-init, the editors) and the inference-only compositing (a
        # trained model's frames): each its own kernel variants
        for rasterizer in (rasterize, rasterize_image):
            WeatherRenderer(_tiny_wall(), weather, up=up, rasterizer=rasterizer).render(cam, 0.5)


def _editor() -> None:
    # one box's shell with the types and layouts box_shells.box_shells passes (its pose's rotation and
    # centre and the camera's centre are views of 4x4s, the maps float64, the normals and fields
    # float32)
    kernels = load_numba_kernels("appearance.shell_kernels")
    assert kernels is not None
    h, w = 12, 16
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 6.0]
    half = np.array([1.0, 0.8, 0.7])
    rays = np.zeros((h, w, 3))
    rays[..., 2] = 1.0
    filled = np.zeros((h, w), np.uint8)
    filled[3:9, 4:12] = 1
    fields = [np.zeros((h, w), np.float32) for _ in range(4)]
    flags = [np.zeros((h, w), bool) for _ in range(3)]
    kernels.box_shell_kernel(filled, filled.copy(), 0, 0, rays, np.full((h, w), 9.0), np.zeros((h, w, 3), np.float32),
                             *fields, np.ones((h, w), bool), *flags, pose[:3, :3], pose[:3, 3], -pose[:3, 3],
                             half, 1, np.float64(-0.4), np.eye(4)[:3, 3], -half, half, -half, half, 0.3, 0.05)
    # and the band over its top, with the frame (float32) and its colour steps
    kernels.top_band_kernel(0, 0, w, h, rays, np.full((h, w), 9.0), np.eye(4)[:3, 3], pose[:3, :3], pose[:3, 3], half,
                            0.3, 1, np.float64(-0.4), np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32),
                            4, 0.08, 0.6, 1, np.zeros((h, w), bool))
    # the rain's reflection lookup with the types maps._reflection_lookup_fast passes
    reflection = load_numba_kernels("appearance.reflection_kernels")
    assert reflection is not None
    rays32 = rays.astype(np.float32)
    rays32[..., 1] = 0.5  # some rays meet the plane below the camera
    reflection.reflection_lookup_kernel(
        rays32, np.full((h, w), 9.0, np.float32), np.full((h, w), 20.0, np.float32), np.array([0.0, -1.5, 0.0]),
        np.array([0.0, -1.0, 0.0]), 0.0, np.ascontiguousarray(np.eye(4)[:3]), np.array([[20.0, 0, 8], [0, 20.0, 6],
                                                                                             [0, 0, 1]]),
        0.1, 0.5, 1e5, np.empty((h, w), np.float32), np.empty((h, w), np.float32), np.empty((h, w), np.uint8))
    # the sRGB transfer functions on a flat float32 array, as shading passes them
    shading = load_numba_kernels("appearance.shading_kernels")
    assert shading is not None
    values = np.linspace(0.0, 1.0, 16, dtype=np.float32)
    shading.srgb_to_linear_kernel(values, np.empty_like(values))
    shading.linear_to_srgb_kernel(values, np.empty_like(values))


def _training() -> None:
    render = torch.rand(8, 12, 3, requires_grad=True)
    training_ssim(render, torch.rand(8, 12, 3), backend="numba").sum().backward()
    sky = SkyModel(("clear",), up=np.array([0.0, 0.0, 1.0]), heading=np.array([1.0, 0.0, 0.0]), rows=4, cols=8)
    sky(sky.grid(torch.nn.functional.normalize(torch.rand(6, 5, 3), dim=-1)), ("clear",)).sum().backward()


#: The steps of :func:`compile_kernels` in their order. A process compiling beside a first run
#: (``wcbench run``) starts with the rasterizer, whose training variants and backward passes are that
#: run's longest wait, and ends with the weather's kernels, which generating a synthetic scene
#: compiles for itself on the way. One run of the README's main job each, 218 s in this order and
#: 227 s with the editor's and training's small steps first, is within the machine's run-to-run
#: tenth: the order is chosen by the run's timeline, not a measured win (docs/findings.md, "A
#: first run's kernels compiled beside it").
_STEPS = ("raster", "training", "editor", "weather")


def kernels_stamp() -> Path:
    """The file :func:`compile_kernels` leaves once every kernel is in numba's cache.

    Its name is a digest of what numba keys that cache on: each kernel module's path, modification
    time and size (numba's source stamp), numba's and Python's versions, the host CPU and
    ``NUMBA_CACHE_DIR``; so an edited or reinstalled kernel module, another interpreter or another
    cache folder has no stamp until its kernels are compiled again.

    Returns
    -------
    Path
        ``<wcbench cache>/kernels/<digest>.json`` (it may not exist).
    """
    h = hashlib.sha256()
    for part in (numba.__version__, sys.version, llvmlite.binding.get_host_cpu_name(),
                 os.environ.get("NUMBA_CACHE_DIR", "")):
        h.update(part.encode() + b"\0")
    for name in KERNEL_MODULES:
        module = load_numba_kernels(name)
        path = Path(module.__file__ or name) if module is not None else Path(name)
        st = path.stat() if path.is_file() else None
        h.update(f"{path.resolve()}:{st.st_mtime if st else 0}:{st.st_size if st else 0}".encode() + b"\0")
    return cache_dir() / "kernels" / f"{h.hexdigest()[:16]}.json"


def kernels_compiled() -> bool:
    """Whether :func:`compile_kernels` has run to its end for these kernel modules (:func:`kernels_stamp`)."""
    return kernels_stamp().is_file()


def compile_kernels(*, echo: Callable[[str], None] | None = None) -> dict[str, float]:
    """Run every kernel once on a tiny input (compiling it, or loading it from numba's cache), then
    leave :func:`kernels_stamp`.

    Parameters
    ----------
    echo : callable, optional
        Called with one line per step.

    Returns
    -------
    dict of str to float
        Seconds of each step (``raster``, ``weather``, ``editor``, ``training``).

    Raises
    ------
    RuntimeError
        When a kernel module cannot be imported (numba missing or broken), naming why.
    """
    for name in KERNEL_MODULES:
        if load_numba_kernels(name) is None:
            raise RuntimeError(f"numba kernels {name} unavailable: {numba_error(name)}")
    steps = {"raster": _raster, "weather": _weather, "editor": _editor, "training": _training}
    seconds = {}
    for step in _STEPS:
        t = time.perf_counter()
        steps[step]()
        seconds[step] = time.perf_counter() - t
        if echo is not None:
            echo(f"{step} kernels ready in {seconds[step]:.1f} s")
    try:
        atomic_write_json(kernels_stamp(), {"seconds": {k: round(v, 2) for k, v in seconds.items()},
                                            "numba": numba.__version__})
    except OutputError:
        pass  # a read-only cache folder: the kernels are compiled all the same; a later run compiles beside
    return seconds
