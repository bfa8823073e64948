"""The sky node: one learnable environment map per weather, looked up by view direction.

The map is equirectangular in the scene's own frame (azimuth around ``up`` from a heading, and
elevation above the horizon), so it is independent of where the camera is: the sky is at infinite
distance. Rays below ``min_elevation`` read the map's lowest row (the sky is rarely seen there;
Gaussians cover the ground). Colors are sigmoid(logits), RGB in (0, 1). A map may span only a
window of directions (what the training cameras saw, :func:`sky_window`), which puts all its
texels where the sky is ever seen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wcbench.reference_model._numba_backend import load_numba_kernels

__all__ = ["SkyModel", "camera_rays", "sky_window", "view_directions"]


def view_directions(camera_to_world: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unit world directions [H, W, 3] (float32) of the rays through every pixel center.

    Parameters
    ----------
    camera_to_world : ndarray [4, 4]
        OpenCV axes (x right, y down, z forward).
    K : ndarray [3, 3]
        Intrinsics in pixels; pixel (i, j) has its center at (i + 0.5, j + 0.5).
    """
    K = np.asarray(K, np.float64)
    xs = (np.arange(width) + 0.5 - K[0, 2]) / K[0, 0]
    ys = (np.arange(height) + 0.5 - K[1, 2]) / K[1, 1]
    d = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], np.ones((height, width))), -1)
    d = d @ np.asarray(camera_to_world, np.float64)[:3, :3].T
    return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)


def camera_rays(K: np.ndarray, width: int, height: int) -> torch.Tensor:
    """Unit camera-frame directions [H, W, 3] (float32, OpenCV axes) of the rays through every pixel
    center: the same for every frame of a camera, so a renderer makes them once and turns them by
    each frame's rotation (:meth:`SkyModel.grid_from_rays`)."""
    return torch.from_numpy(view_directions(np.eye(4), K, width, height))


def sky_window(sky: SkyModel, directions: Sequence[torch.Tensor], *, margin: float = 0.1,
               min_span: float = 0.05) -> tuple[float, float, float, float]:
    """The (azimuth, elevation) window of a sky map that covers ``directions`` (world rays [H, W, 3]
    of the training views), widened by ``margin`` of each span on both sides; the whole sphere's
    azimuths when the rays go round more than 300 degrees. Radians."""
    az_lo = el_lo = math.inf
    az_hi = el_hi = -math.inf
    for d in directions:
        el, az = sky.angles(d)
        az_lo, az_hi = min(az_lo, float(az.min())), max(az_hi, float(az.max()))
        el_lo, el_hi = min(el_lo, float(el.min())), max(el_hi, float(el.max()))
    if not math.isfinite(az_lo):
        raise ValueError("sky_window needs at least one direction")
    pad_a = max(margin * (az_hi - az_lo), min_span)
    pad_e = max(margin * (el_hi - el_lo), min_span)
    if az_hi - az_lo > math.radians(300):
        az_lo, az_hi, pad_a = -math.pi, math.pi, 0.0
    return (max(az_lo - pad_a, -math.pi), min(az_hi + pad_a, math.pi),
            max(el_lo - pad_e, -math.pi / 2), min(el_hi + pad_e, math.pi / 2))


class _SkyLookup(torch.autograd.Function):
    """``grid_sample`` of the maps (bilinear, border, align_corners=False) by :mod:`.sky_kernels`:
    the forward over image rows and the backward with one thread per map channel, where PyTorch
    uses one thread per batch item for both. The gradient goes to the maps only (the grid is a
    constant of the view)."""

    @staticmethod
    def forward(ctx: Any, maps: torch.Tensor, grid: torch.Tensor, kernels: Any) -> torch.Tensor:  # type: ignore[override]
        ctx.kernels, ctx.grid, ctx.size = kernels, grid, tuple(maps.shape[2:])
        out = kernels.grid_sample_map(maps[0].detach().contiguous().numpy(), grid[0].detach().contiguous().numpy())
        return torch.from_numpy(out)[None]

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None, None]:  # type: ignore[override]
        rows, cols = ctx.size
        g = ctx.kernels.grid_sample_map_grad(ctx.grid[0].detach().contiguous().numpy(),
                                             grad[0].detach().to(torch.float32).contiguous().numpy(), rows, cols)
        return torch.from_numpy(g)[None], None, None


