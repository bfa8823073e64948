"""Every frame of a scene at the analysis size: the images, the scaled cameras and their rays.

The analyses of :mod:`wcbench.reference_model.scene_analysis` look at all frames of a scene at
once, at one modest size (480 px wide by default: the weather editor's and WeatherCity's working
width), and hand their results to consumers at any size (:func:`resample_mask`). A resize scales
the intrinsics exactly, K' = diag(W'/W, H'/H, 1) K (docs/design.md §2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from wcbench.core.image_io import read_rgb8
from wcbench.reference_model.transforms import project_points

__all__ = ["ANALYSIS_WIDTH", "AnalysisViews", "PointColumns", "analysis_size", "build_analysis_views", "pixel_indices",
           "resample_mask"]

#: Width (px) the scene analyses run at, unless the frames are narrower.
ANALYSIS_WIDTH = 480


def analysis_size(image_size: tuple[int, int], width: int = ANALYSIS_WIDTH) -> tuple[int, int]:
    """(width, height) of the analysis: ``width`` px wide at the frames' aspect ratio, or the frames'
    own size when they are narrower."""
    w, h = int(image_size[0]), int(image_size[1])
    if w <= width:
        return w, h
    return int(width), max(1, round(width * h / w))


@dataclass
class AnalysisViews:
    """A scene's frames at one size.

    Attributes
    ----------
    size : (int, int)
        (width, height) in pixels.
    images : list of ndarray [H, W, 3] float32
        Display RGB in [0, 1], area-resized from the frames.
    K : list of ndarray [3, 3] float64
        Intrinsics at ``size`` (pixel centres at +0.5).
    camera_to_world : list of ndarray [4, 4] float64
        OpenCV axes (x right, y down, z forward).
    up : ndarray [3] float64
        The scene's unit up vector.
    times : ndarray [F] float64
        Seconds since the first frame.
    """

    size: tuple[int, int]
    images: list[np.ndarray]
    K: list[np.ndarray]
    camera_to_world: list[np.ndarray]
    up: np.ndarray
    times: np.ndarray

    def __len__(self) -> int:
        return len(self.images)

    @property
    def width(self) -> int:
        """Width in pixels."""
        return int(self.size[0])

    @property
    def height(self) -> int:
        """Height in pixels."""
        return int(self.size[1])

    def world_to_camera(self, k: int) -> np.ndarray:
        """[4, 4] inverse pose of frame ``k``."""
        c2w = self.camera_to_world[k]
        out = np.eye(4)
        out[:3, :3] = c2w[:3, :3].T
        out[:3, 3] = -c2w[:3, :3].T @ c2w[:3, 3]
        return out

    def center(self, k: int) -> np.ndarray:
        """[3] camera position of frame ``k`` (m)."""
        return np.asarray(self.camera_to_world[k][:3, 3], np.float64)

    def rays(self, k: int) -> np.ndarray:
        """[H, W, 3] float32 unit world directions of the rays through the pixel centres of frame ``k``."""
        K = self.K[k]
        xs = (np.arange(self.width) + 0.5 - K[0, 2]) / K[0, 0]
        ys = (np.arange(self.height) + 0.5 - K[1, 2]) / K[1, 1]
        d = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], np.ones((self.height, self.width))), -1)
        d = d @ self.camera_to_world[k][:3, :3].T
        return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)

    def elevation(self, k: int) -> np.ndarray:
        """[H, W] float32 sine of each pixel's ray elevation above the horizontal (the plane normal to up)."""
        return (self.rays(k) @ self.up.astype(np.float32)).astype(np.float32)

    def project(self, points: np.ndarray, k: int, *, near: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels of world ``points`` [N, 3] in frame ``k``.

        Returns
        -------
        ij : ndarray [N, 2] int64
            (column, row) of the pixel each point falls in (floor of its projection).
        depth : ndarray [N] float64
            Camera z (m).
        inside : ndarray [N] bool
            In front of the camera (z > ``near``) and inside the image.
        """
        uv, z = project_points(np.asarray(points, np.float64), self.world_to_camera(k), self.K[k])
        with np.errstate(invalid="ignore"):
            ij = np.floor(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)).astype(np.int64)
        inside = (z > near) & (ij[:, 0] >= 0) & (ij[:, 0] < self.width) & (ij[:, 1] >= 0) & (ij[:, 1] < self.height)
        return ij, z, inside

    def hit_map(self, points: np.ndarray | PointColumns, k: int) -> np.ndarray:
        """[H, W] bool: the pixels of frame ``k`` that at least one of ``points`` ([N, 3] world, or
        :class:`PointColumns` of them, faster for many frames) projects into (z > 0.1 m).

        The projection runs in float32 on coordinates relative to the camera (re-based scenes keep
        them within a few hundred metres: under a millimetre of error, far below a pixel)."""
        cols = points if isinstance(points, PointColumns) else PointColumns.of(points)
        out = np.zeros((self.height, self.width), bool)
        if cols.n == 0:
            return out
        w2c = self.world_to_camera(k)
        R, t = w2c[:3, :3], w2c[:3, 3] + w2c[:3, :3] @ cols.origin
        K = self.K[k]
        r = R.astype(np.float32)
        z = cols.x * r[2, 0] + cols.y * r[2, 1] + cols.z * r[2, 2] + np.float32(t[2])
        front = np.nonzero(z > 0.1)[0]
        if front.size == 0:
            return out
        x, y, zf = cols.x[front], cols.y[front], z[front]
        cx = x * np.float32(R[0, 0]) + y * np.float32(R[0, 1]) + cols.z[front] * np.float32(R[0, 2]) + np.float32(t[0])
        cy = x * np.float32(R[1, 0]) + y * np.float32(R[1, 1]) + cols.z[front] * np.float32(R[1, 2]) + np.float32(t[1])
        u = np.floor(cx / zf * np.float32(K[0, 0]) + np.float32(K[0, 2])).astype(np.int32)
        v = np.floor(cy / zf * np.float32(K[1, 1]) + np.float32(K[1, 2])).astype(np.int32)
        ok = (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
        out.ravel()[v[ok] * self.width + u[ok]] = True
        return out


@dataclass(frozen=True)
class PointColumns:
    """World points as three contiguous float32 columns relative to ``origin`` (their mean): fast to
    project into many frames (:meth:`AnalysisViews.hit_map`)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    origin: np.ndarray

    @property
    def n(self) -> int:
        """Number of points."""
        return len(self.x)

    @classmethod
    def of(cls, points: np.ndarray) -> PointColumns:
        """The columns of ``points`` [N, 3] (world, m)."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        origin = p.mean(axis=0) if len(p) else np.zeros(3)
        rel = (p - origin).astype(np.float32)
        return cls(x=np.ascontiguousarray(rel[:, 0]), y=np.ascontiguousarray(rel[:, 1]),
                   z=np.ascontiguousarray(rel[:, 2]), origin=origin)


def pixel_indices(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray, size: tuple[int, int], *,
                  near: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(column [N] int64, row [N] int64, camera depth [N], inside [N] bool) of world ``points``
    [N, 3] in a pinhole view of (width, height) ``size`` (pixel centres at +0.5, so the pixel is the
    floor of the projection); inside: in front (z > ``near``) and within the image."""
    w2c = np.asarray(world_to_camera, np.float64)
    cam = np.asarray(points, np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.floor(np.nan_to_num(K[0, 0] * cam[:, 0] / z + K[0, 2], nan=-1.0, posinf=-1.0, neginf=-1.0))
        v = np.floor(np.nan_to_num(K[1, 1] * cam[:, 1] / z + K[1, 2], nan=-1.0, posinf=-1.0, neginf=-1.0))
    u, v = u.astype(np.int64), v.astype(np.int64)
    inside = (z > near) & (u >= 0) & (u < size[0]) & (v >= 0) & (v < size[1])
    return u, v, z, inside


def build_analysis_views(scene: Any, size: tuple[int, int]) -> AnalysisViews:
    """The frames of ``scene`` (a :class:`wcbench.scenes.scene.Scene` or any object with its
    attributes) at ``size``: images area-resized, intrinsics scaled.

    Parameters
    ----------
    scene : Scene
    size : (int, int)
        (width, height) in pixels.

    Returns
    -------
    AnalysisViews
    """
    w, h = int(size[0]), int(size[1])
    images, Ks, poses = [], [], []
    for f in scene.frames:
        cam = f.camera
        img = read_rgb8(f.image_path)
        if (img.shape[1], img.shape[0]) != (w, h):
            interp = cv2.INTER_AREA if w * h < img.shape[0] * img.shape[1] else cv2.INTER_LINEAR
            img = cv2.resize(img, (w, h), interpolation=interp)
        images.append(img.astype(np.float32) / 255.0)
        Ks.append(np.diag([w / cam.width, h / cam.height, 1.0]) @ np.asarray(cam.K, np.float64))
        poses.append(np.asarray(cam.camera_to_world, np.float64))
    up = np.asarray(scene.up, np.float64)
    t0 = float(scene.frames[0].timestamp)
    return AnalysisViews(size=(w, h), images=images, K=Ks, camera_to_world=poses, up=up / np.linalg.norm(up),
                         times=np.array([float(f.timestamp) - t0 for f in scene.frames]))


def resample_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A [H, W] mask (bool or float in [0, 1]) at another (width, height): area-averaged when
    shrinking, bilinear when enlarging; a bool mask is thresholded at 0.5 afterwards."""
    m = np.asarray(mask)
    if (m.shape[1], m.shape[0]) == tuple(size):
        return m.copy()
    src = m.astype(np.float32)
    interp = cv2.INTER_AREA if size[0] * size[1] < m.shape[0] * m.shape[1] else cv2.INTER_LINEAR
    out = cv2.resize(src, (int(size[0]), int(size[1])), interpolation=interp)
    return out >= 0.5 if m.dtype == bool else out
