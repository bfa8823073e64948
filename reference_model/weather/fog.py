"""Beer-Lambert fog: the exact per-layer form and the paper's depth-map post-process (docs/design.md §7).

Light from a point at distance l along the ray keeps the fraction t = exp(-beta l) and the fog
adds (1 - t) c_fog. With Gaussian splatting a pixel mixes several layers, so the exact image
attenuates every Gaussian by its own distance, t_i = exp(-beta |mu_i - o|) (o the camera center),
and the background (sky) sits at infinity::

    C = sum_i w_i c_i t_i + c_fog (A - sum_i w_i t_i) + T_final (bg t_bg + c_fog (1 - t_bg))

with w_i the blending weights, A = sum_i w_i = 1 - T_final, and t_bg = exp(-beta inf) (0 for any
beta > 0). It costs one extra rasterized channel (sum_i w_i t_i) besides the colors premultiplied by
t_i. The paper instead fogs the rendered image with one t per pixel from the expected depth map
(:func:`fog_postprocess`); :func:`fog_postprocess` minus :func:`compose_exact` is the error of that
shortcut, measured by ``bench_weather``.

``offset_m`` starts the attenuation at a distance (rain haze beyond the explicit particles):
t = exp(-beta max(l - offset_m, 0)). Colors are float32 RGB in [0, 1] (the images' values, as
the paper fogs them); images are numpy.

Visibilities are meteorological optical ranges, V = -ln(0.05) / beta = 2.996 / beta (the WMO's 5 %
contrast threshold; Koschmieder's 2 % gives 3.912 / beta): see :data:`MOR_CONSTANT`.
"""

from __future__ import annotations

import math

import numpy as np

from wcbench.reference_model._numba_backend import load_numba_kernels

__all__ = [
    "KOSCHMIEDER_CONSTANT",
    "KOSCHMIEDER_CONTRAST_THRESHOLD",
    "MOR_CONSTANT",
    "MOR_CONTRAST_THRESHOLD",
    "VISIBILITY_CONTRAST",
    "background_transmittance",
    "compose_exact",
    "density_from_visibility",
    "fog_postprocess",
    "gaussian_transmittance",
    "ray_distance",
    "transmitted_channels",
    "visibility_from_density",
]

#: The visibility convention. Koschmieder's law: a black object seen against the horizon sky keeps
#: the contrast C = exp(-beta l) at distance l, so it vanishes at V = -ln(eps) / beta for a
#: threshold contrast eps. wcbench uses the WMO / CIE meteorological optical range (MOR): the path
#: that attenuates a collimated beam to 5 % (eps = 0.05, WMO-No. 8; CIE 17-31-018), so
#: V = 2.996 / beta. Koschmieder's (1924) own threshold, eps = 0.02, gives V = 3.912 / beta, 1.31x
#: longer (the older "meteorological range"; Rasmussen et al. 1999 use it for snow). The paper's
#: d_f = 0.2 m^-1 is "V ~ 15 m" in the MOR convention.
MOR_CONTRAST_THRESHOLD = 0.05
KOSCHMIEDER_CONTRAST_THRESHOLD = 0.02
#: -ln(0.05) = 2.996: V = MOR_CONSTANT / beta (the convention of every visibility in wcbench).
MOR_CONSTANT = -math.log(MOR_CONTRAST_THRESHOLD)
#: -ln(0.02) = 3.912: Koschmieder's 2 % visibility, for converting a visibility quoted that way.
KOSCHMIEDER_CONSTANT = -math.log(KOSCHMIEDER_CONTRAST_THRESHOLD)
#: The constant the visibility functions use (the MOR's; kept under this name for callers).
VISIBILITY_CONTRAST = MOR_CONSTANT
#: Largest |value| of a fog or background color: the rasterizer's ``MAX_ABS_COLOR`` (not imported:
#: this module needs no torch); beyond it float32 sums could overflow (docs/design.md §9).
MAX_ABS_COLOR = 1e15
#: The math runs in float32: larger densities and offsets would round to Inf (and Inf * 0 = NaN).
_F32_MAX = float(np.finfo(np.float32).max)