class SkyModel(nn.Module):
    """Environment maps [D, 3, rows, cols] over (elevation, azimuth), one per weather.

    Parameters
    ----------
    weathers : sequence of str
        The weathers with a sky (``"clear"`` included).
    up : ndarray [3]
        The scene's up vector (world).
    heading : ndarray [3]
        Azimuth 0 (projected on the horizontal plane), e.g. the first camera's forward axis.
    rows, cols : int
        Resolution of each map in elevation and azimuth.
    min_elevation : float
        Lowest elevation covered (radians, negative: below the horizon).
    window : (float, float, float, float), optional
        (azimuth from, to, elevation from, to) in radians that the map spans, e.g. what the
        training cameras see (:func:`sky_window`): the same texels then resolve the sky far finer
        than over the whole sphere. Default: every azimuth, ``min_elevation`` to the zenith. Rays
        outside take the nearest border texel.
    color : ndarray [3], optional
        Initial color of every map (RGB in (0, 1)); mid grey when omitted.
    shared : bool
        One map for every weather (the "w/o WGS" ablation).
    """

    basis: torch.Tensor  # [3, 3] rows: forward, left, up

    window: torch.Tensor  # [4] azimuth from, to, elevation from, to (radians)

    def __init__(self, weathers: Sequence[str], *, up: np.ndarray, heading: np.ndarray, rows: int = 32,
                 cols: int = 128, min_elevation: float = -0.2, color: np.ndarray | None = None,
                 shared: bool = False, window: tuple[float, float, float, float] | None = None):
        super().__init__()
        self.weathers = tuple(weathers)
        self.shared = shared
        u = np.asarray(up, np.float64)
        u = u / np.linalg.norm(u)
        h = np.asarray(heading, np.float64)
        e1 = h - (h @ u) * u
        if not np.linalg.norm(e1) > 1e-6:
            raise ValueError("heading must not be parallel to up")
        e1 = e1 / np.linalg.norm(e1)
        self.register_buffer("basis", torch.tensor(np.stack([e1, np.cross(u, e1), u]), dtype=torch.float32))
        self.min_elevation = float(min_elevation)
        win = (-math.pi, math.pi, self.min_elevation, math.pi / 2) if window is None else tuple(map(float, window))
        if not (len(win) == 4 and win[0] < win[1] and win[2] < win[3] and all(map(math.isfinite, win))):
            raise ValueError(f"window must be (azimuth from < to, elevation from < to), finite, got {window}")
        self.register_buffer("window", torch.tensor(win, dtype=torch.float64))
        c = np.full(3, 0.5) if color is None else np.clip(np.asarray(color, np.float64), 0.02, 0.98)
        logit = torch.tensor(np.log(c / (1 - c)), dtype=torch.float32)
        n = 1 if shared else len(self.weathers)
        self.logits = nn.Parameter(logit.view(1, 3, 1, 1).repeat(n, 1, rows, cols).contiguous())

    def grid(self, directions: torch.Tensor) -> torch.Tensor:
        """Sampling grid [1, H, W, 2] in [-1, 1] of world directions [H, W, 3] (see ``grid_sample``)."""
        elevation, azimuth = self.angles(directions)
        a0, a1, e0, e1 = self.window.tolist()
        x = (2.0 * (azimuth - a0) / (a1 - a0) - 1.0).clamp(-1.0, 1.0)
        y = (1.0 - 2.0 * (elevation - e0) / (e1 - e0)).clamp(-1.0, 1.0)  # row 0 at the top of the window
        return torch.stack([x, y], -1)[None]

    def angles(self, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Elevation and azimuth (radians) of world directions [..., 3] in the map's frame."""
        local = directions @ self.basis.T  # (forward, left, up) components
        return torch.asin(local[..., 2].clamp(-1.0, 1.0)), torch.atan2(local[..., 1], local[..., 0])

    def grid_from_rays(self, rays: torch.Tensor, camera_to_world: np.ndarray) -> torch.Tensor:
        """:meth:`grid` of the world directions of camera rays [H, W, 3] (:func:`camera_rays`) seen
        from ``camera_to_world`` [4, 4]: one 3 x 3 product per pixel instead of building the rays."""
        rotation = torch.from_numpy(np.asarray(camera_to_world, np.float64)[:3, :3].astype(np.float32)).to(rays.device)
        return self.grid(rays @ rotation.T)

    def forward(self, grid: torch.Tensor, weathers: Sequence[str]) -> torch.Tensor:
        """Sky colors [H, W, 3 len(weathers)] (weather-major) at a grid from :meth:`grid`."""
        idx = [0 if self.shared else self.weathers.index(w) for w in weathers]
        # A run of consecutive maps is a view: its backward is a copy into a slice, where indexing
        # with a list is a serial accumulating index_put (1 ms a step for 4 weathers at 2 threads).
        run = bool(idx) and idx == list(range(idx[0], idx[0] + len(idx)))
        picked = self.logits[idx[0]:idx[0] + len(idx)] if run else self.logits[idx]
        maps = picked.reshape(1, 3 * len(idx), *self.logits.shape[2:])
        kernels = load_numba_kernels("model.sky_kernels")
        if kernels is not None and maps.dtype == grid.dtype == torch.float32 and not grid.requires_grad \
                and grid.shape[0] == 1 and maps.device.type == "cpu":  # elsewhere its torch twin, grid_sample
            out = _SkyLookup.apply(maps, grid, kernels)
        else:
            out = F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=False)
        return torch.sigmoid(out[0].permute(1, 2, 0))

    @torch.no_grad()
    def fill_from(self, weather: str, grid: torch.Tensor, colors: torch.Tensor, mask: torch.Tensor) -> None:
        """Set the map of ``weather`` to the mean of ``colors`` [H, W, 3] where ``mask`` [H, W] holds,
        binned by map cell; cells never seen keep their value (a warm start before training)."""
        if self.shared and weather != self.weathers[0]:
            return
        k = 0 if self.shared else self.weathers.index(weather)
        rows, cols = self.logits.shape[2:]
        g = grid[0][mask]
        cx = ((g[:, 0] + 1) / 2 * cols - 0.5).round().clamp(0, cols - 1).long()
        cy = ((g[:, 1] + 1) / 2 * rows - 0.5).round().clamp(0, rows - 1).long()
        cell = cy * cols + cx
        dev = cell.device
        sums = torch.zeros(rows * cols, 3, device=dev).index_add_(0, cell, colors[mask].float())
        counts = torch.zeros(rows * cols, device=dev).index_add_(0, cell, torch.ones(len(cell), device=dev))
        seen = counts > 0
        mean = (sums[seen] / counts[seen, None]).clamp(0.02, 0.98)
        flat = self.logits.data[k].reshape(3, -1)
        flat[:, seen] = (torch.log(mean) - torch.log1p(-mean)).T
