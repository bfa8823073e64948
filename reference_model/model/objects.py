"""Dynamic scene-graph nodes in torch: rigid objects moved by their track, pedestrians deformed per frame.

A rigid object keeps its Gaussians in its box frame (x along the length, z up) and is placed at
frame t by the track's object-to-world pose: mu_w = R_t mu + p_t, r_w = q_t * r. A non-rigid object
(a pedestrian) is placed the same way after a small learned per-frame offset of each Gaussian,
delta_t [N, 3] in the box frame, kept small and smooth in time by the training's regulariser
(docs/design.md §7). Frames where a track is not annotated have no Gaussians of it.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.transforms import quat_from_matrix

__all__ = ["NonRigidObject", "RigidObject", "place_objects", "quat_left_matrix", "quat_multiply_torch"]


def quat_multiply_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b of (w, x, y, z) quaternions, broadcast over leading axes."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


def quat_left_matrix(q: torch.Tensor) -> torch.Tensor:
    """The 4 x 4 matrices [..., 4, 4] of left multiplication by (w, x, y, z) quaternions [..., 4]:
    ``quat_multiply_torch(q, r) == r @ quat_left_matrix(q).T`` (one product for a whole node)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        torch.stack([w, -x, -y, -z], -1),
        torch.stack([x, w, -z, y], -1),
        torch.stack([y, z, w, -x], -1),
        torch.stack([z, -y, x, w], -1),
    ], -2)


def _refresh_after_load(module: nn.Module, _incompatible: object) -> None:
    module.refresh_poses()  # type: ignore[operator]


