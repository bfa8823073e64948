"""Small random and hand-made Gaussian scenes shared by the rasterizer tests."""

from __future__ import annotations

import torch

PARAM_NAMES = ("means", "quats", "scales", "opacities", "colors")


def pinhole(width: int, height: int, f: float) -> torch.Tensor:
    """[3, 3] intrinsics with the principal point at the image center."""
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def look_from(tx: float = 0.0, ty: float = 0.0, tz: float = 0.0) -> torch.Tensor:
    """[4, 4] world-to-camera with identity rotation and the camera at (tx, ty, tz)."""
    V = torch.eye(4)
    V[:3, 3] = -torch.tensor([tx, ty, tz])
    return V


def random_scene(
    n: int, *, seed: int, channels: int = 3, depth: float = 5.0, spread: float = 1.5,
    scale: tuple[float, float] = (0.01, 0.15), dtype: torch.dtype = torch.float32,
) -> dict[str, torch.Tensor]:
    """Random anisotropic Gaussians in front of an identity camera, parameters requiring grad."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([spread, spread * 0.7, 1.0])
    means[:, 2] += depth
    params = {
        "means": means,
        "quats": torch.randn(n, 4, generator=g),
        "scales": torch.rand(n, 3, generator=g) * (scale[1] - scale[0]) + scale[0],
        "opacities": torch.rand(n, generator=g),
        "colors": torch.rand(n, channels, generator=g),
    }
    return {k: v.to(dtype).requires_grad_(True) for k, v in params.items()}


def args(params: dict[str, torch.Tensor]) -> list[torch.Tensor]:
    """The parameters in rasterize's positional order."""
    return [params[k] for k in PARAM_NAMES]
