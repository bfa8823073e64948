"""Completing a view's distance map where the lidar does not reach.

A street camera sees more than its lidar: the road just in front of the car (below the lidar's
lowest beam) and the upper floors of the facades (above its highest). :func:`complete_distance`
fills those pixels with the two surfaces a street is made of (docs/design.md §7):

* below the horizon, the **ground plane** under the camera (the ray's intersection with it);
* above the horizon, a **vertical wall** continuing the nearest known pixel below in the same
  column (a vertical facade keeps its camera depth along a column when the camera is level). A
  pole, a wire, a mast or a sign in front of a facade is nearer than the facade and thin: the
  camera depth a wall continues is the grey-scale closing (Serra 1982: a running maximum, then a
  running minimum, over a square window, among the known pixels only) of the known pixels', so a
  near thing thinner than the window lends the facade behind it its depth, not its own. The known
  pixels keep their own distance.

The sky stays infinitely far. The WeatherCity build places Gaussians on the completed surfaces
(:func:`~wcbench.reference_model.training.build.completion_cloud`) and the weather editor shades
them (:mod:`wcbench.reference_model.appearance.maps`).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

__all__ = ["FILL_GROUND", "FILL_KNOWN", "FILL_SKY", "FILL_WALL", "closing_among", "complete_distance",
           "ground_height_below"]

#: What each pixel of a completed map is.
FILL_KNOWN, FILL_GROUND, FILL_WALL, FILL_SKY = 0, 1, 2, 3


def ground_height_below(points: np.ndarray, center: np.ndarray, up: np.ndarray, *, radius_m: float = 15.0,
                        camera_height_m: float = 1.6) -> float:
    """Height (along ``up``, m) of the ground around a camera: the 5th percentile of the heights of
    the points within ``radius_m`` sideways, or ``camera_height_m`` below the camera without any.

    Parameters
    ----------
    points : ndarray [N, 3]
        Lidar points (world, m).
    center : ndarray [3]
        Camera centre.
    up : ndarray [3]
        Unit up vector.
    """
    p = np.asarray(points, np.float64)
    c = np.asarray(center, np.float64)
    h = p @ up
    side = (p - c) - np.outer(h - c @ up, up)
    near = np.einsum("ij,ij->i", side, side) < radius_m ** 2
    below = near & (h < c @ up - 0.5)
    if not np.any(below):
        return float(c @ up - camera_height_m)
    return float(np.percentile(h[below], 5))


def complete_distance(distance: np.ndarray, known: np.ndarray, sky: np.ndarray, rays: np.ndarray,
                      center: np.ndarray, up: np.ndarray, ground_height: float, *, forward: np.ndarray,
                      ground_at: Callable[[np.ndarray], np.ndarray] | None = None,
                      thin_fraction: float = 1.0 / 40.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill the unknown pixels of a distance map (see the module docstring).

    Parameters
    ----------
    distance : ndarray [H, W]
        Distance along each pixel's ray (m), read where ``known``.
    known : ndarray [H, W] bool
    sky : ndarray [H, W] bool
        Sky pixels (never filled; ``inf``).
    rays : ndarray [H, W, 3]
        Unit world ray of each pixel.
    center : ndarray [3]
        Camera centre (world, m).
    up : ndarray [3]
        Unit up vector.
    ground_height : float
        The ground plane's height along ``up`` (m).
    forward : ndarray [3]
        The camera's optical axis in the world (its z axis): camera depth = distance x (ray . forward).
    ground_at : callable, optional
        ``ground_at(points [N, 3]) -> [N]`` heights (along ``up``, m) of a ground that is not level
        (a fitted height field): the ray's intersection with it is found by three fixed-point steps
        from the plane at ``ground_height`` (each re-intersects the horizontal plane at the height
        found under the last point). Default: the plane.
    thin_fraction : float
        Half the side of the closing's window, as a share of the image width (1/40: 12 px at 480
        wide, a pole, a wire or a sign up to 24 px thick); 0 continues each column's own pixel.

    Returns
    -------
    distance : ndarray [H, W] float64
        Completed; ``inf`` on the sky, and on an unknown pixel with nothing at a finite distance
        below it in its column (a ray below the horizon that misses the ground, as a street rising
        ahead makes it, is a wall too).
    kind : ndarray [H, W] int8
        :data:`FILL_KNOWN`, :data:`FILL_GROUND`, :data:`FILL_WALL` or :data:`FILL_SKY`.
    source : ndarray [H, W] int64
        For a wall pixel, the row it continues in its column; -1 elsewhere.
    """
    h, w = known.shape
    out = np.where(known & ~sky, np.asarray(distance, np.float64), np.inf)
    kind = np.full((h, w), FILL_KNOWN, np.int8)
    kind[sky] = FILL_SKY
    ray_up = np.asarray(rays, np.float64) @ np.asarray(up, np.float64)
    todo = ~known & ~sky
    ground = todo & (ray_up < -1e-3)
    if np.any(ground):
        c = np.asarray(center, np.float64)
        t = (ground_height - c @ up) / ray_up[ground]
        if ground_at is not None:
            r = np.asarray(rays, np.float64)[ground]
            for _ in range(3):
                hit = c + r * np.where(t > 0, t, 0.0)[:, None]
                t = (np.asarray(ground_at(hit), np.float64) - c @ up) / ray_up[ground]
        out[ground] = np.where(t > 0, t, np.inf)
        # a ray just below the horizon can miss a ground that rises ahead (a street uphill):
        # no ground there, a wall as above the horizon, never a pixel with nothing to rise from
        ground &= np.isfinite(out)
        kind[ground] = FILL_GROUND
    source = np.full((h, w), -1, np.int64)
    wall = todo & ~ground
    if np.any(wall):
        # the nearest known (or ground) pixel below each pixel in its column at a finite distance:
        # the surface it rises from
        drawn = ((known & ~sky) | ground) & np.isfinite(out)
        rows = np.where(drawn, np.arange(h)[:, None], h)
        below_row = np.minimum.accumulate(rows[::-1], axis=0)[::-1]
        rr, cc = np.nonzero(wall)
        src = below_row[rr, cc]
        has = src < h
        src_c = np.minimum(src, h - 1)
        unit = np.asarray(rays, np.float64)
        axis = np.asarray(forward, np.float64) / np.linalg.norm(forward)
        cos_dst = unit[rr, cc] @ axis
        camera_depth = out * (unit @ axis)
        half = round(w * thin_fraction)
        if half > 0:
            camera_depth = closing_among(camera_depth, drawn & np.isfinite(camera_depth), half)
        depth_src = camera_depth[src_c, cc]
        value = np.where(has & np.isfinite(depth_src), depth_src / np.maximum(cos_dst, 1e-6), np.inf)
        out[rr, cc] = value
        kind[rr, cc] = np.where(np.isfinite(value), FILL_WALL, FILL_SKY)
        source[rr, cc] = np.where(np.isfinite(value), src, -1)
    return out, kind, source


def closing_among(values: np.ndarray, mask: np.ndarray, half: int) -> np.ndarray:
    """[H, W] the grey-scale closing of ``values`` over a ``2 half + 1`` square window among the
    pixels of ``mask`` only (the others neither give nor take, and are returned unchanged): a dip
    thinner than the window (a near thing before a far one) is filled; a step or a plateau wider
    than it is kept. OpenCV's min/max filters in float32 (camera depths in metres keep 1e-5 m)."""
    big = np.float32(3e38)
    kernel = np.ones((2 * half + 1, 2 * half + 1), np.uint8)
    v = np.asarray(values, np.float32)
    opts = {"borderType": cv2.BORDER_CONSTANT}
    dilated = cv2.dilate(np.where(mask, v, -big), kernel, borderValue=-float(big), **opts)
    closed = cv2.erode(np.where(mask, dilated, big), kernel, borderValue=float(big), **opts)
    return np.where(mask, closed.astype(np.float64), values)