def density_from_visibility(visibility_m: float) -> float:
    """Extinction coefficient beta (m^-1) for a visibility V (m): beta = 2.996 / V.

    V is the meteorological optical range (5 % contrast, :data:`MOR_CONSTANT`); a visibility quoted
    with Koschmieder's 2 % threshold converts as V_MOR = V_2% x 2.996 / 3.912.

    Raises
    ------
    ValueError
        If ``visibility_m`` is not positive (``inf`` is allowed and gives 0), or so small that beta
        would exceed float32 (the fog math's precision).
    """
    if not visibility_m > 0:
        raise ValueError(f"visibility_m must be > 0 metres, got {visibility_m}")
    if math.isinf(visibility_m):
        return 0.0
    if not VISIBILITY_CONTRAST / _F32_MAX <= visibility_m:
        raise ValueError(f"visibility_m must be at least {VISIBILITY_CONTRAST / _F32_MAX:.3g} m (beta within float32), "
                         f"got {visibility_m}")
    return VISIBILITY_CONTRAST / visibility_m


def visibility_from_density(beta: float) -> float:
    """Visibility V = 2.996 / beta (m), the meteorological optical range (5 % contrast); ``inf`` for
    beta = 0 (and for a beta below 2.996 / 1.8e308, whose visibility exceeds float64).

    Raises
    ------
    ValueError
        If ``beta`` is negative or NaN.
    """
    _check_beta(beta)
    return math.inf if beta == 0 else VISIBILITY_CONTRAST / beta


def _check_beta(beta: float) -> None:
    if not (0 <= beta <= _F32_MAX):
        raise ValueError(f"beta (fog density) must be a finite value >= 0 m^-1 (float32), got {beta}")


def _check_offset(offset_m: float) -> None:
    if not (0 <= offset_m <= _F32_MAX):
        raise ValueError(f"offset_m must be a finite distance >= 0 metres (float32), got {offset_m}")


def _check_color(color: np.ndarray, name: str) -> np.ndarray:
    c = np.asarray(color, np.float64)
    if c.ndim < 1 or c.shape[-1] != 3 or not np.all(np.isfinite(c)) or (c.size and np.abs(c).max() > MAX_ABS_COLOR):
        raise ValueError(f"{name} must be finite RGB within +-{MAX_ABS_COLOR:g} with a last axis of 3, "
                         f"got shape {c.shape}")
    return c.astype(np.float32)


def gaussian_transmittance(
    means: np.ndarray, camera_center: np.ndarray, beta: float, *, offset_m: float = 0.0
) -> np.ndarray:
    """Per-Gaussian transmittance t_i = exp(-beta max(|mu_i - o| - offset_m, 0)).

    Parameters
    ----------
    means : ndarray [N, 3]
        Gaussian centers, world (m).
    camera_center : ndarray [3]
        Camera center o, world (m).
    beta : float
        Extinction coefficient (m^-1), >= 0.
    offset_m : float
        Distance before which there is no attenuation (m), >= 0.

    Returns
    -------
    ndarray [N] float32
        In [0, 1].

    Raises
    ------
    ValueError
        On a negative or non-finite ``beta`` or ``offset_m``, or a wrongly shaped input.
    """
    _check_beta(beta)
    _check_offset(offset_m)
    m = np.asarray(means)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f"means must have shape [N, 3], got {m.shape}")
    if np.float32(beta) == 0:  # no fog: t = 1 even where the float32 distance overflows (0 * Inf)
        return np.ones(m.shape[0], np.float32)
    # float32 is enough: at 1 km a distance is off by 0.1 mm, t by beta * 1e-4 of itself. It runs
    # on every Gaussian of every fogged frame, single-threaded numpy (robust on a loaded machine).
    # A distance beyond float32 is Inf (t = 0); a Gaussian with non-finite values gets NaN (culled).
    with np.errstate(over="ignore", invalid="ignore"):
        diff = m.astype(np.float32, copy=False) - np.asarray(camera_center, np.float32).reshape(3)
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        d -= np.float32(offset_m)
        np.maximum(d, 0.0, out=d)
        d *= np.float32(-beta)
        return np.exp(d, out=d)


