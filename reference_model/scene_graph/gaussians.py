"""A set of 3D Gaussians as float32 numpy arrays: the unit every scene-graph node holds."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.storage import atomic_write

__all__ = ["GaussianCloud"]


@dataclass
class GaussianCloud:
    """A set of 3D Gaussians (float32 numpy arrays).

    Attributes
    ----------
    means : ndarray [N, 3]
        Centers, world (m).
    quats : ndarray [N, 4]
        Rotations (w, x, y, z), unit.
    scales : ndarray [N, 3]
        Standard deviations along the local axes (m).
    opacities : ndarray [N]
        In [0, 1] (after the sigmoid).
    colors : ndarray [N, 3]
        RGB in [0, 1].
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.means).shape[0]
        shapes = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "colors": (n, 3)}
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), np.float32)
            if value.shape != shape:
                raise ValueError(f"GaussianCloud.{name} must have shape {shape}, got {value.shape}")
            setattr(self, name, np.ascontiguousarray(value))

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @classmethod
    def isotropic(cls, means: np.ndarray, scales: np.ndarray | float, colors: np.ndarray,
                  opacities: np.ndarray | float) -> GaussianCloud:
        """Unrotated spheres: the shape the lidar's points start as (each as wide as its spacing).

        Parameters
        ----------
        means : ndarray [N, 3]
            Centres, world (m).
        scales : ndarray [N] or float
            Standard deviation of each, the same along every axis (m).
        colors : ndarray [N, 3]
            RGB, clipped to [0, 1].
        opacities : ndarray [N] or float
            In [0, 1].
        """
        n = np.asarray(means).shape[0]
        quats = np.zeros((n, 4), np.float32)
        quats[:, 0] = 1.0
        s = np.broadcast_to(np.asarray(scales, np.float32), (n,))
        return cls(means=means, quats=quats, scales=np.repeat(s[:, None], 3, 1),
                   opacities=np.broadcast_to(np.asarray(opacities, np.float32), (n,)),
                   colors=np.clip(colors, 0.0, 1.0))

    def subset(self, keep: np.ndarray) -> GaussianCloud:
        """The Gaussians selected by a boolean mask or an index array."""
        return GaussianCloud(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    @staticmethod
    def concatenate(clouds: Iterable[GaussianCloud]) -> GaussianCloud:
        """All Gaussians of ``clouds`` in order."""
        clouds = list(clouds)
        return GaussianCloud(
            **{f.name: np.concatenate([getattr(c, f.name) for c in clouds]) for f in fields(GaussianCloud)}
        )

    def to_torch(self) -> dict[str, Any]:
        """The arrays as float32 torch tensors (sharing memory), keyed by field name."""
        import torch

        return {f.name: torch.from_numpy(getattr(self, f.name)) for f in fields(self)}

    def save_npz(self, path: str | Path) -> None:
        """Write the cloud as an ``.npz`` atomically."""
        atomic_write(path, lambda fh: np.savez(fh, **{f.name: getattr(self, f.name) for f in fields(self)}))

    @classmethod
    def load_npz(cls, path: str | Path) -> GaussianCloud:
        """Read a cloud written by :meth:`save_npz`.

        Raises
        ------
        InputError
            If the file is missing or lacks an array.
        """
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: Gaussian cloud file not found")
        with np.load(path) as data:
            missing = [f.name for f in fields(cls) if f.name not in data]
            if missing:
                raise InputError(f"{path}: Gaussian cloud lacks arrays {missing}")
            return cls(**{f.name: data[f.name] for f in fields(cls)})
