"""Scene-graph nodes placed per frame: rigid objects moved by their track, and the scene they form.

A :class:`RigidNode` keeps a moving object's Gaussians in its box frame (x along the length, z up)
and poses them with the track's object-to-world matrix of each annotated frame; a
:class:`SceneGaussians` is the static background plus those nodes, so :meth:`SceneGaussians.at_frame`
gives every Gaussian of a frame in world coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.transforms import apply_linear, quat_from_matrix, quat_multiply

__all__ = ["RigidNode", "SceneGaussians"]


@dataclass
class RigidNode:
    """A moving object's Gaussians in its box frame, posed per frame by its track.

    Attributes
    ----------
    track_id, class_name : str
    cloud : GaussianCloud
        Gaussians in the box frame (x along the length, z up; metres).
    frames : ndarray [M] int
        Frames where the track is annotated.
    object_to_world : ndarray [M, 4, 4]
        Box pose per annotated frame.
    """

    track_id: str
    class_name: str
    cloud: GaussianCloud
    frames: np.ndarray
    object_to_world: np.ndarray

    def at_frame(self, index: int) -> GaussianCloud | None:
        """The node's Gaussians in world coordinates at frame ``index``, or None if not annotated."""
        hit = np.nonzero(np.asarray(self.frames) == index)[0]
        if hit.size == 0:
            return None
        T = np.asarray(self.object_to_world[hit[0]], np.float64)
        means = apply_linear(self.cloud.means.astype(np.float64), T[:3, :3].T) + T[:3, 3]
        q_pose = quat_from_matrix(T[:3, :3])
        quats = quat_multiply(
            np.broadcast_to(q_pose, self.cloud.quats.shape), self.cloud.quats.astype(np.float64)
        )
        return GaussianCloud(
            means=means,
            quats=quats,
            scales=self.cloud.scales,
            opacities=self.cloud.opacities,
            colors=self.cloud.colors,
        )


@dataclass
class SceneGaussians:
    """Static Gaussians plus rigid nodes: the scene at any frame.

    Attributes
    ----------
    static : GaussianCloud
        World coordinates.
    nodes : list of RigidNode
    """

    static: GaussianCloud
    nodes: list[RigidNode]

    def __len__(self) -> int:
        return len(self.static) + sum(len(n.cloud) for n in self.nodes)

    def at_frame(self, index: int) -> GaussianCloud:
        """All Gaussians of frame ``index`` in world coordinates (nodes not annotated there are absent)."""
        parts = [self.static] + [c for n in self.nodes if (c := n.at_frame(index)) is not None]
        return parts[0] if len(parts) == 1 else GaussianCloud.concatenate(parts)
