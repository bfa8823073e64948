"""The lidar's registration to a camera: a time offset found from the scene's own edges.

A real camera's frames and its lidar sweeps can disagree by a small time offset: each sweep's
returns land where the structure was a few tens of milliseconds before or after the frame, so on
a camera that looks sideways from a moving car the returns of a near pole run several pixels past
its edge into open sky (``pandaset_002_right``: 3-10 px at 480 px wide; docs/findings.md, "The
lidar's registration"). Those returns are trusted (never sky) by every consumer of the analysis.

:func:`fit_time_offset` finds the offset dt that best aligns the lidar's depth discontinuities
(returns at a range jump: the near edge of a pole or a facade against far background or sky) with
the image's edges, the objective of Levinson & Thrun, "Automatic online calibration of cameras and
lasers", RSS 2013: the sum over discontinuity returns of an inverse-distance-transformed edge map
at their projection, here over a time offset instead of a rotation (each frame's camera moved by
its velocity times dt; docs/design.md §7, "The lidar's registration"). The offset is kept only
when the evidence supports it: a peak of the objective pooled over the frames that stands out on
both sides, a gain over no offset, and per-frame optima that agree; otherwise it is 0 and the
given poses stand. :meth:`LidarTimeOffset.apply` moves each sweep's returns by ``-v dt`` (v the
camera's velocity at that frame), so that every projection of the analysis (trusted and
every-sweep hits, the sky, the editor's surfaces) uses the registered returns.

The objective rewards moving the returns into textured interiors, which a radial motion (a camera
looking along the drive) does for every edge at once; a lateral motion shifts both edges of a
structure the same way, so only there is the peak meaningful. The guards (a peak inside the
searched range that drops on both sides) reject the radial case rather than follow it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from wcbench.reference_model.scene_analysis.motion import LidarReturns
from wcbench.reference_model.scene_analysis.views import AnalysisViews

__all__ = ["LidarTimeOffset", "edge_field", "fit_time_offset", "range_edges"]

#: Offsets searched (s): +-_DT_MAX_S in steps of _DT_STEP_S (10 Hz sweeps: at most a tenth of one).
_DT_MAX_S, _DT_STEP_S = 0.1, 0.005
#: Kept only when the pooled objective at its peak exceeds that at 0 by this share ...
_MIN_GAIN = 0.05
#: ... falls by this share of the peak within _SIDE_S on both sides (a peak, not a ramp) ...
_MIN_DROP, _SIDE_S = 0.04, 0.05
#: ... and the per-frame optima's interquartile range is at most this (s).
_MAX_SPREAD_S = 0.02
#: Inverse distance transform of the edge map (Levinson & Thrun's alpha and gamma), per pixel at a
#: width of 960 px, and its reach (px at 960).
_EDGE_ALPHA, _EDGE_GAMMA, _EDGE_REACH = 1.0 / 3.0, 0.9, 12
#: A discontinuity: a return whose neighbours on one side (within _NEIGHBOUR_PX across and
#: _NEIGHBOUR_ROWS up or down, at 960 px) continue its surface and on the other side lie all behind
#: it by more than 1 m + 30 % of its range, or are missing (sky); only returns nearer than _NEAR_M.
_NEIGHBOUR_PX, _NEIGHBOUR_ROWS, _NEAR_M = 10.0, 4.0, 40.0
#: At most this many nearest neighbours are looked at.
_NEIGHBOURS = 24
#: Frames with fewer discontinuities than this do not vote.
_MIN_EDGES = 20


@dataclass(frozen=True)
class LidarTimeOffset:
    """The lidar's time offset to the camera.

    Attributes
    ----------
    seconds : float
        dt (s): frame k's returns are moved by ``-v_k dt``; 0 when the evidence did not support one.
    facts : dict
        For ``info.json``: the pooled peak, its gain, the per-frame spread, why it was kept or not.
    """

    seconds: float
    facts: dict[str, Any] = field(default_factory=dict)

    def apply(self, views: AnalysisViews, returns: LidarReturns) -> LidarReturns:
        """``returns`` with each sweep moved by ``-v dt`` (``returns`` itself when dt is 0)."""
        if self.seconds == 0.0:
            return returns
        vel = camera_velocities(views)
        return dataclasses.replace(returns, points={j: p - vel[j] * self.seconds for j, p in returns.points.items()})


def camera_velocities(views: AnalysisViews) -> np.ndarray:
    """[F, 3] world velocity (m/s) of each frame's camera (central differences of the poses)."""
    centers = np.array([views.center(k) for k in range(len(views))])
    if len(views) < 2:
        return np.zeros_like(centers)
    return np.gradient(centers, views.times, axis=0)