def transmitted_channels(
    means: np.ndarray,
    colors: np.ndarray,
    camera_center: np.ndarray,
    beta: float,
    *,
    offset_m: float = 0.0,
    out: np.ndarray | None = None,
    fast: bool = True,
) -> np.ndarray:
    """The channels the exact fog rasterizes: (c_i t_i, t_i) with t_i of :func:`gaussian_transmittance`.

    Parameters
    ----------
    means : ndarray [N, 3]
        Gaussian centers, world (m).
    colors : ndarray [N, C]
        Colors (RGB in [0, 1] for C = 3).
    camera_center : ndarray [3]
        Camera center o, world (m).
    beta : float
        Extinction coefficient (m^-1), >= 0.
    offset_m : float
        Distance before which there is no attenuation (m), >= 0.
    out : ndarray [N, C + 1] float32, optional
        Written in place and returned.
    fast : bool
        The numba kernel when available (one pass, both cores); else the numpy reference.

    Returns
    -------
    ndarray [N, C + 1] float32
        Colors times t_i, then t_i.

    Raises
    ------
    ValueError
        As :func:`gaussian_transmittance`; or if ``colors`` or ``out`` do not match ``means``.
    """
    _check_beta(beta)
    _check_offset(offset_m)
    m = np.asarray(means, np.float32)
    c = np.asarray(colors, np.float32)
    if m.ndim != 2 or m.shape[1] != 3 or c.ndim != 2 or c.shape[0] != m.shape[0]:
        raise ValueError(f"means must be [N, 3] and colors [N, C], got {m.shape} and {c.shape}")
    shape = (m.shape[0], c.shape[1] + 1)
    if out is None:
        out = np.empty(shape, np.float32)
    elif out.shape != shape or out.dtype != np.float32:
        raise ValueError(f"out must be a float32 array of shape {shape}, got {out.dtype} {out.shape}")
    kernels = load_numba_kernels("weather.fog_kernels") if fast else None
    if kernels is None:
        t = gaussian_transmittance(m, camera_center, beta, offset_m=offset_m)
        with np.errstate(invalid="ignore"):  # Inf * 0 on a non-finite Gaussian: NaN, culled downstream
            np.multiply(c, t[:, None], out=out[:, :-1])
        out[:, -1] = t
        return out
    center = np.asarray(camera_center, np.float32).reshape(3)
    kernels.transmitted_channels_kernel(
        np.ascontiguousarray(m), np.ascontiguousarray(c), center, np.float32(-beta), np.float32(offset_m), out
    )
    return out


def background_transmittance(beta: float) -> float:
    """Transmittance of the background (sky) at infinite distance: 1 for beta = 0, else 0."""
    _check_beta(beta)
    return 1.0 if beta == 0 else 0.0


def compose_exact(
    sum_color_t: np.ndarray,
    sum_t: np.ndarray,
    alpha: np.ndarray,
    *,
    beta: float,
    fog_color: np.ndarray,
    background: np.ndarray | None = None,
    fast: bool = True,
) -> np.ndarray:
    """The exact per-layer fog from the rasterized sums (see the module docstring).

    Parameters
    ----------
    sum_color_t : ndarray [H, W, 3]
        sum_i w_i c_i t_i, rasterized with no background.
    sum_t : ndarray [H, W]
        sum_i w_i t_i.
    alpha : ndarray [H, W]
        A = sum_i w_i.
    beta : float
        Extinction coefficient (m^-1); only decides the sky's transmittance (0 if beta > 0).
    fog_color : ndarray [3]
        RGB in [0, 1].
    background : ndarray [3] or [H, W, 3], optional
        Background (sky) color behind everything; black when omitted.
    fast : bool
        The numba kernel when available (one pass; a [3] background only); else numpy.

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    c_fog = _check_color(fog_color, "fog_color")
    a = np.asarray(alpha, np.float32)[..., None]
    st = np.asarray(sum_t, np.float32)[..., None]
    if sum_color_t.shape[:-1] != alpha.shape or sum_t.shape != alpha.shape:
        raise ValueError(
            f"sum_color_t {sum_color_t.shape}, sum_t {sum_t.shape} and alpha {alpha.shape} must share [H, W]"
        )
    t_bg = background_transmittance(beta)
    bg = np.zeros(3, np.float32) if background is None else _check_color(background, "background")
    sky = bg * t_bg + c_fog * (1.0 - t_bg)
    kernels = load_numba_kernels("weather.fog_kernels") if fast and sky.shape == (3,) else None
    if kernels is not None:
        out = np.empty(sum_color_t.shape, np.float32)
        kernels.compose_exact_kernel(
            np.asarray(sum_color_t, np.float32), st[..., 0], a[..., 0], c_fog, sky.astype(np.float32), out
        )
        return out
    # The fog term A - sum w t is >= 0 in exact arithmetic; clamp float32 round-off. In place:
    # this runs on every frame.
    fog_weight = np.subtract(a, st)
    np.maximum(fog_weight, 0.0, out=fog_weight)
    out = fog_weight * c_fog
    out += sum_color_t
    out += (1.0 - a) * sky
    return out.astype(np.float32, copy=False)


def ray_distance(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Distance along each pixel's ray for a camera-z depth map: l = z sqrt(1 + x_n^2 + y_n^2).

    Parameters
    ----------
    depth : ndarray [H, W]
        Camera-z depth (m).
    K : ndarray [3, 3]
        Intrinsics; pixel (i, j) has its center at (i + 0.5, j + 0.5).

    Returns
    -------
    ndarray [H, W] float32
        Metres; Inf where the ray length exceeds float32.

    Raises
    ------
    ValueError
        If ``depth`` is not [H, W] or ``K`` is not finite with positive focal lengths.
    """
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must have shape [H, W], got {depth.shape}")
    h, w = depth.shape
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K must be finite [3, 3] intrinsics with positive focal lengths, got {K.tolist()}")
    # A ray too long for float32 (extreme intrinsics or depths) comes out as Inf, not as a warning.
    with np.errstate(over="ignore"):
        xn = ((np.arange(w) + 0.5 - K[0, 2]) / K[0, 0]).astype(np.float32)
        yn = ((np.arange(h) + 0.5 - K[1, 2]) / K[1, 1]).astype(np.float32)
        stretch = np.sqrt(1.0 + xn[None, :] ** 2 + yn[:, None] ** 2)
        return depth * stretch


