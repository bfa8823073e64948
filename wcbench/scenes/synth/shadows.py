"""Which Gaussians of a scene the sun reaches, frame by frame: the cast shadows of the clear frames
(docs/design.md §3)."""

from __future__ import annotations

import math

import numpy as np

from wcbench.reference_model.transforms import quat_to_matrix
from wcbench.scenes.synth.content import Content, boxes_at, cloud_at
from wcbench.scenes.synth.geometry import Cloud, gaussian_normals
from wcbench.scenes.synth.layout import SIGMA_OF_SPACING
from wcbench.scenes.synth.raycast import RayBundle

__all__ = ["ShadowCaster"]

#: Shadow rays start this far (m) off their surface, on its sunny side: a surface never shades itself
#: (no shadow acne), and the offset is below a Gaussian's size.
_RAY_OFFSET_M = 0.02
#: Sun rays are traced from 4 points of each Gaussian's cell, each toward its own point of the sun
#: disk, at this fraction of the disk's radius: shadow edges cross a Gaussian in steps of a quarter
#: (no staircase of whole Gaussians) and blur by the sun's penumbra.
_DISK_SAMPLE = 0.6
#: Rays toward a point of the sun disk are culled as if they ran along its centre's line, widened by
#: how far they stray from it within this distance (m): no shadow in the street is longer.
_STRAY_M = 120.0


def _sample_rays(cloud: Cloud, s: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shadow rays of the Gaussians of ``cloud`` that face the sun (unit vector ``s``, disk of angular
    ``radius`` rad): 4 per Gaussian, from the quarter points of its cell (off the surface by
    :data:`_RAY_OFFSET_M`), each toward its own point of the disk.

    Returns
    -------
    facing : ndarray [N] bool
        The Gaussians facing the sun (n.s > 0): the only ones traced.
    points, dirs : ndarray [4 F, 3]
        Origins (m) and unit directions, the 4 rays of each facing Gaussian consecutive.
    """
    normals = gaussian_normals(cloud.quats, cloud.scales)
    facing = normals @ s > 0
    R = quat_to_matrix(cloud.quats[facing])
    scales = cloud.scales[facing]
    axes = np.argsort(scales, axis=1)[:, 1:]  # the two in-plane axes (the smallest is the normal)
    rows = np.arange(len(R))
    u = R[rows, :, axes[:, 0]] * (scales[rows, axes[:, 0]] / SIGMA_OF_SPACING / 4)[:, None]
    v = R[rows, :, axes[:, 1]] * (scales[rows, axes[:, 1]] / SIGMA_OF_SPACING / 4)[:, None]
    base = cloud.means[facing] + _RAY_OFFSET_M * normals[facing]
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]])
    points = (base[:, None] + corners[None, :, 0, None] * u[:, None] + corners[None, :, 1, None] * v[:, None]
              ).reshape(-1, 3)
    e1 = np.cross(s, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(s, e1)
    jitter = _DISK_SAMPLE * radius * np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [-1.0, 0.0]])
    disk = s + jitter[:, :1] * e1 + jitter[:, 1:] * e2
    disk /= np.linalg.norm(disk, axis=1, keepdims=True)
    dirs = np.broadcast_to(disk[None], (len(base), 4, 3)).reshape(-1, 3)
    return facing, points, dirs


class ShadowCaster:
    """Which Gaussians of a scene the sun reaches, frame by frame.

    Every Gaussian facing the sun casts 4 rays toward it (:func:`_sample_rays`) against the shapes the
    lidar sees (:func:`~.content.boxes_at`: buildings, trunks, parked and moving cars, pedestrians'
    limbs; the canopy spheres). The static Gaussians' rays are cast against the static shapes
    once; each frame adds the moving shapes, and the moving Gaussians' rays against everything, so
    moving objects' shadows move with them.

    Parameters
    ----------
    content : Content
        A scene whose profile has a :class:`~.layout.Sun`.
    """

    def __init__(self, content: Content) -> None:
        sun = content.spec.profile.sun
        if sun is None:
            raise ValueError(f"scene {content.spec.folder} has no sun")
        self.content = content
        self.sun = sun.direction()
        self.radius = math.radians(sun.angular_radius_deg)
        self.margin = _STRAY_M * math.tan(_DISK_SAMPLE * self.radius) + 0.05
        facing, points, dirs = _sample_rays(content.static, self.sun, self.radius)
        self._static_facing = facing
        self._static = RayBundle(points, dirs, self.sun, self.margin)
        b = content.boxes
        self._static_blocked = self._static.blocked((b.center, b.R, b.half), content.spheres)

    def visibility(self, k: int, cloud: Cloud | None = None) -> np.ndarray:
        """[N] share of the sun each Gaussian of frame ``k`` sees, in the order of
        :func:`~.content.cloud_at` (``cloud``: its result, when the caller has it); 1 for Gaussians
        facing away from the sun, which it does not light whatever the shapes (their shade is no
        cast shadow)."""
        boxes = boxes_at(self.content, k)
        moving = boxes.mover >= 0
        shapes = (boxes.center[moving], boxes.R[moving], boxes.half[moving])
        static = self._static.blocked(shapes, np.zeros((0, 4)), out=self._static_blocked.copy())
        out = [self._share(self._static_facing, static)]
        n_static = len(self.content.static)
        cloud = cloud_at(self.content, k) if cloud is None else cloud
        if len(cloud) > n_static:
            movers = Cloud(*(getattr(cloud, f)[n_static:] for f in Cloud.__dataclass_fields__))
            facing, points, dirs = _sample_rays(movers, self.sun, self.radius)
            bundle = RayBundle(points, dirs, self.sun, self.margin)
            out.append(self._share(facing, bundle.blocked((boxes.center, boxes.R, boxes.half), self.content.spheres)))
        return np.concatenate(out)

    @staticmethod
    def _share(facing: np.ndarray, blocked: np.ndarray) -> np.ndarray:
        """[N] visibility from the facing mask [N] and the blocked rays [4 F] of the facing ones."""
        vis = np.ones(len(facing))
        vis[facing] = 1.0 - blocked.reshape(-1, 4).mean(axis=1)
        return vis
