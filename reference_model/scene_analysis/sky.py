"""Sky segmentation of a scene's frames: from the image, checked by the lidar.

A pixel whose ray meets a lidar return (of any sweep, for the static scene) is never sky. The
rest cannot be decided from the lidar alone: facades rise above its vertical field of view, wires
and poles are hit now and then, and far buildings lie beyond its range. :func:`segment_sky` decides
them from the image, for every frame of a scene at once (docs/design.md §7, "Sky"):

1. **Seeds.** Confident sky: above the horizon, no return within 4 px, connected to the top of the
   image through such pixels without crossing a step edge (a roof line), in a patch of seeds of
   at least 0.3 % of the frame (a window pane mirroring the sky is smaller), not on the
   continuation of a wall above its topmost return (up to the highest step edge within 5 degrees
   above it: a spinning lidar's upper beams are 2-5 degrees apart, and between two of them a wall
   returns nothing either), smooth (local standard
   deviation of L*, wires closed away, under 0.03), static under the camera's rotation alone (see 2), and either
   within the lidar's coverage (ray elevation under 12 degrees: there the lidar would have
   returned anything within its range) or of the clear sky's blue (b* < -12, -20 < a* < 5:
   Rayleigh scattering). Confident non-sky: every return's pixel above the horizon.
2. **Features** per pixel: CIELAB colour, the local standard deviation of L* over 5 x 5 and 15 x 15
   px and its gradient (taken after closing away dark lines up to 4 px wide: wires do not make the
   sky between them rough, and its smoothness holds seeds there too), the ray's elevation, and
   the *infinity residual*: the smaller of the mean absolute differences to frames k - 2 and
   k + 2 warped by the homography of the rotation alone, K R_j^T R_k K^-1. The sky lies at
   infinity, so it aligns under that warp (residual ~0); a textured surface at finite distance
   moves with the translation and does not (a window band at the top of the frame, a pole, a
   wire).
3. **Evidence**, three independent estimates of the probability of sky, averaged in log-odds: a
   per-scene classifier (random forest, OpenCV's ``ml.RTrees``, 20 trees of depth 12, trained on up
   to 15,000 seeds of each class from every frame); the frame's own colours (Gaussian mixtures of
   its sky and non-sky seeds, GrabCut's colour model); the column's colours (a pixel against the
   nearest sky seed above it and the nearest return below it: a wall rising unseen above its last
   return has the wall's colour, not that of the sky over its roof line).
4. **Per frame, a minimum cut** (Boykov & Jolly 2001, "Interactive graph cuts", ICCV; PyMaxflow)
   with that probability as unary term, contrast-sensitive 4-neighbour smoothness
   4 exp(-beta |dLab|^2) (beta from the frame's mean squared neighbour difference, as in GrabCut),
   and hard constraints: returns and the pixels below the horizon are not sky, sky seeds are. A
   return of a structure a few px wide (:func:`thin_returns`) with the colour of the sky seeds
   nearby (a wire's mixed pixel, another sweep's copy of it a px off) joins no neighbour by the
   smoothness term: it stays non-sky, but does not pull a pocket of sky beside it to the wall.
   After the cut, pixels of the clear sky's blue and of the colour of the sky nearby (CIELAB
   difference under 10), joined to the cut's sky through such pixels, with no return of any sweep in
   them, are sky too (:func:`_blue_pockets`: a narrow pocket between wires and a wall's corner,
   where the evidence is weak, goes to the structures around it otherwise).
5. **The boundary placed by colour** (:func:`refine_boundary`): within 3 px of it, each pixel's
   share of sky from the colour line between the nearby sky and foreground colours (alpha
   matting's colour-line model), or, for a pixel far off that line (a third colour: a pale
   building top between a dark roof and a blue sky), from the line of the nearby surface colour
   that explains it best (sampling-based matting's chromatic distortion); sky where the share is
   at least one half. A patch of sky that holds no seed and does not reach the top of the frame
   (a pane of a window, a gap the cut left in a wall) is dropped: the sky is one with the open
   sky. Patches apart by 2 px or less (at 480 wide: a lamp's arm, a pole's crossbar, a bundle of
   wires) count as one, so the sky under an arm stays sky.
6. **Thin occluders** (:func:`thin_occluders`): the returns of a structure a few px wide in front of
   the sky (a wire, a signal's mast arm, a pole's top: the hit set minus its morphological opening
   by a 7 x 7 px square, with smooth, return-free pixels of the nearby seeds' colour 2-4 px past it
   on both sides along a row, a column or a diagonal) cut the hazy sky under them off from the open
   sky and from the seeds, and their mixed pixels teach the classifiers that pale sky beside a
   structure is not sky. Found after a first pass of seeds, they are crossed on the way to the top
   (the seeds of a second pass need only clear them by 1 px; the way across is the occluder, its
   mixed pixels and those pixels within 4 px of it that have the colour of the sky seeds nearby, so
   a wire crossing a roof line does not lead into the wall below), join the patches they separate in
   step 5, and are left out of the non-sky training. They stay non-sky, and so does every pixel
   within 4 px of them that any sweep's return lands in (``untrusted``: other sweeps register a pole
   or a wire a few px off, and the sky found across it keeps clear of every copy).

7. **Support over time** (:func:`neighbour_support`): a patch of sky is kept only where one of
   frames k -/+ 1, 2, warped by the rotation between them, calls at least half of it sky (the best
   neighbour: a near roof edge's parallax hides part of a side camera's sky from the frames on one
   side). A facade between the lidar's upper scan lines can hold seeds in one frame; its
   neighbours call it wall.

A frame no lidar return lands in gets no seeds of its own (nothing in it is confirmed empty): its
sky is the scene's classifier's, cut with the frame's contrast, and only where it reaches the top
of the frame; a scene with no seed in any frame has no sky (``facts["fallback"]``).

The result is a binary mask per frame and the sky's share of each pixel (a soft matte:
:func:`sky_matte` feathers a mask at another size), so that a wire or a branch against the sky is
a mixed pixel, not a band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import maxflow
import numpy as np

from wcbench.reference_model.scene_analysis.views import AnalysisViews

__all__ = ["SkySegmentation", "infinity_residual", "neighbour_support", "refine_boundary", "rotation_homography",
           "segment_sky", "sky_features", "sky_matte", "thin_occluders", "thin_returns"]

#: Trees and depth of the per-scene classifier; seeds drawn per class at most.
_TREES, _DEPTH, _MAX_SEEDS = 20, 12, 15000
#: Seeds: no lidar return within this radius (px at 480 wide), smoothness and rotation-residual
#: thresholds, lidar coverage (degrees of elevation) and the clear sky's blue (CIELAB).
_SEED_CLEARANCE_PX, _SEED_MAX_STD, _SEED_MAX_RESIDUAL = 4, 0.03, 0.03
_SEED_MAX_ELEVATION_DEG = 12.0
#: Angular gap between a spinning lidar's upper beams (degrees): how far a wall may rise unseen
#: above its topmost return (Hesai Pandar64's beams above +5 degrees are 2-4 apart; on
#: pandaset_002_back a warehouse's roof line lies 4-5 degrees above its last return).
_BEAM_GAP_DEG = 5.0
#: Half the width (px) of a run of returns that makes a wall (rather than a pole or a mast), and
#: the CIELAB step (3 rows above against 3 below) that ends a wall's continuation.
_WALL_RUN_PX, _EDGE_DE = 6, 12.0
_BLUE_B, _BLUE_A = -12.0, (-20.0, 5.0)
#: A patch of seeds smaller than this share of the frame is dropped (a window pane mirroring the blue
#: sky is smaller).
_MIN_OPEN_SKY = 0.003
#: Thin occluders: returns of a structure at most ``2 * _THIN_PX`` px wide (at 480 wide: a wire, a
#: signal's mast arm with the heads that hang from it, a pole's top), looked past ``_THIN_GAP_PX`` px
#: on either side for the sky's colour nearby (CIELAB difference under ``_THIN_DE``). 2 px left the
#: haze under pandaset_002's far signal arm (5-9 rows of returns) walled off from every seed
#: (docs/findings.md, "The sky under a signal's arm").
_THIN_PX, _THIN_GAP_PX, _THIN_DE = 3, (2, 3, 4), 10.0
#: How far (px, a Gaussian's sigma) the seeds give the sky's colour around a thin occluder.
_THIN_REACH_PX = 12.0
#: A patch of sky is kept when the neighbouring frames call at least this share of it sky (warped by
#: the rotation between them).
_MIN_SUPPORT = 0.5
#: Dark lines at most twice this wide (px at 480 wide: overhead wires) are closed away before the
#: texture features are taken: on pandaset_002_front_right the strip of sky between the lowest wire
#: and a roof line was rough over 5 x 5 px everywhere, held no seed and went to the roof
#: (docs/findings.md, "Sky between wires").
_LINE_PX = 2
#: The boundary's third colour (:func:`refine_boundary`): a pixel off the line of the farthest
#: foreground colour and the sky by more than this chromatic distortion (CIELAB) takes its share from
#: the line of a nearby surface colour at least ``_SURFACE_DE`` from the sky's, if that explains it
#: better.
_MAX_DISTORTION, _SURFACE_DE = 6.0, 16.0
#: Smoothness weight of the minimum cut, and the clip of the classifier's probability.
_LAMBDA, _P_CLIP = 4.0, 0.03


def infinity_residual(views: AnalysisViews, k: int, *, gap: int = 2) -> np.ndarray:
    """[H, W] float32: how far frame ``k`` is from frames ``k - gap`` and ``k + gap`` warped by the
    homography of the rotation between them (the motion of points at infinity): the smaller mean
    absolute RGB difference of the two, blurred by 1 px. Zero when the scene has one frame."""
    out = []
    for j in (k - gap, k + gap):
        if not 0 <= j < len(views):
            continue
        H = rotation_homography(views, k, j)
        warped = cv2.warpPerspective(views.images[j], H, views.size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REPLICATE)
        out.append(np.abs(warped - views.images[k]).mean(axis=-1))
    if not out:
        return np.zeros((views.height, views.width), np.float32)
    return cv2.GaussianBlur(np.min(out, axis=0).astype(np.float32), (0, 0), 1.0)


def sky_features(image: np.ndarray, residual: np.ndarray, elevation: np.ndarray, *,
                 line_px: int = _LINE_PX) -> np.ndarray:
    """[H, W, 8] float32 per-pixel features: L*/100, a*/50, b*/50, 10 x the local standard deviation
    of L*/100 over 5 x 5 and 15 x 15 px, the gradient magnitude of L*/100 (Sobel of a 1 px blur),
    10 x the infinity residual and 5 x the sine of the ray's elevation (the clear sky darkens and
    deepens in blue toward the zenith: a dark blue-grey is sky high up, a wall near the horizon).

    The texture features (deviations and gradient) are of L* after a morphological closing by a
    square of side ``2 line_px + 1`` px, which removes dark lines at most ``2 line_px`` px wide:
    overhead wires do not make the sky between them rough (0: the image as it is)."""
    if line_px < 0:
        raise ValueError(f"line_px must be >= 0 (px), got {line_px}")
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    L = lab[..., 0] / 100.0
    colour_L = L
    if line_px:
        L = cv2.morphologyEx(L, cv2.MORPH_CLOSE, np.ones((2 * line_px + 1,) * 2, np.uint8))

    def local_std(size: int) -> np.ndarray:
        mu = cv2.blur(L, (size, size))
        return np.sqrt(np.maximum(cv2.blur(L * L, (size, size)) - mu * mu, 0.0))

    blurred = cv2.GaussianBlur(L, (0, 0), 1.0)
    grad = np.hypot(cv2.Sobel(blurred, cv2.CV_32F, 1, 0), cv2.Sobel(blurred, cv2.CV_32F, 0, 1))
    return np.stack([colour_L, lab[..., 1] / 50.0, lab[..., 2] / 50.0, 10.0 * local_std(5), 10.0 * local_std(15), grad,
                     10.0 * residual, 5.0 * elevation], -1).astype(np.float32)


def _step_edges(image: np.ndarray) -> np.ndarray:
    """[H, W] bool: rows r where the mean CIELAB colour of the 3 rows above and of the 3 rows below
    (r included) differ by more than 12: a roof line or a cornice, not a line of texture or a wire."""
    h, w = image.shape[:2]
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    csum = np.concatenate([np.zeros((1, w, 3), np.float32), np.cumsum(lab, axis=0)])
    r = np.arange(h)
    lo_a, hi_b = np.clip(r - 3, 0, h), np.clip(r + 3, 0, h)
    above = (csum[r] - csum[lo_a]) / np.maximum(r - lo_a, 1)[:, None, None]
    below = (csum[hi_b] - csum[r]) / np.maximum(hi_b - r, 1)[:, None, None]
    edge = np.sqrt(np.sum((above - below) ** 2, axis=-1)) > _EDGE_DE
    edge[0] = False
    return edge


def _wall_continuation(image: np.ndarray, solid: np.ndarray, reach_px: float) -> np.ndarray:
    """[H, W] bool: per column, the pixels from the topmost return of a wall (a run of returns
    across 13 columns or more: not a pole or a mast) up to the highest step edge within ``reach_px``
    rows above it (the mean CIELAB colour of the 3 rows above and the 3 below differ by more than
    12: a roof line, a cornice, not a line of texture), or ``reach_px`` rows without one."""
    h = solid.shape[0]
    joined = cv2.dilate(solid.astype(np.uint8), np.ones((1, 5), np.uint8))
    walls = cv2.morphologyEx(joined, cv2.MORPH_OPEN, np.ones((1, 2 * _WALL_RUN_PX + 1), np.uint8)).astype(bool)
    walls &= solid | cv2.dilate(solid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    top = np.where(walls.any(axis=0), walls.argmax(axis=0), h)
    edge = _step_edges(image)
    rows = np.arange(h)[:, None]
    # the highest step edge within reach above each column's top (a wall's face may have steps of its
    # own: windows, vents, a cornice; its roof line is the last one before the sky)
    reach = round(reach_px)
    lowest = top - reach
    inside = edge & (rows <= top[None, :]) & (rows >= lowest[None, :])
    stop = np.where(inside.any(axis=0), np.where(inside, rows, h).min(axis=0), lowest)
    return (rows >= stop[None, :]) & (rows <= top[None, :]) & (top[None, :] < h)


def _sky_colour_nearby(lab: np.ndarray, sky: np.ndarray, reach_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean CIELAB colour [H, W, 3] of the ``sky`` pixels within a Gaussian of ``reach_px``
    (normalised convolution), and where it is defined [H, W] bool (not far from every sky pixel)."""
    den = cv2.GaussianBlur(sky.astype(np.float32), (0, 0), reach_px)
    ref = cv2.GaussianBlur(lab * sky[..., None].astype(np.float32), (0, 0), reach_px) / np.maximum(den, 1e-6)[..., None]
    return ref, den > 1e-2