def fog_postprocess(
    color: np.ndarray,
    depth: np.ndarray,
    alpha: np.ndarray,
    K: np.ndarray,
    *,
    beta: float,
    fog_color: np.ndarray,
    background: np.ndarray | None = None,
    offset_m: float = 0.0,
) -> np.ndarray:
    """The paper's fog: one transmittance per pixel from the rendered expected depth.

    t = exp(-beta max(l - offset_m, 0)) with l = :func:`ray_distance` of the depth map; the
    surface part of the pixel becomes t C_s + (1 - t) c_fog A and the background part (weight
    1 - A) is at infinity. Where A = 1 this is exactly the paper's C_fog = t C + (1 - t) c_fog; it
    differs from :func:`compose_exact` where layers at different distances share a pixel.

    Parameters
    ----------
    color : ndarray [H, W, 3]
        Rendered colors, background composited in (sum_i w_i c_i + (1 - A) bg).
    depth : ndarray [H, W]
        Expected camera-z depth normalised by alpha (m).
    alpha : ndarray [H, W]
        Accumulated opacity A.
    K : ndarray [3, 3]
        Intrinsics of the render.
    beta : float
        Extinction coefficient (m^-1).
    fog_color : ndarray [3]
    background : ndarray [3] or [H, W, 3], optional
        The background that was composited into ``color`` (black when omitted).
    offset_m : float
        Distance before which there is no attenuation (m).

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    _check_beta(beta)
    _check_offset(offset_m)
    c_fog = _check_color(fog_color, "fog_color")
    a = np.asarray(alpha, np.float32)[..., None]
    if color.shape[:-1] != alpha.shape or depth.shape != alpha.shape:
        raise ValueError(f"color {color.shape}, depth {depth.shape} and alpha {alpha.shape} must share [H, W]")
    bg = np.zeros(3, np.float32) if background is None else _check_color(background, "background")
    # Non-finite depth only occurs where nothing was drawn (its weight A is 0 there); a finite depth
    # whose ray length overflows float32 is as far as float32 goes (t = 0 in any fog).
    l_ray = np.nan_to_num(ray_distance(depth, K), nan=0.0, posinf=_F32_MAX, neginf=0.0)
    with np.errstate(over="ignore"):  # beta l beyond float32 is -Inf: t = 0
        t = np.exp(-beta * np.maximum(l_ray - offset_m, 0.0))[..., None]
    surface = np.asarray(color, np.float32) - (1.0 - a) * bg
    t_bg = background_transmittance(beta)
    out = t * surface + c_fog * a * (1.0 - t) + (1.0 - a) * (bg * t_bg + c_fog * (1.0 - t_bg))
    return out.astype(np.float32, copy=False)