class RigidObject(nn.Module):
    """A boxed object's Gaussians in its box frame and its poses per scene frame (constant for one that
    does not move).

    Parameters
    ----------
    gaussians : GaussianParams
        In the box frame (m).
    track_id, class_name : str
    frames : ndarray [M] int
        Scene frames where the track is annotated.
    object_to_world : ndarray [M, 4, 4]
        Box pose at each of those frames.
    box_size : ndarray [3]
        Length, width, height (m), for edits and masks.
    n_frames : int
        Frames of the scene.
    """

    present: torch.Tensor  # [n_frames] bool
    rotation: torch.Tensor  # [n_frames, 3, 3]
    position: torch.Tensor  # [n_frames, 3]
    quat: torch.Tensor  # [n_frames, 4]
    quat_left: torch.Tensor  # [n_frames, 4, 4] quat_left_matrix(quat), derived (not saved)

    def __init__(self, gaussians: GaussianParams, *, track_id: str, class_name: str, frames: np.ndarray,
                 object_to_world: np.ndarray, box_size: np.ndarray, n_frames: int):
        super().__init__()
        self.gaussians = gaussians
        self.track_id, self.class_name = str(track_id), str(class_name)
        present = np.zeros(n_frames, bool)
        rot = np.tile(np.eye(3, dtype=np.float32), (n_frames, 1, 1))
        pos = np.zeros((n_frames, 3), np.float32)
        quat = np.tile(np.array([1, 0, 0, 0], np.float32), (n_frames, 1))
        for f, T in zip(np.asarray(frames, np.int64), np.asarray(object_to_world, np.float64)):
            if 0 <= f < n_frames:
                present[f] = True
                rot[f], pos[f], quat[f] = T[:3, :3], T[:3, 3], quat_from_matrix(T[:3, :3])
        self.register_buffer("present", torch.from_numpy(present))
        self.register_buffer("rotation", torch.from_numpy(rot))
        self.register_buffer("position", torch.from_numpy(pos))
        self.register_buffer("quat", torch.from_numpy(quat))
        self.register_buffer("quat_left", quat_left_matrix(self.quat), persistent=False)
        self._present_host = present.copy()
        # a loaded state brings its own poses: derive the matrices again from them
        self.register_load_state_dict_post_hook(_refresh_after_load)  # a named function: picklable
        self.box_size = np.asarray(box_size, np.float64).reshape(3)

    def refresh_poses(self) -> None:
        """Derive ``quat_left`` (and the host copy of ``present``) again after the poses changed (a
        loaded state, an edit of the track)."""
        self.quat_left = quat_left_matrix(self.quat)
        # read per node and frame: on a GPU, bool() of the buffer would wait for the device's queue
        self._present_host = self.present.detach().cpu().numpy().copy()

    def at(self, frame: int) -> bool:
        """Whether the object exists at ``frame``."""
        return 0 <= frame < len(self._present_host) and bool(self._present_host[frame])

    def local_means(self, frame: int) -> torch.Tensor:
        """[N, 3] box-frame centres at ``frame`` (the learned ones; deformed for non-rigid objects)."""
        return self.gaussians.means

    def world(self, frame: int, offset: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """World centres [N, 3] and rotations [N, 4] at ``frame``; ``offset`` [3] moves the box (edits)."""
        R, p = self.rotation[frame], self.position[frame]
        if offset is not None:
            p = p + offset
        # two products per node (not a dozen elementwise ops): a frame places ~20 nodes, per step
        means = torch.addmm(p, self.local_means(frame), R.T)
        quats = self.gaussians.quats @ self.quat_left[frame].T
        return means, quats


@functools.lru_cache(maxsize=16)
def _row_nodes(counts: tuple[int, ...], device: str) -> torch.Tensor:
    """[sum(counts)] int64: the index of the node each row belongs to (cached: the counts change only
    when densification does)."""
    rows = np.repeat(np.arange(len(counts)), counts)
    return torch.from_numpy(rows).to(device)


def place_objects(objects: Sequence[tuple[RigidObject, torch.Tensor | None]], frame: int, *,
                  batched: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """World centres [M, 3] and rotations [M, 4] of several objects at ``frame``, concatenated in order.

    Parameters
    ----------
    objects : sequence of (RigidObject, Tensor [3] or None)
        Objects present at ``frame`` and the world translation (m) added to each one's pose (edits).
    frame : int
    batched : bool
        ``False``: :meth:`RigidObject.world` per object, two small products each (the CPU's path).
        ``True``: one batched product for all of them, a few kernels however many objects there are:
        a GPU step is bound by its kernel launches, two per object forward and more backward
        (docs/workstation.md). The two agree within float32 rounding (the products' sums are ordered
        differently); tests compare them.

    Returns
    -------
    means : Tensor [M, 3]
    quats : Tensor [M, 4]
    """
    if not objects:
        raise ValueError("no objects to place")
    if not batched:
        placed = [obj.world(frame, offset) for obj, offset in objects]
        return torch.cat([m for m, _ in placed]), torch.cat([q for _, q in placed])
    local = torch.cat([obj.local_means(frame) for obj, _ in objects])
    quats = torch.cat([obj.gaussians.quats for obj, _ in objects])
    rotation = torch.stack([obj.rotation[frame] for obj, _ in objects])  # [K, 3, 3]
    position = torch.stack([obj.position[frame] if offset is None else obj.position[frame] + offset
                            for obj, offset in objects])  # [K, 3]
    left = torch.stack([obj.quat_left[frame] for obj, _ in objects])  # [K, 4, 4]
    rows = _row_nodes(tuple(len(obj.gaussians) for obj, _ in objects), str(local.device))
    means = torch.baddbmm(position[rows, :, None], rotation[rows], local[:, :, None])[..., 0]
    return means, torch.bmm(left[rows], quats[:, :, None])[..., 0]


class NonRigidObject(RigidObject):
    """A deformable object (pedestrian): a rigid object plus a learned per-frame offset of each Gaussian.

    The offsets start at zero; :meth:`deformation_penalty` is the regulariser that keeps them small
    and smooth in time.
    """

    def __init__(self, gaussians: GaussianParams, **kwargs: object):
        super().__init__(gaussians, **kwargs)  # type: ignore[arg-type]
        self.offsets = nn.Parameter(torch.zeros(len(self.present), len(gaussians), 3))

    def local_means(self, frame: int) -> torch.Tensor:
        """[N, 3] box-frame centres deformed for ``frame``."""
        return self.gaussians.means + self.offsets[frame]

    def deformation_penalty(self) -> torch.Tensor:
        """Mean squared offset plus mean squared change between consecutive frames (m^2)."""
        d = self.offsets
        if d.numel() == 0:
            return d.new_zeros(())
        smooth = (d[1:] - d[:-1]).square().mean() if len(d) > 1 else d.new_zeros(())
        return d.square().mean() + smooth