def thin_returns(solid: np.ndarray, *, width_px: int = _THIN_PX) -> np.ndarray:
    """[H, W] bool: the returns of ``solid`` [H, W] bool no square of side ``2 width_px + 1`` fits
    in (the hit set minus its morphological opening): a structure at most that wide, by its shape."""
    side = 2 * width_px + 1
    opened = cv2.morphologyEx(solid.astype(np.uint8), cv2.MORPH_OPEN, np.ones((side, side), np.uint8))
    return solid & ~opened.astype(bool)


def thin_occluders(image: np.ndarray, solid: np.ndarray, above: np.ndarray, sky: np.ndarray, *,
                   width_px: int = _THIN_PX, gaps_px: tuple[int, ...] = _THIN_GAP_PX, max_de: float = _THIN_DE,
                   max_std: float = _SEED_MAX_STD, reach_px: float = _THIN_REACH_PX,
                   sky_colour: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """[H, W] bool: the returns of thin structures in front of a smooth background (a wire, a
    signal's mast arm, the top of a pole against the sky), which the sky may be connected across.

    A return is *thin* when it is not in the morphological opening of ``solid`` by a square of side
    ``2 width_px + 1`` (the hit set minus its opening: what no such square fits in); it is *in front
    of* a smooth background when, along one of the 4 directions (rows, columns, diagonals) and at one
    of the distances ``gaps_px`` (past the structure and its mixed pixels), the pixels on both sides
    are free of returns, above the horizon, smooth (standard deviation of L*/100 over 3 x 3 px under
    ``max_std``) and both of the colour of the sky nearby (CIELAB difference under ``max_de`` to the
    mean colour of the ``sky`` pixels within a Gaussian of ``reach_px``): the sky on both sides, not
    an edge between two surfaces, nor a wall's scan line (a spinning lidar's upper beams cross a
    facade in lines a few px wide, with the facade's colour on both sides). The returns themselves
    stay non-sky; this only says what the sky's connectivity and the classifiers' non-sky training
    may leave out.

    Parameters
    ----------
    image : ndarray [H, W, 3] float32
        Display RGB in [0, 1].
    solid : ndarray [H, W] bool
        Pixels a lidar return lands in.
    above : ndarray [H, W] bool
        Pixels above the horizon.
    sky : ndarray [H, W] bool
        Confident sky (the seeds found without crossing anything).
    sky_colour : (ndarray [H, W, 3] float32, ndarray [H, W] bool), optional
        The mean CIELAB colour of the ``sky`` pixels within a Gaussian of ``reach_px`` and where it
        is defined, when the caller has it already (it needs it for the corridor across the occluders).
    """
    if solid.shape != image.shape[:2] or above.shape != solid.shape or sky.shape != solid.shape:
        raise ValueError(f"image {image.shape}, solid {solid.shape}, above {above.shape} and sky {sky.shape}: one "
                         "[H, W] size was expected")
    h, w = solid.shape
    thin = thin_returns(solid, width_px=width_px)
    if not thin.any() or not sky.any():
        return np.zeros_like(thin)
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    ref, has_ref = sky_colour if sky_colour is not None else _sky_colour_nearby(lab, sky, reach_px)
    L = lab[..., 0] / 100.0
    mu = cv2.blur(L, (3, 3))
    std = np.sqrt(np.maximum(cv2.blur(L * L, (3, 3)) - mu * mu, 0.0))
    free = ~solid & above & (std < max_std)
    rr, cc = np.nonzero(thin)
    ok = np.zeros(rr.size, bool)
    for dy, dx in ((1, 0), (0, 1), (1, 1), (1, -1)):
        for g in gaps_px:
            y0, x0, y1, x1 = rr - g * dy, cc - g * dx, rr + g * dy, cc + g * dx
            inside = (y0 >= 0) & (y0 < h) & (x0 >= 0) & (x0 < w) & (y1 >= 0) & (y1 < h) & (x1 >= 0) & (x1 < w)
            y0, x0, y1, x1 = np.clip(y0, 0, h - 1), np.clip(x0, 0, w - 1), np.clip(y1, 0, h - 1), np.clip(x1, 0, w - 1)
            r = ref[rr, cc]
            like = ((np.linalg.norm(lab[y0, x0] - r, axis=-1) < max_de)
                    & (np.linalg.norm(lab[y1, x1] - r, axis=-1) < max_de))
            ok |= inside & free[y0, x0] & free[y1, x1] & like & has_ref[rr, cc]
    out = np.zeros_like(thin)
    out[rr[ok], cc[ok]] = True
    return out


def _colour_line(pix: np.ndarray, F: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the share a in [0, 1] of B in ``pix`` on the line from F to B ([N, 3] each, CIELAB)
    and the chromatic distortion |pix - (F + a (B - F))|."""
    line = B - F
    t = np.clip(np.sum((pix - F) * line, axis=1) / np.maximum(np.sum(line * line, axis=1), 1e-6), 0.0, 1.0)
    return t, np.linalg.norm(pix - F - t[:, None] * line, axis=1)


def refine_boundary(image: np.ndarray, mask: np.ndarray, never: np.ndarray, *, band_px: int = 3,
                    window_px: int = 3, min_contrast: float = 5.0, max_distortion: float = _MAX_DISTORTION,
                    surface_de: float = _SURFACE_DE) -> tuple[np.ndarray, np.ndarray]:
    """The sky's boundary placed by colour: each pixel within ``band_px`` of the boundary takes the
    share of the sky in it, the projection of its colour on the line from the nearby foreground
    colour F to the nearby sky colour B (the colour-line model of alpha matting, Levin, Lischinski &
    Weiss 2008), and is sky when that share is at least one half (the rule of the hand-drawn masks).

    B is the mean colour of the sky pixels outside the band within a Gaussian of ``2 window_px``
    (normalised convolution); F is the colour farthest from B among the non-sky pixels within
    ``window_px`` (the core of a wire, a pole, the wall behind an edge). Where B and F differ by less
    than ``min_contrast`` (CIELAB), the label is kept.

    A pixel need not lie on that line: the pale top of a far building under a blue sky, beside the
    dark roof below it, is a third colour, and its projection on the dark-to-blue line says sky. So,
    as sampling-based matting picks the foreground sample by the *chromatic distortion*
    ``|C - (a F + (1 - a) B)|`` (Wang & Cohen 2007, "Optimized color sampling for robust matting",
    CVPR), where that distortion exceeds ``max_distortion`` (CIELAB) the pixel takes its share
    from the line of the nearby surface colour that explains it best, if that explains it better: a
    non-sky pixel within ``window_px`` whose 3 x 3 neighbourhood is all non-sky (a surface's body,
    not a wire's mixed pixel) and whose colour differs from B by more than ``surface_de``. Both
    values were chosen on the hand-drawn masks (``docs/findings.md``, "A third colour at the sky's
    boundary").

    Parameters
    ----------
    image : ndarray [H, W, 3] float32
        Display RGB.
    mask : ndarray [H, W] bool
        The sky as cut.
    never : ndarray [H, W] bool
        Pixels that are never sky (returns, below the horizon).

    Returns
    -------
    mask : ndarray [H, W] bool
    alpha : ndarray [H, W] float32
        The sky's share per pixel: the colour-line estimate in the band, the label elsewhere;
        below 0.5 wherever ``never`` holds.
    """
    h, w = mask.shape
    m8 = mask.astype(np.uint8)
    size = 2 * band_px + 1
    band = (cv2.dilate(m8, np.ones((size, size), np.uint8)) != cv2.erode(m8, np.ones((size, size), np.uint8)))
    alpha = mask.astype(np.float32)
    rr, cc = np.nonzero(band)
    if rr.size == 0:
        return mask.copy(), alpha
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    interior = (mask & ~band).astype(np.float32)
    sigma = 2.0 * window_px
    den = cv2.GaussianBlur(interior, (0, 0), sigma)
    sky_col = cv2.GaussianBlur(lab * interior[..., None], (0, 0), sigma) / np.maximum(den, 1e-6)[..., None]
    B = sky_col[rr, cc]
    has_b = den[rr, cc] > 1e-3
    pix = lab[rr, cc]
    # a surface's body: its 3 x 3 neighbourhood all non-sky (a wire's mixed pixels are not)
    body = cv2.erode((~mask).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    # F: the non-sky colour farthest from B within the window; and the surface colour whose line with
    # B explains the pixel best (the least chromatic distortion) with its share
    best = np.full(rr.size, -1.0)
    F = np.zeros((rr.size, 3), np.float32)
    surface_distortion = np.full(rr.size, np.inf)
    surface_share = np.zeros(rr.size)
    for dy in range(-window_px, window_px + 1):
        for dx in range(-window_px, window_px + 1):
            y, x = rr + dy, cc + dx
            ok = (y >= 0) & (y < h) & (x >= 0) & (x < w)
            y, x = np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)
            cand = ok & ~mask[y, x]
            col = lab[y, x]
            d = np.where(cand, np.sum((col - B) ** 2, axis=1), -1.0)
            take = d > best
            best = np.where(take, d, best)
            F[take] = col[take]
            surface = ok & body[y, x] & (d > surface_de ** 2)
            if surface.any():
                t, distortion = _colour_line(pix, col, B)
                better = surface & (distortion < surface_distortion)
                surface_distortion = np.where(better, distortion, surface_distortion)
                surface_share = np.where(better, t, surface_share)
    share, distortion = _colour_line(pix, F, B)
    third = (distortion > max_distortion) & (surface_distortion < distortion)
    share = np.where(third, surface_share, share)
    norm2 = np.sum((B - F) ** 2, axis=1)
    decided = has_b & (best >= 0) & (norm2 > min_contrast ** 2)
    alpha[rr[decided], cc[decided]] = share[decided]
    out = alpha >= 0.5
    out &= ~never
    alpha = np.where(never, np.minimum(alpha, 0.49), alpha)
    return out, alpha.astype(np.float32)


def _frame_colour_probability(lab: np.ndarray, sky: np.ndarray, not_sky: np.ndarray, region: np.ndarray,
                               *, components: int = 4, max_samples: int = 4000, seed: int = 0) -> np.ndarray | None:
    """[H, W] float32: the probability of sky by colour alone, from Gaussian mixtures (OpenCV's
    ``ml.EM``, diagonal covariances) fitted to this frame's sky and non-sky seed pixels in CIELAB
    (GrabCut's colour model, Rother, Kolmogorov & Blake 2004), over ``region``; ``None`` when either
    class has too few seeds."""
    out = np.full(lab.shape[:2], 0.5, np.float32)
    rng = np.random.default_rng(seed)
    logs = []
    for mask in (sky, not_sky):
        x = lab[mask]
        if len(x) < 20 * components:
            return None
        x = x[rng.choice(len(x), min(len(x), max_samples), replace=False)].astype(np.float64)
        em = cv2.ml.EM_create()  # type: ignore[attr-defined]  # the stubs lack the ml module
        em.setClustersNumber(components)
        em.setCovarianceMatrixType(cv2.ml.EM_COV_MAT_DIAGONAL)
        em.setTermCriteria((cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-3))
        em.trainEM(x)
        weights = em.getWeights().ravel()
        means, covs = em.getMeans(), em.getCovs()
        q = lab[region].astype(np.float64)
        like = np.zeros(len(q))
        for c in range(components):
            var = np.maximum(np.diag(covs[c]), 1.0)
            d = np.sum((q - means[c]) ** 2 / var, axis=1)
            like += weights[c] * np.exp(-0.5 * d) / np.sqrt(np.prod(2 * np.pi * var))
        logs.append(np.log(np.maximum(like, 1e-300)))
    out[region] = (1.0 / (1.0 + np.exp(np.clip(logs[1] - logs[0], -50, 50)))).astype(np.float32)
    return out


def _column_colour_probability(lab: np.ndarray, sky: np.ndarray, not_sky: np.ndarray, *,
                                scale: float = 8.0) -> np.ndarray:
    """[H, W] float32: the probability of sky by the colours of the column: a pixel is compared with
    the nearest sky seed above it and the nearest non-sky seed (a return) below it in its column
    (CIELAB, 3 x 3 box-filtered), p = 1 / (1 + exp((d_sky - d_not) / ``scale``)); 0.5 where either
    is missing. A wall rising above its last return is the colour of that wall, not of the sky over
    its roof line."""
    h, w = sky.shape
    smooth = cv2.blur(lab, (3, 3))
    rows = np.arange(h)[:, None]
    above = np.maximum.accumulate(np.where(sky, rows, -1), axis=0)
    below = np.minimum.accumulate(np.where(not_sky, rows, h)[::-1], axis=0)[::-1]
    cols = np.broadcast_to(np.arange(w)[None, :], (h, w))
    has = (above >= 0) & (below < h)
    d_sky = np.linalg.norm(lab - smooth[np.clip(above, 0, h - 1), cols], axis=-1)
    d_not = np.linalg.norm(lab - smooth[np.clip(below, 0, h - 1), cols], axis=-1)
    p = 1.0 / (1.0 + np.exp(np.clip((d_sky - d_not) / scale, -50, 50)))
    return np.where(has, p, 0.5).astype(np.float32)


def _blue_pockets(lab: np.ndarray, sky: np.ndarray, free: np.ndarray, *, max_de: float = _THIN_DE,
                  reach_px: float = _THIN_REACH_PX) -> np.ndarray:
    """[H, W] bool: the pixels of ``free`` (above the horizon, no return in them) of the clear sky's
    blue (b* < -12, -20 < a* < 5) and of the colour of the ``sky`` nearby (CIELAB difference under
    ``max_de`` to its mean within a Gaussian of ``reach_px``) that are joined to ``sky`` through such
    pixels (8-connected); ``lab`` [H, W, 3] is the frame in CIELAB.

    The minimum cut's smoothness term takes a narrow pocket of sky between structures to them when
    the evidence there is weak (between two guy wires and a wall's corner, under a bar over a roof, on
    pandaset_002_right: docs/findings.md, "Pockets of blue sky"). A pixel of the sky's own blue,
    joined to it, with nothing the lidar saw in it, is sky by the argument that makes blue pixels
    seeds (Rayleigh scattering); a blue sign or glass differs from the sky beside it by more."""
    if not sky.any():
        return np.zeros_like(sky)
    ref, has_ref = _sky_colour_nearby(lab, sky, reach_px)
    blue = (lab[..., 2] < _BLUE_B) & (lab[..., 1] > _BLUE_A[0]) & (lab[..., 1] < _BLUE_A[1])
    like = free & blue & has_ref & (np.linalg.norm(lab - ref, axis=-1) < max_de) & ~sky
    if not like.any():
        return like
    _, labels = cv2.connectedComponents((like | sky).astype(np.uint8), connectivity=8)
    return like & np.isin(labels, np.unique(labels[sky]))


def _sky_components(mask: np.ndarray, seeds: np.ndarray, *, bridge_px: int = 0,
                    link: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The components of ``mask`` (8-connected: a sky crossed by a wire stays one) that hold a seed
    or touch the top row; with ``bridge_px``, components apart by at most that many pixels (a lamp's
    arm, a pole's crossbar, a bundle of wires: not a wall) count as one; pixels of ``link`` (thin
    occluders, :func:`thin_occluders`) join the components they touch. A component that does
    neither (a pane in a wall) is dropped.

    Returns
    -------
    labels : ndarray [H, W] int32
        The component of each pixel of ``mask`` (0 outside it).
    kept : ndarray [N] int
        The labels that hold a seed or touch the top row.
    """
    joined = mask.astype(np.uint8)
    if link is not None:
        joined |= link.astype(np.uint8)
    if bridge_px > 0:
        joined = cv2.morphologyEx(joined, cv2.MORPH_CLOSE, np.ones((2 * bridge_px + 1,) * 2, np.uint8))
    _, labels = cv2.connectedComponents(joined, connectivity=8)
    labels = np.where(mask, labels, 0).astype(np.int32)
    kept = np.unique(np.concatenate([labels[seeds & mask], labels[0][mask[0]]]))
    return labels, kept[kept > 0]


def rotation_homography(views: AnalysisViews, k: int, j: int) -> np.ndarray:
    """[3, 3] float64: the homography that maps a pixel of frame ``k`` to the pixel of frame ``j``
    that sees the same direction (points at infinity: K_j R_j^T R_k K_k^-1, in pixel-centre
    coordinates, as ``cv2.warpPerspective`` takes it with ``WARP_INVERSE_MAP``)."""
    shift = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])  # pixel centres at +0.5
    R = views.camera_to_world[j][:3, :3].T @ views.camera_to_world[k][:3, :3]
    return np.linalg.inv(shift) @ views.K[j] @ R @ np.linalg.inv(views.K[k]) @ shift


def neighbour_support(views: AnalysisViews, masks: np.ndarray, k: int, labels: np.ndarray, *,
                      gaps: tuple[int, ...] = (1, 2)) -> np.ndarray:
    """Per region of frame ``k``, the share of it that the neighbouring frames ``k -/+ gaps`` also
    call sky, each warped by the rotation between them (the sky lies at infinity: it stays where the
    rotation puts it, a surface at finite distance does not); the largest over the neighbours that
    see at least half of the region (a near edge's parallax hides part of the sky from the frames on
    one side), NaN where none does (a scene of one frame).

    Parameters
    ----------
    views : AnalysisViews
    masks : ndarray [F, H, W] bool
        Every frame's sky.
    k : int
    labels : ndarray [H, W] int
        Regions of frame ``k``, 1 to N (0: none).

    Returns
    -------
    ndarray [N + 1] float64
        Index 0 (no region) is NaN.
    """
    n = int(labels.max()) + 1
    area = np.bincount(labels.ravel(), minlength=n).astype(np.float64)
    best = np.full(n, np.nan)
    flags = cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
    for gap in gaps:
        for j in (k - gap, k + gap):
            if not 0 <= j < len(views):
                continue
            H = rotation_homography(views, k, j)
            seen = cv2.warpPerspective(np.ones(masks[j].shape, np.uint8), H, views.size, flags=flags,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
            sky = cv2.warpPerspective(masks[j].astype(np.uint8), H, views.size, flags=flags,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool) & seen
            n_seen = np.bincount(labels[seen], minlength=n)
            n_sky = np.bincount(labels[sky], minlength=n)
            use = n_seen >= 0.5 * np.maximum(area, 1)
            share = n_sky[use] / n_seen[use]
            best[use] = np.where(np.isnan(best[use]), share, np.maximum(best[use], share))
    best[0] = np.nan
    return best


def _top_connected(mask: np.ndarray) -> np.ndarray:
    """The components of ``mask`` (4-connected) that touch the top row."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=4)
    if n <= 1:
        return mask.copy()
    top = np.unique(labels[0][mask[0]])
    return np.isin(labels, top[top > 0])


def _large(mask: np.ndarray, min_fraction: float) -> np.ndarray:
    """The components of ``mask`` (8-connected) that cover at least ``min_fraction`` of the image."""
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_fraction * mask.size)
    return np.isin(labels, big[big > 0])


def _cut(image: np.ndarray, p: np.ndarray, never: np.ndarray, always: np.ndarray, *,
         loose: np.ndarray | None = None) -> np.ndarray:
    """[H, W] bool: the minimum cut of the sky/non-sky labelling (see the module docstring); no
    smoothness term joins a pixel of ``loose`` [H, W] bool to its neighbours."""
    h, w = p.shape
    lab = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2Lab)
    dx = np.sum((lab[:, 1:] - lab[:, :-1]) ** 2, axis=-1)
    dy = np.sum((lab[1:] - lab[:-1]) ** 2, axis=-1)
    beta = 1.0 / (2.0 * max(float(np.concatenate([dx.ravel(), dy.ravel()]).mean()), 1e-6))
    graph = maxflow.Graph[float]()
    ids = graph.add_grid_nodes((h, w))
    free = np.ones((h, w), bool) if loose is None else ~loose
    for diff, structure, joined in ((dx, np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]]), free[:, 1:] & free[:, :-1]),
                                    (dy, np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]]), free[1:] & free[:-1])):
        weights = np.zeros((h, w), np.float64)
        weights[:diff.shape[0], :diff.shape[1]] = _LAMBDA * np.exp(-beta * diff) * joined
        graph.add_grid_edges(ids, weights=weights, structure=structure, symmetric=True)
    pc = np.clip(p.astype(np.float64), _P_CLIP, 1.0 - _P_CLIP)
    cost_sky, cost_not = -np.log(pc), -np.log1p(-pc)
    big = 1e9
    cost_sky[never] = big
    cost_not[always & ~never] = big
    # a node on the source side is sky and pays its sink capacity (the cost of being sky)
    graph.add_grid_tedges(ids, cost_not, cost_sky)
    graph.maxflow()
    return ~graph.get_grid_segments(ids)


@dataclass
class SkySegmentation:
    """Sky masks of every frame of a scene at the analysis size.

    Attributes
    ----------
    masks : ndarray [F, H, W] bool
    probability : ndarray [F, H, W] float32
        The per-scene classifier's probability of sky (0 below the horizon).
    alpha : ndarray [F, H, W] float32
        The sky's share of each pixel (:func:`refine_boundary`): fractional along the boundary.
    facts : dict
        Seeds, classifier and timing facts for ``info.json``.
    """

    masks: np.ndarray
    probability: np.ndarray
    alpha: np.ndarray
    facts: dict[str, Any] = field(default_factory=dict)


def segment_sky(views: AnalysisViews, solid: list[np.ndarray], *, seed: int = 0,
                untrusted: list[np.ndarray] | None = None) -> SkySegmentation:
    """Sky masks of every frame (see the module docstring).

    Parameters
    ----------
    views : AnalysisViews
    solid : list of ndarray [H, W] bool
        Per frame, the pixels a lidar return projects into (static returns of every sweep and the
        frame's own): never sky.
    seed : int
        Seeds the sampling of the classifier's training pixels.
    untrusted : list of ndarray [H, W] bool, optional
        Per frame, the pixels any sweep's return lands in (``any_sweep_masks`` of the scene's analysis:
        the copies of a structure that other sweeps' registration puts a few px off). Within reach of
        a crossed thin occluder they are never sky either: the sky found across a wire or a pole keeps
        clear of every copy of it.

    Returns
    -------
    SkySegmentation
        All-false masks when no frame has a sky seed (a view without open sky, or no lidar at all:
        then nothing can be told from the image with confidence; ``facts["fallback"]`` says so).
    """
    n, h, w = len(views), views.height, views.width
    if untrusted is not None and (len(untrusted) != n or any(u.shape != (h, w) for u in untrusted)):
        raise ValueError(f"untrusted: {n} masks of {h}x{w} (one per frame) were expected")
    clearance = max(1, round(_SEED_CLEARANCE_PX * w / 480))
    kernel = np.ones((2 * clearance + 1, 2 * clearance + 1), np.uint8)
    line_px = max(1, round(_LINE_PX * w / 480)) if _LINE_PX else 0  # 0: no closing, at any size
    feats, above, sky_seeds, not_seeds, links, corridors, loose = [], [], [], [], [], [], []
    for k in range(n):
        elev = views.elevation(k)
        feat = sky_features(views.images[k], infinity_residual(views, k), elev, line_px=line_px)
        # not the continuation of a wall above its topmost return, up to the first edge (a spinning
        # lidar's upper beams are degrees apart: between two of them a wall returns nothing either)
        reach = views.K[k][1, 1] * math.tan(math.radians(_BEAM_GAP_DEG))
        beyond = ~_wall_continuation(views.images[k], solid[k], reach)
        lab = cv2.cvtColor(views.images[k], cv2.COLOR_RGB2Lab)
        blue = (lab[..., 2] < _BLUE_B) & (lab[..., 1] > _BLUE_A[0]) & (lab[..., 1] < _BLUE_A[1])
        within = elev < math.sin(math.radians(_SEED_MAX_ELEVATION_DEG))
        smooth_static = (feat[..., 3] < 10 * _SEED_MAX_STD) & (feat[..., 6] < 10 * _SEED_MAX_RESIDUAL)
        # connected to the top through the open sky: not across a lidar return, nor a roof line; and in a
        # patch of seeds of some size (a window mirroring the blue sky is a small one)
        edges = _step_edges(views.images[k])
        near = cv2.dilate(solid[k].astype(np.uint8), kernel).astype(bool)
        clear = (elev > 0.0) & ~near & ~edges
        seeds = _large(_top_connected(clear) & beyond & smooth_static & (within | blue), _MIN_OPEN_SKY)
        # thin occluders with that sky on both sides (a wire, a mast arm, a pole's top) are crossed on the
        # way to the top, and the seeds need only clear their mixed pixels; other returns keep the clearance
        # the sky's colour around the seeds: the occluders' test and the corridor across them both need it
        sky_colour = _sky_colour_nearby(lab, seeds, _THIN_REACH_PX) if seeds.any() else None
        thin = thin_occluders(views.images[k], solid[k], elev > 0.0, seeds, sky_colour=sky_colour)
        if thin.any() and sky_colour is not None:
            thick = cv2.dilate((solid[k] & ~thin).astype(np.uint8), kernel).astype(bool)
            mixed = cv2.dilate(thin.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            near = thick | mixed
            # the corridor is the occluder, its mixed pixels and the sky's colour around it: where a wire
            # crosses a roof line, the wall below is not on the way (pandaset_002_back, frame 12)
            ref, has_ref = sky_colour
            sky_like = has_ref & (np.linalg.norm(lab - ref, axis=-1) < _THIN_DE)
            corridor = (cv2.dilate(thin.astype(np.uint8), kernel).astype(bool) & ~thick & (elev > 0.0)
                        & (sky_like | mixed))
            clear = (elev > 0.0) & ~near & ~edges
            open_sky = _top_connected(clear | corridor)
            candidates = open_sky & clear & beyond & smooth_static & (within | blue)
            seeds = _large(candidates | (open_sky & corridor), _MIN_OPEN_SKY) & candidates
        if not solid[k].any():  # no lidar in view: nothing here is confirmed empty, and no seed is made
            seeds = np.zeros_like(seeds)
        # a return of a structure a few px wide with the colour of the sky around it (a wire's mixed
        # pixel, another sweep's copy of a wire or a mast a px off) stays non-sky but says nothing of
        # its neighbours: no smoothness term joins it to them in the cut (the pockets of sky between
        # a bundle of wires and a roof's corner on pandaset_002_right)
        if sky_colour is not None:
            ref, has_ref = sky_colour
            loose.append(thin_returns(solid[k]) & has_ref & (np.linalg.norm(lab - ref, axis=-1) < _THIN_DE))
        else:
            loose.append(np.zeros((h, w), bool))
        feats.append(feat)
        above.append(elev > 0.0)
        sky_seeds.append(seeds)
        # a thin occluder's returns are mixed pixels of it and the sky behind: not the non-sky's colours
        not_seeds.append(solid[k] & ~thin & (elev > -0.02))
        corridors.append(cv2.dilate(thin.astype(np.uint8), kernel).astype(bool))
        links.append(cv2.dilate(thin.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (elev > 0.0))
    n_sky = int(sum(s.sum() for s in sky_seeds))
    n_not = int(sum(s.sum() for s in not_seeds))
    facts: dict[str, Any] = {"size": [w, h], "sky_seed_pixels": n_sky, "non_sky_seed_pixels": n_not}
    probability = np.zeros((n, h, w), np.float32)
    masks = np.zeros((n, h, w), bool)
    alphas = np.zeros((n, h, w), np.float32)
    labels = np.zeros((n, h, w), np.int32)
    kept: list[np.ndarray] = [np.zeros(0, int)] * n
    refined = np.zeros((n, h, w), bool)
    if n_sky == 0:
        facts["fallback"] = "no confident sky pixel in any frame: no sky"
        return SkySegmentation(masks=masks, probability=probability, alpha=alphas, facts=facts)
    rng = np.random.default_rng(seed)
    xs = np.concatenate([f[s] for f, s in zip(feats, sky_seeds)])
    xn = np.concatenate([f[s] for f, s in zip(feats, not_seeds)]) if n_not else np.zeros((0, xs.shape[1]), np.float32)
    xs = xs[rng.choice(len(xs), min(len(xs), _MAX_SEEDS), replace=False)]
    if len(xn):
        xn = xn[rng.choice(len(xn), min(len(xn), _MAX_SEEDS), replace=False)]
        forest = cv2.ml.RTrees_create()  # type: ignore[attr-defined]  # the stubs lack the ml module
        forest.setMaxDepth(_DEPTH)
        forest.setMinSampleCount(10)
        forest.setTermCriteria((cv2.TERM_CRITERIA_MAX_ITER, _TREES, 0))
        cv2.setRNGSeed(seed)
        forest.train(np.ascontiguousarray(np.concatenate([xs, xn]), np.float32), cv2.ml.ROW_SAMPLE,
                     np.concatenate([np.ones(len(xs)), np.zeros(len(xn))]).astype(np.int32))
    else:
        forest = None
    for k in range(n):
        region = above[k]
        p = np.zeros((h, w), np.float32)
        if region.any():
            if forest is None:
                p[region] = 1.0
            else:
                _, votes = forest.predict(np.ascontiguousarray(feats[k][region]), flags=cv2.ml.DTREES_PREDICT_SUM)
                p[region] = votes.ravel() / _TREES
        lab = cv2.cvtColor(views.images[k], cv2.COLOR_RGB2Lab)
        evidence = [p]
        colour = _frame_colour_probability(lab, sky_seeds[k], not_seeds[k] & region, region, seed=seed + k)
        if colour is not None:
            evidence.append(colour)
        evidence.append(_column_colour_probability(lab, sky_seeds[k], not_seeds[k]))
        # the scene's classifier, the frame's colours and the column's colours: their mean log-odds
        odds = np.mean([np.log(np.clip(e, _P_CLIP, 1 - _P_CLIP) / (1 - np.clip(e, _P_CLIP, 1 - _P_CLIP)))
                        for e in evidence], axis=0)
        p = np.where(region, 1.0 / (1.0 + np.exp(-odds)), 0.0).astype(np.float32)
        probability[k] = p
        never = ~region | solid[k] | (untrusted[k] & corridors[k] if untrusted is not None else False)
        cut = _cut(views.images[k], p, never, sky_seeds[k] & ~never, loose=loose[k]) & ~never
        # a pocket of the sky's own blue the cut gave to the structures around it is sky (no return of
        # any sweep in it: another sweep's copy of a wire stays out)
        cut |= _blue_pockets(lab, cut, ~never & (~untrusted[k] if untrusted is not None else True))
        mask, alpha = refine_boundary(views.images[k], cut, never)
        # the sky is one with the open sky: a patch enclosed by the scene, with no seed, is not
        labels[k], kept[k] = _sky_components(mask, sky_seeds[k], bridge_px=max(1, round(2 * w / 480)),
                                             link=links[k])
        masks[k], alphas[k] = np.isin(labels[k], kept[k]), alpha
        refined[k] = mask
    # and it is sky in the neighbouring frames too: a facade between the lidar's upper scan lines that
    # one frame calls sky (its seeds and all) the next does not; decided against every frame's first
    # labels, so the order of frames does not matter
    first = masks.copy()
    dropped = 0
    for k in range(n):
        support = neighbour_support(views, first, k, labels[k])
        weak = kept[k][support[kept[k]] < _MIN_SUPPORT]  # NaN (no neighbour sees it) compares False
        if len(weak):
            masks[k] &= ~np.isin(labels[k], weak)
            dropped += len(weak)
        alphas[k] = np.where(refined[k] & ~masks[k], 0.0, alphas[k]).astype(np.float32)
    facts["patches_without_support"] = dropped
    facts.update(classifier=f"random forest ({_TREES} trees, depth {_DEPTH}) on {len(xs)} sky and {len(xn)} "
                            f"non-sky seed pixels", sky_fraction=round(float(masks.mean()), 4))
    return SkySegmentation(masks=masks, probability=probability, alpha=alphas, facts=facts)


def sky_matte(mask: np.ndarray, image: np.ndarray, solid: np.ndarray | None = None, *, radius: int = 2,
              eps: float = 1e-3) -> np.ndarray:
    """[H, W] float32 soft sky matte in [0, 1]: ``mask`` feathered along the frame's edges by a
    guided filter (He et al. 2013) with ``image`` (display RGB) as guide; pixels of ``solid`` (lidar
    returns) stay below 0.5, pixels far from the boundary keep their label.

    Parameters
    ----------
    mask : ndarray [H, W] bool
    image : ndarray [H, W, 3] float32
    solid : ndarray [H, W] bool, optional
    radius : int
        Guided filter radius (px); 0 returns the mask as floats.
    eps : float
        Guided filter regularisation.
    """
    m = np.asarray(mask, np.float32)
    if radius <= 0:
        return m
    # OpenCV's filter on the [0, 1] frame, which smooths across the sky's edges as a box would
    # (reference_model/guided_filter.py): the definition kept a pole's crossarms whole under the
    # overcast sky but left more of the clear sky's blue at the edges and raised the rear camera's
    # snow flicker over the raw frames' (docs/findings.md, thirty-fifth session)
    alpha = cv2.ximgproc.guidedFilter(np.ascontiguousarray(image, np.float32), m, radius, eps)
    alpha = np.clip(alpha, 0.0, 1.0)
    # only the boundary band is feathered: a pixel whose whole window has one label keeps it
    band = cv2.dilate(m, np.ones((2 * radius + 1,) * 2, np.uint8)) != cv2.erode(m, np.ones((2 * radius + 1,) * 2,
                                                                                          np.uint8))
    alpha = np.where(band, alpha, m)
    if solid is not None:
        alpha = np.where(solid, np.minimum(alpha, 0.49), alpha)
    return alpha.astype(np.float32)
