"""The ego vehicle's own body in a camera's frames: a region fixed in the image, to mask, not weather.

A camera mounted on a car may see part of that car (a back camera its trunk, a front camera its
bonnet). That region moves with the camera: it is not part of the scene, so the weather editor
leaves its weather alone and training does not model it. :func:`ego_mask` finds it from the frames
alone, by comparing two explanations of each pixel's motion between frames k and k + 2 over the
whole sequence (docs/design.md §7, "Ego vehicle"):

* the **identity**: the pixel is fixed in the image (the ego body), so frame k + 2 equals frame k
  there;
* the **ground plane**: the pixel is the road, so frame k + 2 warped through the plane of the
  ground below the camera (its height from the lidar) equals frame k there.

E = mean over pairs of (|I_k - warp_ground(I_{k+2})| - |I_k - I_{k+2}|) is positive on the ego body
and negative on the road wherever they have texture (both are zero on a uniform surface); it counts
for a body only where the identity wins in at least two thirds of the pairs (a body is fixed in
every pair, a sidewalk the parked cars now and then hide from the ground's warp is not). The body
rises from the bottom of the image, so each column's boundary is the row above which E stops
paying (the maximum of the sum of E - 0.002 from the bottom up), median-filtered across columns; a
column the warp never reaches the bottom of (it leaves the frame) takes its neighbours' boundary,
and so does a short run of columns at a side of the image.
A region under 1 % of the image, or a scene whose camera barely moves (under 1 m over the
sequence: the two explanations coincide), gives no mask.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from scipy.ndimage import median_filter
from scipy.spatial import cKDTree

from wcbench.reference_model.scene_analysis.views import AnalysisViews
from wcbench.reference_model.scene_graph.completion import ground_height_below

__all__ = ["ego_mask"]

#: Bias per pixel subtracted from the evidence, per-column minimum sum, minimum area and travel.
_BIAS, _MIN_COLUMN_SUM, _MIN_AREA, _MIN_TRAVEL_M = 0.002, 0.15, 0.01, 1.0
_GAP = 2
#: A pixel is evidence of a body only where the identity explains it better than the ground in at least
#: this share of the frame pairs: the body is fixed in every pair, while a sidewalk that parked cars
#: hide from the ground's warp now and then is so in about half (pandaset_002_right: 0.36-0.61 over
#: a patch its mean evidence drew as a body, a skyline of bare patches in the snow; the back
#: camera's trunk 0.75-1.0, 10th to 90th percentile).
_MIN_FIXED_SHARE = 2.0 / 3.0


def _ground_warp(views: AnalysisViews, k: int, j: int, height: float) -> np.ndarray:
    """Frame ``j`` warped into frame ``k`` through the ground plane at ``height`` (along up; m);
    NaN where the plane is not seen below the horizon or lands outside frame ``j``."""
    rays = views.rays(k).astype(np.float64)
    up = views.up
    c = views.center(k)
    down = rays @ up
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (height - c @ up) / down
    ok = (down < -1e-3) & (t > 0)
    X = c + rays * np.where(ok, t, 0.0)[..., None]
    w2c = views.world_to_camera(j)
    cam = X.reshape(-1, 3) @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = views.K[j][0, 0] * cam[:, 0] / cam[:, 2] + views.K[j][0, 2] - 0.5
        v = views.K[j][1, 1] * cam[:, 1] / cam[:, 2] + views.K[j][1, 2] - 0.5
    map_x = np.where(ok.ravel() & (z > 0.1), u, -1e4).reshape(views.height, views.width).astype(np.float32)
    map_y = np.where(ok.ravel() & (z > 0.1), v, -1e4).reshape(views.height, views.width).astype(np.float32)
    out = cv2.remap(views.images[j], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=(np.nan, np.nan, np.nan))
    return out


def ego_mask(views: AnalysisViews, points: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """The ego vehicle's body in every frame (see the module docstring).

    Parameters
    ----------
    views : AnalysisViews
    points : ndarray [N, 3]
        Static lidar returns (world, m): the ground's height below each camera.

    Returns
    -------
    mask : ndarray [H, W] bool
        The same for every frame (the body is fixed in the image); all false when none is found.
    facts : dict
        The fraction of the image masked, or why there is no mask.
    """
    h, w = views.height, views.width
    none = np.zeros((h, w), bool)
    if len(views) <= _GAP:
        return none, {"ego_mask": "none: too few frames"}
    centers = np.stack([views.center(k) for k in range(len(views))])
    travel = float(np.linalg.norm(np.diff(centers, axis=0), axis=1).sum())
    if travel < _MIN_TRAVEL_M:
        return none, {"ego_mask": f"none: the camera travels {travel:.2f} m"}
    evidence = np.zeros((h, w), np.float64)
    count = np.zeros((h, w), np.float64)
    fixed = np.zeros((h, w), np.float64)
    # the ground below each camera is read from the returns near the path only
    pts = np.asarray(points, np.float64)
    flat = pts - np.outer(pts @ views.up, views.up)
    path = centers - np.outer(centers @ views.up, views.up)
    near, _ = cKDTree(path).query(flat, distance_upper_bound=16.0, workers=-1)
    pts = pts[np.isfinite(near)]
    for k in range(len(views) - _GAP):
        j = k + _GAP
        height = ground_height_below(pts, views.center(k), views.up)
        ground = _ground_warp(views, k, j, height)
        r_ground = np.abs(ground - views.images[k]).mean(axis=-1)
        r_fixed = np.abs(views.images[j] - views.images[k]).mean(axis=-1)
        ok = np.isfinite(r_ground)
        evidence[ok] += (r_ground - r_fixed)[ok]
        count[ok] += 1
        fixed[ok] += (r_ground > r_fixed)[ok]
    e = np.where(count > 0, evidence / np.maximum(count, 1), 0.0)
    # a body is fixed in (nearly) every pair, not on average
    e = np.where(fixed >= _MIN_FIXED_SHARE * count, e, np.minimum(e, 0.0))
    e = cv2.GaussianBlur(e.astype(np.float32), (0, 0), 2.0) - _BIAS
    # per column, the rows from the bottom up to where the cumulative evidence peaks
    cum = np.cumsum(e[::-1], axis=0)  # cum[i, c]: sum of the bottom i + 1 rows
    best = np.argmax(cum, axis=0)
    peak = cum[best, np.arange(w)]
    rows = np.where(peak > _MIN_COLUMN_SUM, best + 1, 0).astype(np.float64)
    # a column whose bottom the warp never reaches (it leaves the frame) has no evidence: it takes
    # its neighbours' boundary
    seen = (count[-max(1, h // 10):] > 0).mean(axis=0) > 0.5
    if seen.any() and not seen.all():
        rows[~seen] = np.interp(np.flatnonzero(~seen), np.flatnonzero(seen), rows[seen])
    rows = median_filter(np.round(rows).astype(np.int64), size=max(3, (w // 32) | 1), mode="nearest")
    # the image's side columns see the least motion of the road (it leaves the frame there): a short
    # run without a body at a side takes the boundary next to it
    body = np.flatnonzero(rows > 0)
    if body.size:
        edge = max(1, w // 8)
        if 0 < body[0] <= edge:
            rows[:body[0]] = rows[body[0]]
        if w - 1 - edge <= body[-1] < w - 1:
            rows[body[-1] + 1:] = rows[body[-1]]
    mask = np.arange(h)[:, None] >= (h - rows)[None, :]
    fraction = float(mask.mean())
    if fraction < _MIN_AREA:
        return none, {"ego_mask": f"none: {100 * fraction:.2f} % of the image is fixed in it"}
    return mask, {"ego_mask": f"{100 * fraction:.1f} % of the image (the ego vehicle's body, fixed in the frame)"}
