"""Completing a view's distance map where the lidar does not reach.

A street camera sees more than its lidar: the road just in front of the car (below the lidar's
lowest beam) and the upper floors of the facades (above its highest). :func:`complete_distance`
fills those pixels with the two surfaces a street is made of (docs/design.md §7):

* below the horizon, the **ground plane** under the camera (the ray's intersection with it; a
  ray whose meeting with a street rising ahead is not found is a wall as far as the level plane
  under the camera, not an infinitely far one);
* above the horizon, a **vertical wall** continuing the nearest known pixel below in the same
  column (a vertical facade keeps its camera depth along a column when the camera is level). A
  pole, a wire, a mast or a sign in front of a facade is nearer than the facade and thin: the
  camera depth a wall continues is the grey-scale closing (Serra 1982: a running maximum, then a
  running minimum, over a square window, among the known pixels only) of the known pixels', so a
  near thing thinner than the window lends the facade behind it its depth, not its own. The known
  pixels keep their own distance.
* a wall pixel **between two returns of one surface** in its column lies on it (:func:`bridge_rings`:
  a far facade's rows between the lidar's rings), given no facade plane and not smoothed.
* where a **facade plane** is known (:func:`fit_facades`: vertical planes fitted to the scene's
  static returns above a car's height by sequential RANSAC, Fischler & Bolles 1981, each refined
  by least squares), a wall pixel is the ray's intersection with the first facade behind the
  surface it rises from (docs/design.md §7). An oblique facade's upper floors then recede with
  it pixel by pixel, and a sign, a wire or a pole wider than the closing's window lends them
  nothing; where no facade lies behind, the closing's depth stays (the fallback). Completing
  what a range sensor misses with the planar, mostly vertical structure of a built scene is the
  Manhattan-world prior (Coughlan & Yuille 1999) as used for depth completion of urban scans
  (e.g. Furukawa et al. 2009, "Manhattan-world stereo").
* where the lidar's **reach** is given, a wall pixel inside the lidar's field that no return lands
  near, between returns in its row and above one in its column, lies at least as far as the
  lidar reaches (:func:`beyond_reach`: the ray came back empty; a building closing the street
  beyond the returns is not the car in front of it).
* given the frame, the walls' column-by-column guesses are **smoothed along the image**
  (:func:`smooth_walls`): a guided filter of their log distances, so that one surface in the frame
  gets one distance and not a block per column.

The sky stays infinitely far. The WeatherCity build places Gaussians on the completed surfaces
(:func:`~wcbench.reference_model.training.build.completion_cloud`) and the weather editor shades
them (:mod:`wcbench.reference_model.appearance.maps`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from wcbench.reference_model.guided_filter import guided_filter

__all__ = [
    "FILL_GROUND",
    "FILL_KNOWN",
    "FILL_SKY",
    "FILL_WALL",
    "Facades",
    "beyond_reach",
    "bridge_rings",
    "closing_among",
    "complete_distance",
    "fit_facades",
    "ground_height_below",
    "reach_vote",
    "smooth_walls",
]

#: The elevation step (degrees) between a spinning lidar's beams at the top of its field (1 degree
#: on the Hesai Pandar64 that recorded PandaSet): a facade the lidar looked over ends within it
#: above its highest return (:meth:`Facades.first_behind`).
BEAM_DEG = 1.0

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


@dataclass(frozen=True)
class Facades:
    """Vertical facade planes of a scene (world, m): the points x with ``normal . x = offset``
    whose position along ``tangent`` lies in ``extent`` (grown by ``margin_m`` each way), at any
    height.

    Attributes
    ----------
    normal : ndarray [P, 3]
        Unit horizontal normals.
    offset : ndarray [P]
    tangent : ndarray [P, 3]
        Unit horizontal directions along each facade.
    extent : ndarray [P, 2]
        (first, last) position of its returns along ``tangent`` (m).
    top : ndarray [P, B]
        Height (along ``up``, m) of its highest return in each ``bin_m`` bin along it from
        ``extent[:, 0]`` (``-inf`` in a bin without any; past its end, its last bin's).
    up : ndarray [3]
        The scene's unit up vector.
    bin_m : float
    margin_m : float
        A facade reaches this far beyond its outermost returns (its corners are sampled sparsely).
    """

    normal: np.ndarray
    offset: np.ndarray
    tangent: np.ndarray
    extent: np.ndarray
    top: np.ndarray
    up: np.ndarray
    bin_m: float = 1.0
    margin_m: float = 1.0

    @classmethod
    def none(cls, up: np.ndarray) -> Facades:
        """No facade (the closing is the fallback everywhere)."""
        return cls(normal=np.zeros((0, 3)), offset=np.zeros(0), tangent=np.zeros((0, 3)), extent=np.zeros((0, 2)),
                   top=np.zeros((0, 1)), up=np.asarray(up, np.float64))

    def __len__(self) -> int:
        return len(self.offset)

    def first_behind(self, center: np.ndarray, rays: np.ndarray, reach_m: np.ndarray, *,
                     slack: tuple[float, float] = (0.5, 0.05), on_m: tuple[float, float] = (0.3, 0.01),
                     reach_beyond_m: float = 8.0, near_share: float = 0.7, grazing: float = 0.1,
                     ceiling_deg: float | None = None, beam_deg: float = BEAM_DEG) -> np.ndarray:
        """[N] index of the facade a surface seen along unit ``rays`` [N, 3] from ``center`` at
        horizontal distance ``reach_m`` [N] (m) stands on, -1 where none: the nearest facade the
        ray meets, at more than ``grazing`` (cosine) from its plane, within its extent and either
        farther than ``reach_m`` less ``slack`` (metres, share of the distance) but nearer than
        ``reach_m / near_share`` (a surface nearer still is a thing of its own before the facade,
        a street tree whose canopy the closing continues; a sign or an awning hangs close to it),
        or nearer than ``reach_m`` and met at most ``slack`` (share of the facade's distance)
        above its highest return there (a return seen through a facade below its top came
        through a window, or from another sweep; one seen over its top is what stands behind
        it); or, up to ``reach_beyond_m`` past its extent (its returns there may stay under the
        fit's height), one the surface lies on (within ``on_m``).

        A facade's highest return is its top only where the lidar looked over it: given the
        field's top ``ceiling_deg`` (degrees above the horizontal from ``center``), a facade whose
        highest return there lies more than ``beam_deg`` under it (the lidar's next beam up passed
        over it) ends at most a beam's step above that return, and a ray passes over it once it
        passes ``slack`` metres plus that step over the return; elsewhere (the field cut the
        facade, or no ceiling given) the share of ``slack`` stands for its unseen floors. A far
        return seen a metre over a sign 30 m away, taken through the sign, put the wall above it
        on the sign: haze in blocks over a warehouse (pandaset_002_back, docs/findings.md)."""
        c = np.asarray(center, np.float64)
        r = np.asarray(rays, np.float64)
        reach = np.asarray(reach_m, np.float64)[:, None]
        d = r - np.outer(r @ self.up, self.up)
        flat = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        cos = (d @ self.normal.T) / flat[:, None]  # [N, P] of the horizontal direction
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset - self.normal @ c)[None, :] / cos  # horizontal distance
        along = (self.tangent @ c)[None, :] + t * ((d @ self.tangent.T) / flat[:, None])
        facing = (np.abs(cos) > grazing) & (t > 0)
        inside = (along >= self.extent[:, 0] - self.margin_m) & (along <= self.extent[:, 1] + self.margin_m)
        near = (along >= self.extent[:, 0] - reach_beyond_m) & (along <= self.extent[:, 1] + reach_beyond_m)
        tol = slack[0] + slack[1] * np.where(np.isfinite(reach), reach, 0.0)
        behind = (t > reach - tol) & (reach >= near_share * t)
        height = c @ self.up + t * ((r @ self.up) / flat)[:, None]
        b = np.clip(np.nan_to_num((along - self.extent[:, 0]) / self.bin_m), 0, self.top.shape[1] - 1)
        top = self.top[np.arange(len(self))[None, :], b.astype(np.int64)]  # in the margins: the end's
        on = np.abs(t - reach) <= on_m[0] + on_m[1] * np.where(np.isfinite(reach), reach, 0.0)
        over_by = slack[1] * t  # the facade's unseen floors: an angular slack
        if ceiling_deg is not None:
            rise = top - c @ self.up
            seen_over = np.arctan2(rise, np.where(np.isfinite(t), t, 1.0)) < np.radians(ceiling_deg - beam_deg)
            over_by = np.where(seen_over, t * np.tan(np.radians(beam_deg)), over_by)
        over = height > top + slack[0] + over_by  # the ray passes over the facade
        through = ~over & (reach > t)  # the surface lies behind the facade, below its top
        # past its extent a facade is not looked through: rays past a short facade's end toward the
        # far end of a street would take it
        ok = facing & ((inside & (behind | through)) | (near & on))
        t = np.where(ok, t, np.inf)
        best = np.argmin(t, axis=1)
        return np.where(np.isfinite(t[np.arange(len(r)), best]), best, -1)

    def distance(self, index: np.ndarray, center: np.ndarray, rays: np.ndarray) -> np.ndarray:
        """[N] distance (m) along unit ``rays`` [N, 3] from ``center`` to facade ``index`` [N]
        (``inf`` where the ray runs parallel to it or away from it)."""
        n = self.normal[index]
        cos = np.einsum("ij,ij->i", np.asarray(rays, np.float64), n)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset[index] - n @ np.asarray(center, np.float64)) / cos
        return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def fit_facades(points: np.ndarray, normals: np.ndarray, heights: np.ndarray, up: np.ndarray, *,
                min_height_m: float = 2.5, max_tilt: float = 0.35, cell_m: float = 0.2,
                tolerance_m: float = 0.3, min_points: int = 300, min_length_m: float = 3.0,
                max_gap_m: float = 4.0, max_planes: int = 40, hypotheses: int = 256, bin_m: float = 1.0,
                seed: int = 0) -> Facades:
    """Vertical facade planes through a scene's static returns by sequential RANSAC (Fischler &
    Bolles 1981) on their footprint.

    The returns higher than ``min_height_m`` above the ground whose normal is within ``max_tilt``
    (|normal . up|) of horizontal are binned into ``cell_m`` cells of the ground plane (a cell
    weighs its returns: a wall stacks many). Each round draws ``hypotheses`` lines through two
    cells, keeps the one with the most returns within ``tolerance_m``, refines it twice by weighted
    least squares (the footprint's principal axis), splits its inliers where they leave a gap over
    ``max_gap_m`` and keeps each run of ``min_points`` returns over ``min_length_m``; its inliers
    leave the pool. Stops after ``max_planes`` rounds or when fewer than ``min_points`` returns
    remain in the best line. Each facade keeps its highest return per ``bin_m`` along it (the
    largest of a bin and its two neighbours).

    Parameters
    ----------
    points : ndarray [N, 3]
        Static returns (world, m).
    normals : ndarray [N, 3]
        Their unit normals.
    heights : ndarray [N]
        Their height above the ground below them (m).
    up : ndarray [3]
        Unit up vector.

    Returns
    -------
    Facades

    Raises
    ------
    ValueError
        On arrays whose shapes disagree.
    """
    p = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    hgt = np.asarray(heights, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or nrm.shape != p.shape or hgt.shape != (len(p),):
        raise ValueError(f"points [N, 3], normals [N, 3] and heights [N] were expected, got {p.shape}, "
                         f"{nrm.shape} and {hgt.shape}")
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    axes = np.stack([e1, e2])
    keep = (hgt > min_height_m) & (np.abs(nrm @ u) < max_tilt)
    xy = p[keep] @ axes.T
    out: list[tuple[np.ndarray, float, np.ndarray, float, float, np.ndarray]] = []
    if len(xy) >= 2:
        keys, inverse, weight = np.unique(np.floor(xy / cell_m).astype(np.int64), axis=0, return_inverse=True,
                                          return_counts=True)
        inverse = inverse.reshape(-1)
        cells = np.zeros((len(keys), 2))
        np.add.at(cells, inverse, xy)
        cells /= weight[:, None]  # each cell at the mean of its returns
        cell_top = np.full(len(keys), -np.inf)
        np.maximum.at(cell_top, inverse, p[keep] @ u)
        w = weight.astype(np.float64)
        alive = np.ones(len(cells), bool)
        rng = np.random.default_rng(seed)
        for _ in range(max_planes):
            idx = np.flatnonzero(alive)
            if len(idx) < 2 or w[idx].sum() < min_points:
                break
            pts, ww = cells[idx], w[idx]
            a = rng.choice(len(idx), size=hypotheses, p=ww / ww.sum())
            b = rng.choice(len(idx), size=hypotheses, p=ww / ww.sum())
            step = pts[b] - pts[a]
            length = np.linalg.norm(step, axis=1)
            normal2 = np.stack([-step[:, 1], step[:, 0]], 1) / np.maximum(length, 1e-9)[:, None]
            offset2 = np.einsum("ij,ij->i", normal2, pts[a])
            score = ww @ (np.abs(pts @ normal2.T - offset2) < tolerance_m)
            score[length < 2 * cell_m] = 0.0
            best = int(np.argmax(score))
            n2, o2 = normal2[best], float(offset2[best])
            inl = np.abs(pts @ n2 - o2) < tolerance_m
            for _ in range(2):  # weighted least squares: the principal axis of the inliers' footprint
                mu = np.average(pts[inl], axis=0, weights=ww[inl])
                q = pts[inl] - mu
                n2 = np.linalg.eigh((q * ww[inl, None]).T @ q)[1][:, 0]
                o2 = float(n2 @ mu)
                inl = np.abs(pts @ n2 - o2) < tolerance_m
            if ww[inl].sum() < min_points:
                break
            t2 = np.array([-n2[1], n2[0]])
            s = pts[inl] @ t2
            order = np.argsort(s)
            s, sw, st = s[order], ww[inl][order], cell_top[idx[inl]][order]
            cuts = np.flatnonzero(np.diff(s) > max_gap_m) + 1
            for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(s)]):
                if sw[lo:hi].sum() >= min_points and s[hi - 1] - s[lo] >= min_length_m:
                    bins = np.full(int((s[hi - 1] - s[lo]) // bin_m) + 1, -np.inf)
                    np.maximum.at(bins, ((s[lo:hi] - s[lo]) // bin_m).astype(np.int64), st[lo:hi])
                    bins = np.max(np.stack([bins, np.r_[-np.inf, bins[:-1]], np.r_[bins[1:], -np.inf]]), axis=0)
                    out.append((n2 @ axes, o2, t2 @ axes, float(s[lo]), float(s[hi - 1]), bins))
            alive[idx[inl]] = False
    if not out:
        return Facades.none(u)
    top = np.full((len(out), max(len(o[5]) for o in out)), -np.inf)
    for i, o in enumerate(out):
        top[i, :len(o[5])] = o[5]
        top[i, len(o[5]):] = o[5][-1]
    return Facades(normal=np.stack([o[0] for o in out]), offset=np.array([o[1] for o in out]),
                   tangent=np.stack([o[2] for o in out]), extent=np.array([[o[3], o[4]] for o in out]), top=top,
                   up=u, bin_m=bin_m)


def complete_distance(distance: np.ndarray, known: np.ndarray, sky: np.ndarray, rays: np.ndarray,
                      center: np.ndarray, up: np.ndarray, ground_height: float, *, forward: np.ndarray,
                      ground_at: Callable[[np.ndarray], np.ndarray] | None = None,
                      thin_fraction: float = 1.0 / 40.0, facades: Facades | None = None,
                      facade_slack: tuple[float, float] = (0.5, 0.05), guide: np.ndarray | None = None,
                      guide_radius: float = 12.0 / 270.0, guide_eps: float = 1e-3,
                      hits: np.ndarray | None = None, reach: tuple[float, tuple[float, float]] | None = None,
                      ring_gap: float = 12.0 / 270.0, ring_agree: float = 0.05,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    facades : Facades, optional
        The scene's facade planes (:func:`fit_facades`): a wall pixel rising from a lidar return
        meets the facade that return stands on (:meth:`Facades.first_behind`); the closing's
        depth where none is, and above the completed ground.
    facade_slack : (float, float)
        (metres, share of the distance): how much nearer than the pixel it rises from a facade may
        lie, or how far below that pixel's ray its top, and still be the one it stands on (the
        returns' noise, the plane's fit and the projection's error).
    guide : ndarray [H, W, 3] float32, optional
        The frame (display RGB in [0, 1]): when given, the walls' distances are smoothed along it
        (:func:`smooth_walls`).
    guide_radius : float
        The smoothing's window radius as a share of the height (12 px at 270 rows).
    guide_eps : float
        The guided filter's regularisation (edges weaker than its square root are smoothed over).
    ring_gap, ring_agree : float
        :func:`bridge_rings`' most rows between two returns (a share of the height; 0 bridges
        nothing) and their depths' largest difference (a share of the nearer).
    hits : ndarray [H, W] bool, optional
        Pixels a lidar return lands in (the editor passes the analysis' solid masks); with
        ``reach``, the evidence of :func:`beyond_reach`, applied to the walls before they are
        smoothed.
    reach : (float, (float, float)), optional
        The lidar's reach (m) and elevation band (degrees above the horizontal), as
        :class:`~wcbench.reference_model.scene_analysis.reach.LidarReach` reads them. The band's top
        also says which facades the lidar looked over (:meth:`Facades.first_behind`'s ceiling).

    Returns
    -------
    distance : ndarray [H, W] float64
        Completed; ``inf`` on the sky, and on an unknown pixel with nothing at a finite distance
        below it in its column (a ray below the horizon that misses the ground, as a street rising
        ahead makes it, is a wall too).
    kind : ndarray [H, W] int8
        :data:`FILL_KNOWN`, :data:`FILL_GROUND`, :data:`FILL_WALL` or :data:`FILL_SKY`.
    source : ndarray [H, W] int64
        For a wall pixel, the row it continues in its column; -1 elsewhere (and on a wall pixel
        below the horizon, which continues nothing).
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
        # a ray just below the horizon whose meeting with a rising ground the steps do not find
        # meets what stands far down the street: a wall as far as the level plane under the camera
        # (walls above rise from it), not an infinitely far sky nor a thing nearer below it
        met = np.isfinite(t) & (t > 0)
        level = (ground_height - c @ up) / ray_up[ground]
        out[ground] = np.where(met, t, np.where(level > 0, level, np.inf))
        kind[ground] = np.where(met, FILL_GROUND, FILL_WALL)
    source = np.full((h, w), -1, np.int64)
    fixed = np.zeros((h, w), bool)
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
        raw_depth = camera_depth
        half = round(w * thin_fraction)
        if half > 0:
            camera_depth = closing_among(camera_depth, drawn & np.isfinite(camera_depth), half)
        depth_src = camera_depth[src_c, cc]
        value = np.where(has & np.isfinite(depth_src), depth_src / np.maximum(cos_dst, 1e-6), np.inf)
        # only a lidar return stands on a facade: the completed ground (and the far wall below the
        # horizon) is a guess whose distance, far down the street, would pick any facade before it
        measured = has & known[src_c, cc] & ~sky[src_c, cc]
        # a wall pixel between two returns of one surface in its column lies on that surface (the
        # rows a spinning lidar's rings leave between them on a far facade): their camera depths
        # interpolated, before any facade or smoothing is consulted
        gap = round(ring_gap * h)
        between = (bridge_rings(np.where(known & ~sky, raw_depth, np.inf), sky, rr, cc, max_gap=gap,
                                agree=ring_agree) if gap > 0 else np.full(len(rr), np.inf))
        bridged = np.isfinite(between)
        if facades is not None and len(facades) and np.any(measured & ~bridged):
            value = _on_facades(value, facades, np.asarray(center, np.float64), unit, out, rr, cc, src,
                                measured & ~bridged, facade_slack, None if reach is None else float(reach[1][1]))
        value = np.where(bridged, between / np.maximum(cos_dst, 1e-6), value)
        fixed[rr[bridged], cc[bridged]] = True
        out[rr, cc] = value
        kind[rr, cc] = np.where(np.isfinite(value), FILL_WALL, FILL_SKY)
        source[rr, cc] = np.where(np.isfinite(value), src, -1)
    if hits is not None and reach is not None:
        out = beyond_reach(out, kind, hits, rays, up, range_m=reach[0], elevation_deg=reach[1], guide=guide)
    if guide is not None:
        out = smooth_walls(out, kind, guide, radius=max(1, round(guide_radius * h)), eps=guide_eps, keep=fixed)
    return out, kind, source


#: How near (a share of the image width: 3 px at 480) a return may land and still leave a wall
#: pixel to :func:`beyond_reach` (a return's pixel is where its beam's footprint centre falls).
REACH_CLEARANCE = 3.0 / 480.0
#: The frame-guided vote of :func:`beyond_reach`: window radius (a share of the height), the
#: guided filter's regularisation, and the share of candidates a pixel's surroundings must hold.
REACH_GUIDE_RADIUS, REACH_GUIDE_EPS, REACH_SHARE = 20.0 / 270.0, 1e-3, 0.8


def beyond_reach(distance: np.ndarray, kind: np.ndarray, hits: np.ndarray, rays: np.ndarray, up: np.ndarray, *,
                 range_m: float, elevation_deg: tuple[float, float],
                 clearance: float = REACH_CLEARANCE, guide: np.ndarray | None = None,
                 guide_radius: float = REACH_GUIDE_RADIUS) -> np.ndarray:
    """[H, W] ``distance`` with each wall pixel the lidar would have seen, had anything stood nearer
    than its reach, put at least as far as that reach (see the module docstring).

    A wall pixel (``kind`` :data:`FILL_WALL`) is such a pixel when its ray's elevation lies inside
    the lidar's band, no return lands within ``clearance`` of it, and returns land on both sides
    of it in its row and below it in its column (the lidar swept across it: outside its azimuth
    there are none on one side). A window or dark paint that returns nothing inside a surface that
    does is within the clearance of that surface's returns only when it is a few pixels wide; the
    band and the row's returns leave out what lies above the highest beam or beside the sweep.

    Parameters
    ----------
    distance : ndarray [H, W] float64
        Completed distances (m).
    kind : ndarray [H, W] int8
        :data:`FILL_KNOWN`, :data:`FILL_GROUND`, :data:`FILL_WALL` or :data:`FILL_SKY` per pixel.
    hits : ndarray [H, W] bool
        Pixels a lidar return lands in (the editor passes the analysis' solid masks: the returns of
        every sweep it trusts in this frame).
    rays : ndarray [H, W, 3]
        Unit world ray of each pixel.
    up : ndarray [3]
        Unit up vector.
    range_m : float
        The lidar's reach (m), > 0.
    elevation_deg : (float, float)
        Its field's lowest and highest elevation above the horizontal (degrees).
    clearance : float
        How near a return may land (a share of the width; at least 1 px).
    guide : ndarray [H, W, 3] float, optional
        The frame (display RGB in [0, 1]). Given, the verdict is put to the frame's vote
        (:func:`reach_vote`): a candidate stands only where the guided filter of the candidates is
        at least :data:`REACH_SHARE` of that of candidates and returns together (the top floors of
        a facade between a spinning lidar's sparse upper beams, whose lower floors returned, stay).
    guide_radius : float
        The vote's window radius, a share of the height (20 px at 270 rows).

    Returns
    -------
    ndarray [H, W] float64

    Raises
    ------
    ValueError
        If the shapes disagree, ``range_m`` is not > 0 or the band is empty.
    """
    h, w = kind.shape
    lo, hi = float(elevation_deg[0]), float(elevation_deg[1])
    if distance.shape != (h, w) or hits.shape != (h, w) or np.shape(rays) != (h, w, 3):
        raise ValueError(f"distance, kind and hits [H, W] and rays [H, W, 3] were expected, got {distance.shape}, "
                         f"{kind.shape}, {hits.shape} and {np.shape(rays)}")
    if not (np.isfinite(range_m) and range_m > 0 and lo < hi):
        raise ValueError(f"range_m > 0 and a band low < high were expected, got {range_m} and {elevation_deg}")
    hits = np.asarray(hits, bool)
    out = np.array(distance, np.float64, copy=True)
    empty = (kind == FILL_WALL) & (out < range_m)
    rr, cc = np.nonzero(empty)
    if not len(rr):
        return out
    # the elevation of the few walls short of the reach, not of every ray
    sine = np.asarray(rays, np.float64)[rr, cc] @ np.asarray(up, np.float64)
    inside = (sine > np.sin(np.radians(lo))) & (sine < np.sin(np.radians(hi)))
    r = max(1, round(clearance * w))
    near = cv2.dilate(hits.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
    left = np.maximum.accumulate(hits, axis=1)
    right = np.maximum.accumulate(hits[:, ::-1], axis=1)[:, ::-1]
    below = np.maximum.accumulate(hits[::-1], axis=0)[::-1]
    keep = inside & ~near[rr, cc] & left[rr, cc] & right[rr, cc] & below[rr, cc]
    empty[rr[~keep], cc[~keep]] = False
    if guide is not None and np.any(empty):
        empty &= reach_vote(empty, hits, guide, radius=max(1, round(guide_radius * h)))
    out[empty] = range_m
    return out


def reach_vote(candidates: np.ndarray, hits: np.ndarray, guide: np.ndarray, *, radius: int,
               crop: bool = True) -> np.ndarray:
    """[H, W] bool: where the frame-guided filter of ``candidates`` is at least
    :data:`REACH_SHARE` of that of ``candidates`` and ``hits`` together (:func:`beyond_reach`'s
    vote: one surface in the frame, one verdict); read it at the candidates.

    The filter's output at a pixel reads the frame within twice the window radius of it, so with
    ``crop`` it runs on the candidates' bounding box grown by that much (a wall short of the reach
    is a band about the horizon, not the frame; half the time on `pandaset_002`): at every
    candidate the same verdict as the whole frame's (``crop=False``, its twin in the tests);
    elsewhere in the box the filter meets the box's edge, and outside it the answer is False.

    Parameters
    ----------
    candidates, hits : ndarray [H, W] bool
    guide : ndarray [H, W, 3] float
        The frame, display RGB in [0, 1].
    radius : int
        The window radius (px), >= 1.
    crop : bool
        Filter the candidates' surroundings only.

    Returns
    -------
    ndarray [H, W] bool
    """
    h, w = candidates.shape
    y0, y1, x0, x1 = 0, h, 0, w
    if crop and np.any(candidates):
        ys, xs = np.nonzero(candidates.any(axis=1))[0], np.nonzero(candidates.any(axis=0))[0]
        m = 2 * radius + 1
        y0, y1 = max(0, int(ys[0]) - m), min(h, int(ys[-1]) + 1 + m)
        x0, x1 = max(0, int(xs[0]) - m), min(w, int(xs[-1]) + 1 + m)
    window = (slice(y0, y1), slice(x0, x1))
    src = np.stack([candidates[window], hits[window]], -1).astype(np.float32)
    votes = guided_filter(np.asarray(guide)[window], src, radius=radius, eps=REACH_GUIDE_EPS)
    ev, hv = np.maximum(votes[..., 0], 0.0), np.maximum(votes[..., 1], 0.0)
    out = np.zeros((h, w), bool)
    out[window] = ev > REACH_SHARE * (ev + hv)
    return out


#: How much nearer than the closing of the distances around it (a share) a return must be to
#: stand before the surface rather than on it (:func:`smooth_walls`).
OCCLUDER_SHARE = 0.05


def smooth_walls(distance: np.ndarray, kind: np.ndarray, guide: np.ndarray, *, radius: int,
                 eps: float = 1e-3, keep: np.ndarray | None = None) -> np.ndarray:
    """[H, W] ``distance`` with each wall pixel's replaced by the frame-guided mean of the log
    distances of the drawn pixels around it.

    A wall's distance is a guess made column by column (the surface below it continued, or the
    facade that surface stands on), and it jumps wherever the surface below changes: over a lower
    roof, a sign or a few far returns, a dark facade band above them came out as alternating near
    and far columns, blocks of haze in fog (docs/findings.md). The frame shows one surface there.
    Each wall pixel takes the normalised guided filter
    (:func:`~wcbench.reference_model.guided_filter.guided_filter`; normalised convolution,
    Knutsson & Westin 1993) of the log distances of the pixels with a finite distance (returns,
    ground, walls), the frame as guide, clamped to their range in the window: the guesses are
    averaged within what the frame shows as one region and not across its edges. A return more
    than :data:`OCCLUDER_SHARE` nearer than the grey-scale closing of those distances over the
    window (a thing thinner than the window before the surface) is left out. Lidar returns
    and the ground keep their own distance (smoothing them as well lowered the editor's PSNR
    against the synthetic truth).

    Parameters
    ----------
    distance : ndarray [H, W] float64
        Completed distances (m; ``inf`` on the sky).
    kind : ndarray [H, W] int8
        :data:`FILL_KNOWN`, :data:`FILL_GROUND`, :data:`FILL_WALL` or :data:`FILL_SKY` per pixel.
    guide : ndarray [H, W, 3] float
        The frame, display RGB in [0, 1].
    radius : int
        Window radius (px), >= 1.
    eps : float
        Regularisation of the guided filter.
    keep : ndarray [H, W] bool, optional
        Wall pixels whose distance is not a guess (:func:`bridge_rings`): they count in the
        means around them and keep their own.

    Returns
    -------
    ndarray [H, W] float64

    Raises
    ------
    ValueError
        If the shapes disagree or ``radius`` < 1.
    """
    h, w = kind.shape
    if distance.shape != (h, w) or np.shape(guide)[:2] != (h, w) or radius < 1 or \
            (keep is not None and np.shape(keep) != (h, w)):
        raise ValueError(f"distance, kind and keep [H, W], guide [H, W, 3] and radius >= 1 were expected, got "
                         f"{distance.shape}, {kind.shape}, {None if keep is None else np.shape(keep)}, "
                         f"{np.shape(guide)} and {radius}")
    wall = kind == FILL_WALL
    drawn = np.isfinite(distance) & (kind != FILL_SKY)
    if not np.any(wall & drawn):
        return distance
    log_d = np.where(drawn, np.log(np.where(drawn, np.maximum(distance, 1e-3), 1.0)), 0.0).astype(np.float32)
    # a return nearer than the closing of the drawn distances over the window (a thing thinner
    # than the window: a pole, a sign before a facade, as complete_distance's closing reads one)
    # is not the surface the walls around it belong to, however alike their colours: it lends
    # them nothing (a dark pole pulled a dark facade 50 m away to 21 m, docs/findings.md)
    closed = closing_among(log_d.astype(np.float64), drawn, radius)
    lends = drawn & ((kind == FILL_WALL) | (log_d >= closed + np.log1p(-OCCLUDER_SHARE)))
    weight = lends.astype(np.float32)
    sums = guided_filter(guide, np.stack([log_d * weight, weight], -1), radius=radius, eps=eps)
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    big = np.float32(1e30)
    low = cv2.erode(np.where(lends, log_d, big), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float(big))
    high = cv2.dilate(np.where(lends, log_d, -big), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float(-big))
    # a weight this low is a window mostly of sky, whose edge the filter's local model crosses
    ok = wall & drawn & (sums[..., 1] > 0.2)
    if keep is not None:
        ok &= ~np.asarray(keep, bool)
    mean = np.clip(sums[..., 0][ok] / sums[..., 1][ok], low[ok], high[ok])
    out = np.array(distance, np.float64, copy=True)
    out[ok] = np.exp(mean.astype(np.float64))
    return out


def bridge_rings(depth: np.ndarray, sky: np.ndarray, rr: np.ndarray, cc: np.ndarray, *, max_gap: int,
                 agree: float) -> np.ndarray:
    """[N] camera depth (m) of pixels (``rr``, ``cc``) that lie between two returns of one surface in
    their column; ``inf`` for the others.

    Returns above and below it in its column, at most ``max_gap`` rows apart, no sky between, camera
    depths within ``agree`` of the nearer (a far facade between a spinning lidar's rings); it takes
    their inverse depths interpolated in the row (a plane's inverse depth is affine in the image).

    Parameters
    ----------
    depth : ndarray [H, W] float64
        Camera depth (m) of the returns; ``inf`` elsewhere.
    sky : ndarray [H, W] bool
        Sky pixels (nothing is bridged across them).
    rr, cc : ndarray [N] int
        The pixels asked about (rows, columns).
    max_gap : int
        The most rows between the two returns (px).
    agree : float
        Their depths' largest difference, a share of the nearer.

    Returns
    -------
    ndarray [N] float64
    """
    h = depth.shape[0]
    event = np.isfinite(depth) | np.asarray(sky, bool)
    idx = np.arange(h)[:, None]
    above = np.maximum.accumulate(np.where(event, idx, -1), axis=0)[rr, cc]
    below = np.minimum.accumulate(np.where(event, idx, h)[::-1], axis=0)[::-1][rr, cc]
    ok = (above >= 0) & (below < h) & (below - above - 1 <= max_gap)
    za = np.where(ok, depth[np.clip(above, 0, h - 1), cc], np.inf)
    zb = np.where(ok, depth[np.clip(below, 0, h - 1), cc], np.inf)
    ok &= np.isfinite(za) & np.isfinite(zb) & (za > 0) & (zb > 0)  # a sky pixel is no return
    with np.errstate(divide="ignore", invalid="ignore"):
        ok &= np.abs(za - zb) <= agree * np.minimum(za, zb)
        t = (rr - above) / np.maximum(below - above, 1)
        return np.where(ok, 1.0 / ((1.0 - t) / za + t / zb), np.inf)


def _on_facades(value: np.ndarray, facades: Facades, center: np.ndarray, unit: np.ndarray, out: np.ndarray,
                rr: np.ndarray, cc: np.ndarray, src: np.ndarray, has: np.ndarray,
                slack: tuple[float, float], ceiling_deg: float | None = None) -> np.ndarray:
    """``value`` [N] (the wall pixels' distances by the closing) where the wall pixel (``rr``,
    ``cc``) meets a facade behind its source pixel (row ``src`` of its column): the ray's distance
    to it. The facade is chosen once per source pixel (its ray's horizontal direction)."""
    width = unit.shape[1]
    keys, back = np.unique(src[has] * width + cc[has], return_inverse=True)
    back = back.reshape(-1)
    pairs = np.stack([keys // width, keys % width], 1)
    src_ray = unit[pairs[:, 0], pairs[:, 1]]
    horizontal = np.linalg.norm(src_ray - np.outer(src_ray @ facades.up, facades.up), axis=1)
    with np.errstate(invalid="ignore"):
        reach = out[pairs[:, 0], pairs[:, 1]] * horizontal  # the source's horizontal distance
    chosen = facades.first_behind(center, src_ray, reach, slack=slack, ceiling_deg=ceiling_deg)[back]
    on = np.flatnonzero(has)[chosen >= 0]
    result = value.copy()
    hit = facades.distance(chosen[chosen >= 0], center, unit[rr[on], cc[on]])
    result[on] = np.where(np.isfinite(hit), hit, value[on])
    return result


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
