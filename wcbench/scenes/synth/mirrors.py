"""What the wet ground of a synthetic street mirrors: the view ray reflected at each wet Gaussian,
traced against the street's own shapes (docs/design.md §3, "Harder synthetic scene").

A wet road is a mirror of what stands above it: the cars ahead, the trunks and canopies, the far
facades, and the sky only where the reflected ray meets none of them. The harder truth's profile
(``Profile.traced_mirrors``) casts that ray against the boxes and canopy spheres the lidar and the
sun's shadows are cast against (:mod:`.raycast`) and the ground plane, and the mirror shows the
colour the scene has where the ray meets it (the nearest Gaussian's, shaded under the same
weather, one bounce), hazed over the reflected path as the camera's own path is (Koschmieder).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from wcbench.scenes.synth.content import Boxes
from wcbench.scenes.synth.light import linear_to_srgb, srgb_to_linear
from wcbench.scenes.synth.raycast import box_entry, sphere_entry

__all__ = ["RAY_OFFSET_M", "mirror_hits", "mirrored_colors", "mirrors_meeting", "reflected_rays"]

#: Reflected rays start this far (m) along their direction off the Gaussian: the surface never
#: mirrors itself, and the offset is below a Gaussian's size.
RAY_OFFSET_M = 0.05


def reflected_rays(means: np.ndarray, normals: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """[N, 3] unit directions of the view rays from ``eye`` [3] (m) to ``means`` [N, 3] (m), mirrored
    about the unit ``normals`` [N, 3] (the reflection law: r = v - 2 (v . n) n)."""
    view = np.asarray(means, np.float64) - np.asarray(eye, np.float64)
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-9)
    n = np.asarray(normals, np.float64)
    r = view - 2.0 * np.sum(view * n, axis=1, keepdims=True) * n
    out: np.ndarray = r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-9)
    return out


def mirror_hits(origins: np.ndarray, dirs: np.ndarray, boxes: Boxes, spheres: np.ndarray, *,
                ground_z: float | None = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The distance (m) along each ray to the first box, canopy sphere or ground it meets (inf where it
    meets none), and which box that is (-1: a sphere, the ground or nothing).

    Parameters
    ----------
    origins : ndarray [N, 3]
        Ray origins (m, street coordinates, z up).
    dirs : ndarray [N, 3]
        Unit directions.
    boxes : Boxes
        The oriented boxes (:func:`~.content.boxes_at`).
    spheres : ndarray [K, 4]
        Centres and radii (m) of the canopies.
    ground_z : float or None
        Height (m) of the ground plane a downward ray meets; ``None``: no ground.

    Returns
    -------
    t : ndarray [N]
    box : ndarray [N] int
        Index into ``boxes`` of the shape met first, -1 where that is no box.
    """
    o, d = np.asarray(origins, np.float64), np.asarray(dirs, np.float64)
    t = np.full(len(o), np.inf)
    box = np.full(len(o), -1, np.int64)
    for m, (c, R, h) in enumerate(zip(boxes.center, boxes.R, boxes.half)):
        e = box_entry((o - c) @ R, d @ R, h)
        box[e < t] = m
        t = np.minimum(t, e)
    for s in np.asarray(spheres, np.float64).reshape(-1, 4):
        e = sphere_entry(s[:3] - o, d, float(s[3]))
        box[e < t] = -1
        t = np.minimum(t, e)
    if ground_z is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            g = (ground_z - o[:, 2]) / d[:, 2]
        e = np.where((d[:, 2] < 0) & (g > 0), g, np.inf)
        box[e < t] = -1
        t = np.minimum(t, e)
    return t, box