def edge_field(image: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """[H, W] float32 edge strength of an image for the alignment: Levinson & Thrun's inverse
    distance transform of its edges, alpha E + (1 - alpha) max_r gamma^r max_{|d| <= r} E.

    Parameters
    ----------
    image : ndarray [H, W, 3]
        Display RGB in [0, 1].
    scale : float
        Width / 960: the transform's decay and reach are per pixel at 960 px wide.

    Notes
    -----
    E is the horizontal gradient's magnitude, normalised to 1: a range jump along a scan line is a
    vertical edge, and horizontal texture (kerbs, roof lines) would pull the returns up or down.
    """
    gray = cv2.cvtColor(np.clip(image * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
    e = np.abs(cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3))
    e /= max(float(e.max()), 1e-6)
    reach = max(1, round(_EDGE_REACH * scale))
    gamma = _EDGE_GAMMA ** (1.0 / max(scale, 1e-6))
    spread = e.copy()
    for r in range(1, reach + 1):
        spread = np.maximum(spread, cv2.dilate(e, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) * np.float32(gamma ** r))
    return (_EDGE_ALPHA * e + (1.0 - _EDGE_ALPHA) * spread).astype(np.float32)


def range_edges(uv: np.ndarray, depth: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """[N] float64 weight of each return as a depth discontinuity (0 where it is none): the square
    root of its range jump (m, at most 10; Levinson & Thrun's gamma 1/2).

    Parameters
    ----------
    uv : ndarray [N, 2]
        Projections (px).
    depth : ndarray [N]
        Camera z (m).
    scale : float
        Width / 960 (the neighbourhood is in pixels at 960 px wide).
    """
    n = len(depth)
    out = np.zeros(n)
    if n < 3:
        return out
    du, dv = _NEIGHBOUR_PX * scale, max(_NEIGHBOUR_ROWS * scale, 1.0)
    xy = np.c_[uv[:, 0], uv[:, 1] * (du / dv)]
    near = np.nonzero(depth < _NEAR_M)[0]
    if len(near) == 0:
        return out
    # the _NEIGHBOURS nearest returns within the neighbourhood (index n where there are fewer)
    _, nb = cKDTree(xy).query(xy[near], k=min(_NEIGHBOURS + 1, n), distance_upper_bound=du)
    nb = nb.reshape(len(near), -1)
    valid = (nb < n) & (nb != near[:, None])
    nb = np.where(valid, nb, 0)
    z = depth[near][:, None]
    zn, un = depth[nb], uv[nb, 0]
    jump = np.zeros((len(near), 2))
    same = np.zeros((len(near), 2), bool)
    for s, side in enumerate((valid & (un < uv[near, 0][:, None]), valid & (un > uv[near, 0][:, None]))):
        nearest_behind = np.where(side, zn, np.inf).min(axis=1) - z[:, 0]
        jump[:, s] = np.where(side.any(axis=1), np.maximum(nearest_behind, 0.0), 10.0)  # empty: sky or a gap
        same[:, s] = (side & (np.abs(zn - z) < 0.1 + 0.03 * z)).sum(axis=1) >= 2
    # the surface continues on one side; the other is empty or wholly behind
    j = np.maximum(np.where(same[:, 1], jump[:, 0], 0.0), np.where(same[:, 0], jump[:, 1], 0.0))
    edge = j > 1.0 + 0.3 * z[:, 0]
    out[near[edge]] = np.minimum(j[edge], 10.0) ** 0.5
    return out


def fit_time_offset(views: AnalysisViews, returns: LidarReturns) -> LidarTimeOffset:
    """The time offset between ``views``' frames and their own sweeps (see the module docstring).

    Parameters
    ----------
    views : AnalysisViews
    returns : LidarReturns
        Each frame's sweep; only its static returns are used.

    Returns
    -------
    LidarTimeOffset
        0 s unless the pooled objective has a clear peak that the frames agree on.
    """
    dts = np.round(np.arange(-_DT_MAX_S, _DT_MAX_S + _DT_STEP_S / 2, _DT_STEP_S), 4)
    zero = int(np.argmin(np.abs(dts)))
    scale = views.width / 960.0
    vel = camera_velocities(views)
    curves, frames = [], []
    for k, pts in sorted(returns.points.items()):
        p = pts[returns.static_mask(k)]
        w2c = views.world_to_camera(k)
        cam = p @ w2c[:3, :3].T + w2c[:3, 3]
        K = views.K[k]
        cam = cam[cam[:, 2] > 0.5]
        uv = np.c_[K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < views.width) & (uv[:, 1] >= 0) & (uv[:, 1] < views.height)
        weight = range_edges(uv[inside], cam[inside, 2], scale=scale)
        sel = weight > 0
        if sel.sum() < _MIN_EDGES:
            continue
        edge_pts, w = cam[inside][sel], weight[sel]
        field_k = edge_field(views.images[k], scale=scale)
        v_cam = w2c[:3, :3] @ vel[k]
        curve = np.empty(len(dts))
        for i, dt in enumerate(dts):
            q = edge_pts - v_cam * dt
            ok = q[:, 2] > 0.5
            u = np.floor(K[0, 0] * q[ok, 0] / q[ok, 2] + K[0, 2]).astype(np.int64)
            v = np.floor(K[1, 1] * q[ok, 1] / q[ok, 2] + K[1, 2]).astype(np.int64)
            keep = (u >= 0) & (u < views.width) & (v >= 0) & (v < views.height)
            curve[i] = float((w[ok][keep] * field_k[v[keep], u[keep]]).sum())
        curves.append(curve)
        frames.append(k)
    facts: dict[str, Any] = {"frames": len(frames), "searched_s": [float(dts[0]), float(dts[-1])]}
    if not curves:
        return LidarTimeOffset(0.0, {**facts, "kept": False, "why": "no frame with enough range edges"})
    pooled = np.sum(curves, axis=0)
    best = int(np.argmax(pooled))
    per_frame = np.array([dts[int(np.argmax(c))] for c in curves])
    q1, q3 = np.percentile(per_frame, [25, 75])
    side = round(_SIDE_S / _DT_STEP_S)
    left, right = pooled[max(0, best - side):best + 1], pooled[best:best + side + 1]
    gain = float(pooled[best] / max(pooled[zero], 1e-12) - 1.0)
    drop = float(min(pooled[best] - left.min(), pooled[best] - right.min()) / max(pooled[best], 1e-12))
    facts.update({"peak_s": float(dts[best]), "gain": round(gain, 4), "drop": round(drop, 4),
                  "per_frame_iqr_s": [float(q1), float(q3)]})
    checks = {"a peak inside the range": 0 < best < len(dts) - 1, "gain": gain >= _MIN_GAIN,
              "drops on both sides": drop >= _MIN_DROP, "frames agree": q3 - q1 <= _MAX_SPREAD_S}
    failed = [name for name, ok in checks.items() if not ok]
    if failed:
        return LidarTimeOffset(0.0, {**facts, "kept": False, "why": "no support: " + ", ".join(failed)})
    return LidarTimeOffset(float(dts[best]), {**facts, "kept": True})