def mirrors_meeting(means: np.ndarray, normals: np.ndarray, eye: np.ndarray, mirrors: np.ndarray, boxes: Boxes,
                    spheres: np.ndarray, mover: int, *, ground_z: float | None = 0.0) -> np.ndarray:
    """[N] bool: the ``mirrors`` among a frame's Gaussians (``means``, ``normals`` [N, 3]) whose reflected
    view ray from ``eye`` meets a box of moving object ``mover`` first (``boxes.mover``): where that
    object is seen in the wet ground."""
    out = np.zeros(len(means), bool)
    idx = np.flatnonzero(mirrors)
    if len(idx) == 0:
        return out
    r = reflected_rays(np.asarray(means)[idx], np.asarray(normals)[idx], eye)
    _, box = mirror_hits(np.asarray(means, np.float64)[idx] + RAY_OFFSET_M * r, r, boxes, spheres, ground_z=ground_z)
    out[idx] = (box >= 0) & (boxes.mover[np.maximum(box, 0)] == mover)
    return out


def mirrored_colors(means: np.ndarray, normals: np.ndarray, eye: np.ndarray, mirrors: np.ndarray,
                    colors: np.ndarray, sky: np.ndarray, boxes: Boxes, spheres: np.ndarray, *,
                    beta: float = 0.0, haze: np.ndarray | None = None, ground_z: float | None = 0.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The sRGB colour each mirror among a frame's Gaussians shows: what its reflected view ray meets.

    Parameters
    ----------
    means, normals : ndarray [N, 3]
        The frame's Gaussians: centres (m) and unit normals.
    eye : ndarray [3]
        The camera's centre (m).
    mirrors : ndarray [N] bool
        The Gaussians that mirror (the wet ground).
    colors : ndarray [N, 3]
        sRGB colour of every Gaussian under the weather, without its own mirror (what a reflected ray
        shows where it meets it: one bounce).
    sky : ndarray [N, 3] or [3]
        sRGB sky each Gaussian's reflected ray sees where it meets nothing (the haze's colour where
        there is haze).
    boxes, spheres, ground_z
        The street's shapes (:func:`mirror_hits`).
    beta : float
        Extinction (1/m) of the weather's haze, >= 0; the reflected path from the mirror to what it
        meets is hazed toward ``haze`` (sRGB [3]) by exp(-beta t), in linear light.

    Returns
    -------
    colors : ndarray [N, 3]
        ``sky`` broadcast, with the mirrors whose ray meets the scene set to the colour there.
    hit : ndarray [N] bool
        The mirrors whose ray met the scene.

    Raises
    ------
    ValueError
        On shapes that disagree, a negative ``beta``, or haze without its colour.
    """
    means = np.asarray(means, np.float64)
    n = len(means)
    if np.shape(normals) != (n, 3) or np.shape(mirrors) != (n,) or np.shape(colors) != (n, 3):
        raise ValueError(f"means, normals [N, 3], mirrors [N] and colors [N, 3] were expected, got {means.shape}, "
                         f"{np.shape(normals)}, {np.shape(mirrors)} and {np.shape(colors)}")
    if not beta >= 0 or (beta > 0 and haze is None):
        raise ValueError(f"beta >= 0 (1/m), with the haze's colour when > 0, was expected; got {beta}, {haze}")
    out = np.array(np.broadcast_to(np.asarray(sky, np.float64), (n, 3)), np.float64)
    hit = np.zeros(n, bool)
    idx = np.flatnonzero(mirrors)
    if len(idx) == 0:
        return out, hit
    r = reflected_rays(means[idx], np.asarray(normals)[idx], eye)
    origins = means[idx] + RAY_OFFSET_M * r
    t, _ = mirror_hits(origins, r, boxes, spheres, ground_z=ground_z)
    met = np.isfinite(t)
    if not met.any():
        return out, hit
    # the scene's colour where the ray meets it: the Gaussians cover every shape's surface
    _, nearest = cKDTree(means).query(origins[met] + r[met] * t[met, None])
    seen = srgb_to_linear(np.clip(np.asarray(colors, np.float64)[nearest], 0.0, 1.0))
    if beta > 0:
        assert haze is not None
        kept = np.exp(-beta * t[met])[:, None]
        seen = seen * kept + srgb_to_linear(np.asarray(haze, np.float64)) * (1.0 - kept)
    out[idx[met]] = linear_to_srgb(seen)
    hit[idx[met]] = True
    return out, hit
