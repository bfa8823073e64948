"""Rain and snow as Gaussian particles in a camera-following volume (docs/design.md §7).

A raindrop is one Gaussian stretched along its velocity relative to the camera (motion blur over
the exposure); a snowflake is three equal elongated Gaussians at 60 degrees sharing one center
(WeatherCity's flake). Velocities are physical: fall speed from the drop diameter plus wind (plus a
smooth seeded flutter for snow), with gravity along ``-up`` of the scene.

Particles live in a box that follows the camera (horizontal half-size ``radius_m`` in the plane
orthogonal to ``up``, ``below_m``/``above_m`` along it) and wraps periodically: a particle leaving
one face re-enters through the opposite one, and on every vertical wrap its horizontal position is
re-drawn from a counter-based hash of (seed, particle, wrap count). Positions are closed-form
functions of time, so frame t is a pure function of (seed, t, parameters, camera center): frame
17 rendered alone equals frame 17 of a sequence.

Physical presets derive the density and sizes from a drop-size distribution
N(D) = N0 exp(-Lambda D) (Marshall-Palmer for rain, Gunn-Marshall for snow, D in mm). Drops of at
least ``min_diameter_mm`` in the box are simulated; above ``max_particles`` each particle stands
for k = physical / simulated drops and its opacity becomes 1 - (1 - a)^k (the optical depth of k
independent drops; equal to k a for faint drops). Every simulated drop or flake draws its own
diameter from the distribution (inverse CDF of a seeded stream), and its size and fall speed follow
from it. Rain and snow beyond the box are haze, with the extinction coefficient of the rate: see
:func:`precipitation_extinction` (empirical relations by default, :func:`extinction_coefficient`
for the geometric-optics form).

All lengths are metres, times seconds, diameters millimetres; colors float RGB in [0, 1]
(the images' values, as everywhere in wcbench).
Quaternions are (w, x, y, z).

The numpy code here is the reference; :mod:`.particle_kernels` computes the same frame in two
numba passes (``fast=True``, the default when numba imports) and the tests compare the two.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from wcbench.reference_model._numba_backend import load_numba_kernels
from wcbench.reference_model.transforms import apply_linear, quat_multiply, quat_to_matrix

__all__ = [
    "ParticleField",
    "ParticleGaussians",
    "ParticleSpec",
    "Wind",
    "extinction_coefficient",
    "haze_density",
    "horizontal_basis",
    "number_density",
    "particle_dilation_compensation",
    "precipitation_extinction",
    "quat_from_axis_to",
    "rain_extinction",
    "rain_fall_speed",
    "sample_diameters",
    "size_distribution",
    "snow_extinction",
    "snow_fall_speed",
]

KINDS = ("rain", "snow")
_KIND_CODE = {"rain": 1, "snow": 2}
_TURB_MODES = 3  # sinusoids per axis of the snow flutter
_TURB_FREQ_HZ = (0.2, 1.0)  # flutter frequencies of falling aggregates
_SHORT_OVER_LONG = 0.625  # the paper flake's axis ratio, 0.004 / 0.0064
_MAX_SINGLE_OPACITY = 0.99  # the rasterizer's clamp; (1 - a)^k needs a < 1
#: Largest magnitude of a position, speed or length written to the float32 Gaussians (an eighth of
#: float32's range: sums of a few such terms stay finite; docs/design.md §9).
_MAX_F32_MAGNITUDE = 4e37
#: Largest |omega t| of the flutter and spin phases: the fast path's sine is exact for |x| < 1e7.
_MAX_PHASE_RAD = 1e6
#: Vertical wrap counts are exact integers up to 2^52 box heights (float64), then int64.
_MAX_WRAPS = 2.0**52
#: Shortest standard deviation of a particle Gaussian (m): normal in float32, and a streak's
#: length stays > 0 (its opacity is scaled by width / length).
_MIN_SIGMA_M = 1e-30
#: (N0, exponent of R in N0, Lambda coefficient, exponent of R in Lambda): Marshall-Palmer (1948)
#: for rain, Gunn-Marshall (1958) for snow (melted diameters).
_DSD_DEFAULTS = {"rain": (8000.0, 0.0, 4.1, -0.21), "snow": (3800.0, -0.87, 2.55, -0.48)}
#: Rain extinction beta = a R^b km^-1 with R in mm/h (Weber et al. 2015): (a, b).
RAIN_EXTINCTION_KM = (0.312, 0.67)
#: Snow aggregates of Rasmussen et al. (1999): (C3 = flake density x diameter in g cm^-2, fall
#: speed in m/s). Dry aggregates fall at ~1 m/s, wet or rimed ones at ~2 m/s.
SNOW_AGGREGATES = {"dry": (0.017, 1.0), "wet": (0.072, 2.0)}
#: Haze models per kind; the first is the default.
HAZE_MODELS = {"rain": ("weber2015", "geometric"), "snow": ("rasmussen1999_dry", "rasmussen1999_wet", "geometric")}


# --------------------------------------------------------------------------------------------
# Physics of the drop population


def size_distribution(kind: str, rate_mm_h: float, spec: ParticleSpec | None = None) -> tuple[float, float]:
    """Exponential drop-size distribution N(D) = N0 exp(-Lambda D) for a precipitation rate.

    Parameters
    ----------
    kind : {"rain", "snow"}
        Rain uses Marshall-Palmer (N0 = 8000 m^-3 mm^-1, Lambda = 4.1 R^-0.21 mm^-1); snow uses
        Gunn-Marshall on melted diameters (N0 = 3800 R^-0.87, Lambda = 2.55 R^-0.48).
    rate_mm_h : float
        Liquid-water precipitation rate R (mm/h), >= 0.
    spec : ParticleSpec, optional
        Takes the coefficients from ``spec`` instead of the defaults above.

    Returns
    -------
    n0 : float
        Intercept (m^-3 mm^-1); 0 when the rate is 0.
    lam : float
        Slope Lambda (mm^-1); ``inf`` when the rate is 0.

    Raises
    ------
    ValueError
        If ``kind`` is unknown or ``rate_mm_h`` is negative or not finite.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if not math.isfinite(rate_mm_h) or rate_mm_h < 0:
        raise ValueError(f"rate_mm_h must be a finite rate >= 0 mm/h, got {rate_mm_h}")
    a0, b0, a1, b1 = (
        _DSD_DEFAULTS[kind] if spec is None else (spec.dsd_n0, spec.dsd_n0_b, spec.dsd_lambda_a, spec.dsd_lambda_b)
    )
    if rate_mm_h == 0:
        return 0.0, math.inf
    try:
        n0, lam = float(a0 * rate_mm_h**b0), float(a1 * rate_mm_h**b1)
    except OverflowError:
        n0 = lam = math.inf
    if not (0 <= n0 < math.inf and 0 < lam < math.inf):
        raise ValueError(f"the {kind} size distribution at {rate_mm_h} mm/h is not representable: N0 = {n0}, "
                         f"Lambda = {lam} (coefficients {a0}, {b0}, {a1}, {b1})")
    return n0, lam


def number_density(n0: float, lam: float, d_min_mm: float, d_max_mm: float = math.inf) -> float:
    """Drops per cubic metre with diameter in [d_min, d_max] for N(D) = N0 exp(-Lambda D).

    Parameters
    ----------
    n0 : float
        m^-3 mm^-1.
    lam : float
        mm^-1 (``inf`` gives 0).
    d_min_mm, d_max_mm : float
        Diameter range (mm).

    Returns
    -------
    float
        m^-3.
    """
    if n0 <= 0 or not math.isfinite(lam) or d_max_mm <= d_min_mm:
        return 0.0
    upper = 0.0 if math.isinf(d_max_mm) else math.exp(-lam * d_max_mm)
    return float(n0 / lam * (math.exp(-lam * d_min_mm) - upper))


def sample_diameters(u: np.ndarray, lam: float, d_min_mm: float, d_max_mm: float) -> np.ndarray:
    """Inverse-CDF sampling of the exponential distribution truncated to [d_min, d_max].

    Parameters
    ----------
    u : ndarray [N]
        Uniform numbers in [0, 1).
    lam : float
        Slope (mm^-1), > 0.
    d_min_mm, d_max_mm : float
        Truncation (mm).

    Returns
    -------
    ndarray [N] float64
        Diameters (mm).
    """
    span = -math.expm1(-lam * (d_max_mm - d_min_mm))  # CDF mass inside the range, precise for small lam
    return d_min_mm - np.log1p(-np.asarray(u, np.float64) * span) / lam


def rain_fall_speed(d_mm: np.ndarray | float) -> np.ndarray:
    """Terminal fall speed of raindrops, v(D) = 9.65 - 10.3 exp(-0.6 D) m/s (Atlas et al. 1973).

    Parameters
    ----------
    d_mm : ndarray [N] or float
        Equivalent diameter (mm).

    Returns
    -------
    ndarray [N] float64
        m/s, clipped at 0 (the fit goes negative below 0.1 mm).
    """
    return np.maximum(9.65 - 10.3 * np.exp(-0.6 * np.asarray(d_mm, np.float64)), 0.0)


def snow_fall_speed(d_mm: np.ndarray | float) -> np.ndarray:
    """Fall speed of snow aggregates, v = 0.8 D^0.16 m/s (Locatelli & Hobbs 1974), in [0.5, 1.5].

    Parameters
    ----------
    d_mm : ndarray [N] or float
        Flake extent (mm).

    Returns
    -------
    ndarray [N] float64
        m/s.
    """
    return np.clip(0.8 * np.power(np.maximum(np.asarray(d_mm, np.float64), 1e-6), 0.16), 0.5, 1.5)


def extinction_coefficient(n0: float, lam: float, *, size_ratio: float = 1.0) -> float:
    """Optical extinction coefficient of an exponential drop population (geometric optics).

    beta = integral Q_ext (pi/4) (r D)^2 N(D) dD with Q_ext = 2 (large-particle limit) gives
    beta = pi r^2 N0 / Lambda^3 (with the mm units converted). Heavy rain (25 mm/h) gives
    2.8e-3 m^-1, a visibility 2.996 / beta of about 1 km.

    Parameters
    ----------
    n0 : float
        m^-3 mm^-1.
    lam : float
        mm^-1 (``inf`` gives 0).
    size_ratio : float
        Optical extent / distribution diameter (snow: flake / melted diameter).

    Returns
    -------
    float
        beta (m^-1).
    """
    if n0 <= 0 or not math.isfinite(lam):
        return 0.0
    # Products and quotients, not powers: a power that overflows raises instead of giving Inf.
    return float(math.pi * size_ratio * size_ratio * n0 / lam / lam / lam * 1e-6)  # mm^2 -> m^2


def _check_rate(rate_mm_h: float) -> None:
    if not (math.isfinite(rate_mm_h) and rate_mm_h >= 0):
        raise ValueError(f"rate_mm_h must be a finite rate >= 0 mm/h, got {rate_mm_h}")


def rain_extinction(rate_mm_h: float) -> float:
    """Extinction coefficient of rain from its rate: beta = 0.312 R^0.67 km^-1.

    The relation is the one of Weber, Jolivet, Gilet & Ghazanfarpour (2015), "A multiscale model for
    rain rendering in real-time", Computers & Graphics 50, 61-70 (doi:10.1016/j.cag.2015.04.007),
    also used by Halder, Lalonde & de Charette (2019, "Physics-based rendering for improving
    robustness to rain"): an empirical extinction coefficient in km^-1 for R in mm/h. The
    geometric-optics extinction of the Marshall-Palmer population, pi N0 / Lambda^3 =
    0.365 R^0.63 km^-1 (:func:`extinction_coefficient`, ``haze_model="geometric"``), is 3-13 %
    higher between 25 and 2.5 mm/h.

    Parameters
    ----------
    rate_mm_h : float
        Rain rate R (mm/h), finite and >= 0.

    Returns
    -------
    float
        beta (m^-1): 5.8e-4 at 2.5 mm/h, 1.2e-3 at 7.6 mm/h, 2.7e-3 at 25 mm/h (visibilities
        2.996 / beta of 5.2, 2.5 and 1.1 km).

    Raises
    ------
    ValueError
        If ``rate_mm_h`` is negative or not finite.
    """
    _check_rate(rate_mm_h)
    a, b = RAIN_EXTINCTION_KM
    return float(a * rate_mm_h**b * 1e-3)  # km^-1 -> m^-1; b < 1, so no finite rate overflows


def snow_extinction(rate_mm_h: float, *, aggregates: str = "dry") -> float:
    """Extinction coefficient of snowfall from its liquid-equivalent rate (Rasmussen et al. 1999).

    Rasmussen, Vivekanandan, Cole, Myers & Masters (1999), "The estimation of snowfall rate using
    visibility", J. Appl. Meteor. 38, 1542-1563, derive for aggregates whose density falls as
    rho_s = C3 / D (D the flake's maximum dimension) and which fall at one speed v_t, with the
    large-particle extinction efficiency 2: beta = (pi / 2) int D^2 N(D) dD and
    S = (pi C3 v_t / (6 rho_w)) int D^2 N(D) dD, so

        beta = 3 rho_w S / (C3 v_t),

    whatever the size distribution (they write it S = 1.3 C3 v_t / Vis with Koschmieder's
    Vis = 3.912 / beta). Dry aggregates: C3 = 0.017 g cm^-2, v_t = 1 m/s, 4.9 km^-1 per mm/h; wet
    or rimed: C3 = 0.072 g cm^-2, v_t = 2 m/s, 0.58 km^-1 per mm/h (:data:`SNOW_AGGREGATES`). The
    two are 8.5x apart; Rasmussen et al. observed visibilities a factor 3-10 apart for one rate.
    The form is re-derived above; the constants are as a secondary summary of the paper quotes
    them, and give the visibilities it reports at 2 mm/h (0.3 km dry, 2.6 km wet) as 2.996 / beta.

    Parameters
    ----------
    rate_mm_h : float
        Liquid-equivalent snowfall rate S (mm/h), finite and >= 0.
    aggregates : {"dry", "wet"}
        Which aggregates' constants to use.

    Returns
    -------
    float
        beta (m^-1): for dry snow 2.5e-3 at 0.5 mm/h and 1.2e-2 at 2.5 mm/h (visibilities
        2.996 / beta of 1.2 km and 245 m).

    Raises
    ------
    ValueError
        If ``rate_mm_h`` is negative or not finite, or ``aggregates`` is unknown.
    """
    _check_rate(rate_mm_h)
    if aggregates not in SNOW_AGGREGATES:
        raise ValueError(f"aggregates must be one of {sorted(SNOW_AGGREGATES)}, got {aggregates!r}")
    c3_g_cm2, v_t = SNOW_AGGREGATES[aggregates]
    rate_m_s = rate_mm_h * (1e-3 / 3600.0)  # liquid water
    c3_m = c3_g_cm2 * 1e-2  # g cm^-2 over rho_w = 1 g cm^-3: a length (cm -> m)
    return float(3.0 * rate_m_s / (c3_m * v_t))


def precipitation_extinction(kind: str, rate_mm_h: float, *, model: str | None = None,
                             spec: ParticleSpec | None = None) -> float:
    """Extinction coefficient (m^-1) of rain or snow at a rate, by one of :data:`HAZE_MODELS`.

    Parameters
    ----------
    kind : {"rain", "snow"}
    rate_mm_h : float
        Rain or liquid-equivalent snowfall rate (mm/h), finite and >= 0.
    model : str, optional
        ``"weber2015"`` (rain, :func:`rain_extinction`), ``"rasmussen1999_dry"`` or
        ``"rasmussen1999_wet"`` (snow, :func:`snow_extinction`), or ``"geometric"`` (either kind:
        :func:`extinction_coefficient` of the size distribution, with the flake ratio for snow).
        Default: the kind's first model (the empirical relation).
    spec : ParticleSpec, optional
        Distribution coefficients and flake ratio for ``"geometric"`` (default: Marshall-Palmer,
        Gunn-Marshall with a flake 4x its melted diameter).

    Returns
    -------
    float
        beta (m^-1), 0 at a rate of 0.

    Raises
    ------
    ValueError
        If ``kind`` or ``model`` is unknown, or the rate is negative or not finite.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    model = HAZE_MODELS[kind][0] if model is None else model
    if model not in HAZE_MODELS[kind]:
        raise ValueError(f"haze_model for {kind} must be one of {HAZE_MODELS[kind]}, got {model!r}")
    _check_rate(rate_mm_h)
    if model == "weber2015":
        return rain_extinction(rate_mm_h)
    if model.startswith("rasmussen1999_"):
        return snow_extinction(rate_mm_h, aggregates=model.removeprefix("rasmussen1999_"))
    n0, lam = size_distribution(kind, rate_mm_h, spec)
    ratio = 1.0 if kind == "rain" else (spec.flake_ratio if spec is not None else 4.0)
    return extinction_coefficient(n0, lam, size_ratio=ratio)


# --------------------------------------------------------------------------------------------
# Geometry helpers


def horizontal_basis(up: np.ndarray, heading: np.ndarray | None = None) -> np.ndarray:
    """Right-handed orthonormal basis (e1, e2, up) with e1, e2 horizontal.

    Parameters
    ----------
    up : ndarray [3]
        Up vector of the world (normalised here).
    heading : ndarray [3], optional
        Direction e1 should follow (projected onto the horizontal plane), e.g. the first
        camera's viewing direction; defaults to the world axis least aligned with ``up``.

    Returns
    -------
    ndarray [3, 3] float64
        Rows e1, e2 = up x e1, up.

    Raises
    ------
    ValueError
        If ``up`` is not a finite non-zero 3-vector.
    """
    u = np.asarray(up, np.float64).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u / max(np.abs(u).max(), 1e-300)) < 1e-9:
        raise ValueError(f"up must be a finite non-zero 3-vector, got {up!r}")
    u = u / np.abs(u).max()  # first to ~1: the norm of a huge vector would overflow
    u = u / np.linalg.norm(u)
    candidates = [] if heading is None else [np.asarray(heading, np.float64).reshape(3)]
    candidates.append(np.eye(3)[int(np.argmin(np.abs(u)))])
    for h in candidates:
        e1 = h - (h @ u) * u
        if np.all(np.isfinite(e1)) and np.linalg.norm(e1) > 1e-6:
            e1 = e1 / np.linalg.norm(e1)
            return np.stack([e1, np.cross(u, e1), u])
    raise AssertionError("unreachable: the least aligned axis is never parallel to up")


def quat_from_axis_to(v: np.ndarray) -> np.ndarray:
    """Quaternions [N, 4] rotating the local z axis onto the line of each ``v`` [N, 3].

    The Gaussian is symmetric, so z is mapped onto +v or -v, whichever needs the smaller turn;
    this avoids the singular 180-degree case for rain falling along -z.
    """
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    d = np.where(n > 1e-12, v / np.maximum(n, 1e-300), np.array([0.0, 0.0, 1.0]))
    d = d * np.where(d[..., 2:3] < 0, -1.0, 1.0)
    # Half-way quaternion between z and d: (1 + z.d, z x d), with z.d >= 0 so never degenerate.
    q = np.stack([1.0 + d[..., 2], -d[..., 1], d[..., 0], np.zeros_like(d[..., 0])], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _quat_about_z(angle: np.ndarray) -> np.ndarray:
    half = 0.5 * np.asarray(angle, np.float64)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], -1)


def _random_quaternions(u: np.ndarray) -> np.ndarray:
    """Uniformly random rotations from u [N, 3] in [0, 1) (Shoemake 1992)."""
    a, b, c = u[:, 0], 2 * np.pi * u[:, 1], 2 * np.pi * u[:, 2]
    r1, r2 = np.sqrt(1 - a), np.sqrt(a)
    return np.stack([r2 * np.cos(c), r1 * np.sin(b), r1 * np.cos(b), r2 * np.sin(c)], -1)


def _hash_uniform(seed: int, index: np.ndarray, counter: np.ndarray, stream: int) -> np.ndarray:
    """Counter-based uniform numbers in [0, 1): splitmix64 of (seed, index, counter, stream).

    Used for the horizontal re-draw on wrap, so that the value for wrap n of particle i never
    depends on which frames were rendered before.
    """
    with np.errstate(over="ignore"):
        x = np.uint64(seed & 0xFFFFFFFFFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15)
        x = _splitmix64(x ^ np.asarray(index).astype(np.uint64))
        x = _splitmix64(x ^ np.asarray(counter).astype(np.int64).astype(np.uint64))
        x = _splitmix64(x ^ np.uint64(stream))
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        x = np.asarray(x, np.uint64) + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))


def particle_dilation_compensation(
    means: np.ndarray,
    quats: np.ndarray,
    scales: np.ndarray,
    viewmat: np.ndarray,
    K: np.ndarray,
    *,
    eps2d: float,
) -> np.ndarray:
    """Opacity factor sqrt(det Sigma / det(Sigma + eps I)) per Gaussian (gsplat "antialiased").

    The rasterizer dilates every 2D covariance by ``eps2d`` px^2; a raindrop a tenth of a pixel
    wide would grow several-fold in coverage, and by a resolution-dependent amount. Scaling its
    opacity by this factor keeps its integrated coverage.

    Parameters
    ----------
    means : ndarray [M, 3]
        World (m).
    quats : ndarray [M, 4]
        wxyz.
    scales : ndarray [M, 3]
        Standard deviations (m).
    viewmat : ndarray [4, 4]
        World-to-camera (OpenCV axes).
    K : ndarray [3, 3]
        Intrinsics.
    eps2d : float
        The rasterizer's dilation (px^2).

    Returns
    -------
    ndarray [M] float32
        In (0, 1]; 1 where the projection is degenerate (such Gaussians are culled anyway).
    """
    if len(means) == 0:
        return np.zeros(0, np.float32)
    W = np.asarray(viewmat, np.float64)
    cam = apply_linear(np.asarray(means, np.float64), W[:3, :3].T) + W[:3, 3]
    x, y, z = cam[:, 0], cam[:, 1], np.maximum(cam[:, 2], 1e-6)
    fx, fy = K[0, 0], K[1, 1]
    J = np.zeros((len(cam), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * x / z**2
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * y / z**2
    M = quat_to_matrix(quats) * np.asarray(scales, np.float64)[:, None, :]
    T = J @ W[:3, :3] @ M
    c00 = np.einsum("ij,ij->i", T[:, 0], T[:, 0])
    c11 = np.einsum("ij,ij->i", T[:, 1], T[:, 1])
    # det(T T^T) as the sum of the squared 2x2 minors of T (Cauchy-Binet), not c00 c11 - c01^2:
    # for a long thin streak that difference is rounding noise of either sign (docs/design.md §9).
    det = ((T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0]) ** 2
           + (T[:, 0, 0] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 0]) ** 2
           + (T[:, 0, 1] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 1]) ** 2)
    det_d = det + eps2d * (c00 + c11) + eps2d * eps2d
    factor = np.sqrt(det / np.maximum(det_d, 1e-30))
    return np.where(np.isfinite(factor), np.clip(factor, 0.0, 1.0), 1.0).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Parameters


@dataclass(frozen=True)
class Wind:
    """A uniform wind.

    Attributes
    ----------
    speed_m_s : float
        Magnitude (m/s), >= 0.
    tilt_deg : float
        Angle of the wind vector below the horizontal plane (degrees, in [-90, 90]); positive
        blows downward (a descending gust), negative upward.
    azimuth_deg : float
        Horizontal direction the wind blows *toward*, counter-clockwise seen from above, from the
        basis axis e1 (the first camera's horizontal viewing direction in a rendered scene).
    """

    speed_m_s: float = 0.0
    tilt_deg: float = 0.0
    azimuth_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("speed_m_s", "tilt_deg", "azimuth_deg"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"wind {name} must be finite, got {getattr(self, name)}")
        if not 0 <= self.speed_m_s <= _MAX_F32_MAGNITUDE:
            raise ValueError(f"wind speed_m_s must be in [0, {_MAX_F32_MAGNITUDE:g}], got {self.speed_m_s}")
        if not -90.0 <= self.tilt_deg <= 90.0:
            raise ValueError(f"wind tilt_deg must be in [-90, 90], got {self.tilt_deg}")

    def vector(self, basis: np.ndarray) -> np.ndarray:
        """[3] wind velocity in world coordinates (m/s) for a :func:`horizontal_basis`."""
        tilt, az = math.radians(self.tilt_deg), math.radians(self.azimuth_deg)
        e1, e2, up = np.asarray(basis, np.float64)
        horizontal = math.cos(az) * e1 + math.sin(az) * e2
        return self.speed_m_s * (math.cos(tilt) * horizontal - math.sin(tilt) * up)


@dataclass(frozen=True)
class ParticleSpec:
    """Everything that defines a rain or snow particle population (see ``presets.toml``).

    Either ``rate_mm_h`` (physical: density, sizes and speeds from the size distribution) or
    ``count`` (fixed count with fixed ``scale_m``/``opacity``, the paper's settings) is used;
    ``count`` wins when both are set. ``haze_model`` picks the extinction of the haze beyond the
    box (:data:`HAZE_MODELS`; ``None`` is the kind's empirical relation).
    """

    kind: str = "rain"
    rate_mm_h: float | None = None
    count: int | None = None
    max_particles: int = 40000
    dsd_n0: float = 8000.0
    dsd_n0_b: float = 0.0
    dsd_lambda_a: float = 4.1
    dsd_lambda_b: float = -0.21
    min_diameter_mm: float = 0.5
    max_diameter_mm: float = 6.0
    flake_ratio: float = 1.0
    radius_m: float = 10.0
    below_m: float = 3.0
    above_m: float = 5.0
    fade_m: float = 1.0
    min_distance_m: float = 0.3
    color: tuple[float, float, float] = (0.75, 0.76, 0.8)
    opacity: float = 0.6
    scale_m: tuple[float, float, float] | None = None
    fall_speed_m_s: float | None = None
    stretch_with_exposure: bool = True
    turbulence_m_s: float = 0.0
    spin_rad_s: float = 0.0
    haze: bool = True
    haze_color: tuple[float, float, float] = (0.6, 0.62, 0.66)
    haze_model: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.haze_model is None:  # the kind's empirical relation
            object.__setattr__(self, "haze_model", HAZE_MODELS[self.kind][0])
        if self.haze_model not in HAZE_MODELS[self.kind]:
            raise ValueError(f"haze_model for {self.kind} must be one of {HAZE_MODELS[self.kind]}, "
                             f"got {self.haze_model!r}")
        if self.rate_mm_h is None and self.count is None:
            raise ValueError("a particle spec needs rate_mm_h (physical) or count (fixed)")
        if self.rate_mm_h is not None and (not math.isfinite(self.rate_mm_h) or self.rate_mm_h < 0):
            raise ValueError(f"rate_mm_h must be a finite rate >= 0 mm/h, got {self.rate_mm_h}")
        if self.count is not None and self.count < 0:
            raise ValueError(f"count must be >= 0, got {self.count}")
        if self.max_particles < 0:
            raise ValueError(f"max_particles must be >= 0, got {self.max_particles}")
        # Every number finite (NaN fails every comparison below): docs/design.md §9.
        for name in ("min_diameter_mm", "max_diameter_mm", "flake_ratio", "dsd_n0", "dsd_lambda_a"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)}")
        # Lengths of the box are float32 positions and are squared in float64.
        for name in ("radius_m", "below_m", "above_m"):
            if not 0 < getattr(self, name) <= _MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in (0, {_MAX_F32_MAGNITUDE:g}] m, got {getattr(self, name)}")
        for name in ("fade_m", "min_distance_m"):
            if not 0 <= getattr(self, name) <= _MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in [0, {_MAX_F32_MAGNITUDE:g}] m, got {getattr(self, name)}")
        for name in ("turbulence_m_s", "spin_rad_s"):
            if not 0 <= getattr(self, name) <= _MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in [0, {_MAX_F32_MAGNITUDE:g}], got {getattr(self, name)}")
        for name in ("dsd_n0_b", "dsd_lambda_b"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if not 0.0 <= self.opacity <= 1.0:
            raise ValueError(f"opacity must be in [0, 1], got {self.opacity}")
        if not self.min_diameter_mm < self.max_diameter_mm:
            raise ValueError(
                f"need 0 < min_diameter_mm < max_diameter_mm, got {self.min_diameter_mm}, {self.max_diameter_mm}"
            )
        for name in ("color", "haze_color"):
            rgb = getattr(self, name)
            if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
                raise ValueError(f"{name} must be RGB in [0, 1], got {rgb}")
        if self.scale_m is not None and (len(self.scale_m) != 3 or not all(_MIN_SIGMA_M <= v <= _MAX_F32_MAGNITUDE
                                                                          for v in self.scale_m)):
            raise ValueError(f"scale_m must be three lengths in [{_MIN_SIGMA_M:g}, {_MAX_F32_MAGNITUDE:g}] m "
                             f"(float32), got {self.scale_m}")
        if self.count is None:  # sizes from the drop-size distribution: sigma = D / 4 (times the flake ratio)
            ratio = self.flake_ratio if self.kind == "snow" else 1.0
            short = _SHORT_OVER_LONG if self.kind == "snow" else 1.0
            lo = self.min_diameter_mm * 1e-3 / 4.0 * ratio * short
            hi = self.max_diameter_mm * 1e-3 / 4.0 * ratio
            if not (_MIN_SIGMA_M <= lo and hi <= _MAX_F32_MAGNITUDE):
                raise ValueError(f"diameters in [{self.min_diameter_mm}, {self.max_diameter_mm}] mm give particle "
                                 f"sizes in [{lo:.3g}, {hi:.3g}] m, outside [{_MIN_SIGMA_M:g}, "
                                 f"{_MAX_F32_MAGNITUDE:g}] m (float32)")
        if self.count is not None and (self.scale_m is None or self.fall_speed_m_s is None):
            raise ValueError("a fixed-count spec needs scale_m and fall_speed_m_s")
        if self.fall_speed_m_s is not None and not abs(self.fall_speed_m_s) <= _MAX_F32_MAGNITUDE:
            raise ValueError(f"fall_speed_m_s must be finite, within +-{_MAX_F32_MAGNITUDE:g} m/s, "
                             f"got {self.fall_speed_m_s}")

    @classmethod
    def from_mapping(cls, kind: str, values: Mapping[str, Any]) -> ParticleSpec:
        """Build a spec from a preset table; unknown keys raise ``ValueError`` naming them.

        ``drop_opacity`` (rain) and ``flake_opacity`` (snow) map to ``opacity`` unless the table
        sets ``opacity`` itself (fixed presets).
        """
        known = {f.name for f in fields(cls)}
        values = dict(values)
        for alias in ("drop_opacity", "flake_opacity"):
            if alias in values:
                v = values.pop(alias)
                values.setdefault("opacity", v)
        values.pop("default_preset", None)
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown {kind} particle settings {unknown}; known: {sorted(known)}")
        for key in ("color", "haze_color", "scale_m"):
            if values.get(key) is not None:
                values[key] = tuple(float(x) for x in values[key])
        if values.get("count") is not None:
            values["count"] = int(values["count"])
        return cls(kind=kind, **{k: v for k, v in values.items() if k != "kind"})

    @property
    def box_size(self) -> np.ndarray:
        """[3] box edge lengths along (e1, e2, up), metres."""
        return np.array([2 * self.radius_m, 2 * self.radius_m, self.below_m + self.above_m])

    @property
    def box_low(self) -> np.ndarray:
        """[3] lower box corner relative to the camera center along (e1, e2, up), metres."""
        return np.array([-self.radius_m, -self.radius_m, -self.below_m])

    @property
    def physical(self) -> bool:
        """Whether sizes and counts come from the drop-size distribution."""
        return self.count is None


@dataclass
class ParticleGaussians:
    """Particles of one frame as Gaussians (float32 numpy arrays).

    Attributes
    ----------
    means : ndarray [M, 3]
        World positions (m).
    quats : ndarray [M, 4]
        Rotations (w, x, y, z), unit.
    scales : ndarray [M, 3]
        Standard deviations along the local axes (m).
    opacities : ndarray [M]
        In [0, 1].
    colors : ndarray [M, 3]
        RGB in [0, 1].
    particle : ndarray [M] int64
        Index of the particle each Gaussian belongs to (a flake has three).
    velocity : ndarray [M, 3]
        World velocity of the particle (m/s).
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray
    particle: np.ndarray
    velocity: np.ndarray

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def subset(self, keep: np.ndarray) -> ParticleGaussians:
        """The Gaussians selected by a boolean mask or index array ``keep``."""
        return ParticleGaussians(
            **{f.name: getattr(self, f.name)[keep] for f in fields(self)}  # type: ignore[arg-type]
        )

    def head(self, k: int) -> ParticleGaussians:
        """Views of the first ``k`` Gaussians (no copy)."""
        return ParticleGaussians(
            **{f.name: getattr(self, f.name)[:k] for f in fields(self)}  # type: ignore[arg-type]
        )

    @staticmethod
    def allocate(n: int) -> ParticleGaussians:
        """Uninitialised buffers for ``n`` Gaussians (see :meth:`ParticleField.gaussians`)."""
        e = np.empty
        return ParticleGaussians(
            e((n, 3), np.float32),
            e((n, 4), np.float32),
            e((n, 3), np.float32),
            e(n, np.float32),
            e((n, 3), np.float32),
            e(n, np.int64),
            e((n, 3), np.float32),
        )

    @staticmethod
    def empty() -> ParticleGaussians:
        """No Gaussians (clear weather, zero rate)."""
        z = np.zeros
        return ParticleGaussians(
            z((0, 3), np.float32),
            z((0, 4), np.float32),
            z((0, 3), np.float32),
            z(0, np.float32),
            z((0, 3), np.float32),
            z(0, np.int64),
            z((0, 3), np.float32),
        )


# --------------------------------------------------------------------------------------------
# The particle field


def haze_density(spec: ParticleSpec) -> float:
    """Extinction coefficient (m^-1) of the rain or snow beyond the particle box, 0 if haze is off.

    From the rate by the spec's ``haze_model`` (:func:`precipitation_extinction`): the empirical
    relation of the kind by default, or geometric optics on the spec's size distribution. A
    function of the spec alone: no particle needs to be drawn for it.
    """
    if not spec.haze or not spec.physical:
        return 0.0
    assert spec.rate_mm_h is not None
    if spec.haze_model == "geometric":
        n0, lam = size_distribution(spec.kind, spec.rate_mm_h, spec)
        ratio = spec.flake_ratio if spec.kind == "snow" else 1.0
        return extinction_coefficient(n0, lam, size_ratio=ratio)
    return precipitation_extinction(spec.kind, spec.rate_mm_h, model=spec.haze_model)


@dataclass
class ParticleField:
    """A seeded population of rain drops or snowflakes; positions are closed-form in time.

    Parameters
    ----------
    spec : ParticleSpec
    wind : Wind
    up : ndarray [3]
        World up vector (gravity is ``-up``).
    heading : ndarray [3], optional
        Reference horizontal direction for the wind azimuth (see :func:`horizontal_basis`).
    seed : int
        Same seed and parameters give the same particles.
    anchor : ndarray [3], optional
        World point the initial box is centred on at t = 0 (default: the origin, which is the
        first camera of a re-based scene). Part of the parameters: keep it fixed for a sequence.
    """

    spec: ParticleSpec
    wind: Wind = field(default_factory=Wind)
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    heading: np.ndarray | None = None
    seed: int = 0
    anchor: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        spec = self.spec
        self.basis = horizontal_basis(self.up, self.heading)
        self.anchor_ = np.zeros(3) if self.anchor is None else np.asarray(self.anchor, np.float64).reshape(3)
        if not np.all(np.abs(self.anchor_) <= _MAX_F32_MAGNITUDE):
            raise ValueError(f"anchor must be a finite position within +-{_MAX_F32_MAGNITUDE:g} m, got {self.anchor!r}")
        volume = math.prod(spec.box_size.tolist())
        if spec.physical:
            assert spec.rate_mm_h is not None
            self.n0, self.lam = size_distribution(spec.kind, spec.rate_mm_h, spec)
            self.density_per_m3 = number_density(self.n0, self.lam, spec.min_diameter_mm, spec.max_diameter_mm)
            self.physical_count = self.density_per_m3 * volume
            if not math.isfinite(self.physical_count):
                raise ValueError(f"{spec.kind} at {spec.rate_mm_h} mm/h in a {volume:.3g} m^3 box has no finite "
                                 f"drop count (density {self.density_per_m3} m^-3)")
            n = int(min(round(self.physical_count), spec.max_particles))
        else:
            assert spec.count is not None
            self.n0, self.lam, self.density_per_m3 = 0.0, math.inf, spec.count / volume
            self.physical_count = float(spec.count)
            n = spec.count
        self.count = n
        # Each simulated particle stands for `represented` physical ones (1 below the cap).
        self.represented = self.physical_count / n if n > 0 else 1.0

        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(self.seed), _KIND_CODE[spec.kind]])))
        self.initial = spec.box_low + rng.random((n, 3)) * spec.box_size  # box coords at t = 0
        if spec.physical:
            self.diameter_mm = sample_diameters(rng.random(n), self.lam, spec.min_diameter_mm, spec.max_diameter_mm)
        else:
            rng.random(n)  # keep the stream aligned between the two modes
            self.diameter_mm = np.zeros(n)
        if spec.fall_speed_m_s is not None:
            fall = np.full(n, float(spec.fall_speed_m_s))
        elif spec.kind == "rain":
            fall = rain_fall_speed(self.diameter_mm)
        else:
            fall = snow_fall_speed(self.diameter_mm * spec.flake_ratio)
        self.fall_speed = fall
        self.wind_vector = self.wind.vector(self.basis)
        # Mean velocity in box coordinates (e1, e2, up) and in world coordinates.
        self.velocity_box = np.zeros((n, 3)) + self.wind_vector @ self.basis.T
        self.velocity_box[:, 2] -= fall
        # Flutter: per axis a sum of sinusoids with RMS velocity turbulence_m_s (half vertically).
        freq = 2 * np.pi * (_TURB_FREQ_HZ[0] + (_TURB_FREQ_HZ[1] - _TURB_FREQ_HZ[0]) * rng.random((n, 3, _TURB_MODES)))
        self.turb_omega = freq
        self.turb_phase = 2 * np.pi * rng.random((n, 3, _TURB_MODES))
        amp_v = spec.turbulence_m_s * math.sqrt(2.0 / _TURB_MODES) * np.array([1.0, 1.0, 0.5])
        self.turb_amp = amp_v[None, :, None] / freq  # displacement amplitude (m)
        # Displacement at t = 0, subtracted so the flutter starts at the drawn position.
        self.turb_offset = (self.turb_amp * np.sin(self.turb_phase)).sum(-1)
        self._speed_max = (
            float(np.sqrt(np.einsum("ij,ij->i", self.velocity_box, self.velocity_box)).max()) if n else 0.0
        )
        # Bounds used by the guards of every frame (_check_frame): the flutter's largest speed and
        # displacement, and the fastest phase of the flutter and spin sines.
        self._flutter_speed = spec.turbulence_m_s * math.sqrt(2.0 * _TURB_MODES) * math.sqrt(2.25)
        self._flutter_reach = float(2.0 * np.abs(self.turb_amp).sum(-1).max()) if n else 0.0
        if not math.isfinite(self.haze_density()):
            raise ValueError(f"the haze of {spec.kind} at {spec.rate_mm_h} mm/h has no finite extinction coefficient")
        speed_bound = self._speed_max + self._flutter_speed
        if not speed_bound <= _MAX_F32_MAGNITUDE:
            raise ValueError(f"particle speeds up to {speed_bound:.3g} m/s (wind, fall and flutter) exceed "
                             f"{_MAX_F32_MAGNITUDE:g} m/s, beyond float32")
        # Flake orientation: random rotation, then spin about its normal (local z).
        self.orientation = _random_quaternions(rng.random((n, 3)))
        self.spin_rate = spec.spin_rad_s * rng.standard_normal(n)
        self._phase_rate = max(float(np.abs(self.spin_rate).max()) if n else 0.0,
                               float(freq.max()) if n and spec.turbulence_m_s > 0 else 0.0)

    def _check_frame(self, t: float, c: np.ndarray) -> None:
        """Refuse a time and camera center the float64 kinematics cannot represent exactly.

        Both paths (numpy and numba) call this, so they accept and refuse the same frames
        (docs/design.md §9): the sines of the flutter and spin need |omega t| <= 1e6 rad (the fast
        sine is exact below 1e7), vertical wrap counts must stay exact integers (at most 2^52 box
        heights of travel from the anchor), and positions must fit float32.

        Raises
        ------
        ValueError
            Naming ``t`` or ``camera_center`` and the bound.
        """
        if not math.isfinite(t):
            raise ValueError(f"t must be finite seconds, got {t}")
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"camera_center must be a finite [3] position, got {c!r}")
        if abs(t) * self._phase_rate > _MAX_PHASE_RAD:
            raise ValueError(f"t = {t} s is too far from the field's time origin: the flutter and spin phases "
                             f"reach {abs(t) * self._phase_rate:.3g} rad, more than {_MAX_PHASE_RAD:g}")
        spec = self.spec
        extent = float(np.abs(spec.box_size).max())
        if not float(np.abs(c).max()) + extent <= _MAX_F32_MAGNITUDE:
            raise ValueError(f"camera_center {c.tolist()} is beyond +-{_MAX_F32_MAGNITUDE:g} m (float32 positions)")
        travel = float(np.linalg.norm(c - self.anchor_)) + self._speed_max * abs(t) + self._flutter_reach + extent
        if not travel <= _MAX_WRAPS * spec.box_size[2]:
            raise ValueError(f"t = {t} s and camera_center put the particles {travel:.3g} m from the field's anchor, "
                             f"more than 2^52 box heights ({_MAX_WRAPS * spec.box_size[2]:.3g} m): wrap counts "
                             "would not be exact")

    # ---- kinematics -----------------------------------------------------------------------

    def _turbulence(self, t: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray | None:
        """[K, 3] flutter displacement since t = 0 in box coordinates, or None without flutter."""
        if self.spec.turbulence_m_s == 0:
            return None
        omega, phase = self.turb_omega[idx], self.turb_phase[idx]
        return (self.turb_amp[idx] * np.sin(omega * t + phase)).sum(-1) - self.turb_offset[idx]

    def _velocity_box(self, t: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        v = self.velocity_box[idx]
        if self.spec.turbulence_m_s == 0:
            return v
        omega = self.turb_omega[idx]
        return v + (self.turb_amp[idx] * omega * np.cos(omega * t + self.turb_phase[idx])).sum(-1)

    def displacement(self, t: float) -> np.ndarray:
        """[N, 3] world displacement of every particle from t = 0 to ``t``, ignoring wraps (m)."""
        d = self.velocity_box * t
        turb = self._turbulence(t)
        if turb is not None:
            d = d + turb
        return apply_linear(d, self.basis)

    def velocity(self, t: float) -> np.ndarray:
        """[N, 3] world velocity of every particle at time ``t`` (m/s)."""
        return apply_linear(self._velocity_box(t), self.basis)

    def initial_positions(self) -> np.ndarray:
        """[N, 3] world positions at t = 0 (before any wrap), metres."""
        return self.anchor_ + apply_linear(self.initial, self.basis)

    def positions(self, t: float, camera_center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Wrapped world positions at time ``t`` in the box around ``camera_center``.

        Parameters
        ----------
        t : float
            Seconds since the field's time origin (the scene's first frame).
        camera_center : ndarray [3]
            World position the box is centred on (horizontally; vertically it spans
            [-below_m, above_m] around it).

        Returns
        -------
        positions : ndarray [N, 3] float64
            World positions (m), all inside the box.
        wraps : ndarray [N] int64
            Vertical wrap count of each particle (0 until it first leaves the box vertically).

        Raises
        ------
        ValueError
            If ``t`` or ``camera_center`` is not finite, or beyond the range where the
            kinematics are exact (see :meth:`_check_frame`).
        """
        c = np.asarray(camera_center, np.float64).reshape(-1)
        self._check_frame(t, c)
        lo, size = self.spec.box_low, self.spec.box_size
        cam = (c - self.anchor_) @ self.basis.T  # camera in box coordinates
        # Box-relative coordinates before wrapping; shifting by -lo makes the wrap a plain modulo.
        unwrapped = self.initial + (self.velocity_box * t - (cam + lo))
        turb = self._turbulence(t)
        if turb is not None:
            unwrapped += turb
        wraps = np.floor(unwrapped[:, 2] / size[2]).astype(np.int64)
        moved = np.nonzero(wraps)[0]
        if moved.size:
            # A vertical wrap re-draws the horizontal position; the hash keeps it a pure function
            # of (seed, particle, wrap count), whatever frames were rendered before.
            for axis in (0, 1):
                unwrapped[moved, axis] += size[axis] * _hash_uniform(self.seed, moved, wraps[moved], axis)
        # u - floor(u / size) size, not np.mod: the same operations as the numba kernel.
        rel = unwrapped - np.floor(unwrapped / size) * size + lo
        return apply_linear(rel, self.basis) + c, wraps

    # ---- appearance -----------------------------------------------------------------------

    def visible(
        self,
        t: float,
        camera_center: np.ndarray,
        *,
        exposure_s: float = 0.01,
        camera_speed: float = 0.0,
        view: tuple[np.ndarray, np.ndarray, int, int] | None = None,
        near: float = 0.01,
        fast: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions and indices of the particles within range (and in view, with ``view``).

        Parameters
        ----------
        t, camera_center, exposure_s, view, near
            As in :meth:`gaussians`.
        camera_speed : float
            |camera velocity| (m/s), for the bound on streak lengths.
        fast : bool
            The numba kernel when available; else (or ``False``) the numpy reference.

        Returns
        -------
        positions : ndarray [K, 3] float64
            World positions of the kept particles (m).
        index : ndarray [K] int64
            Their particle indices, increasing.
        """
        spec = self.spec
        c = np.asarray(camera_center, np.float64).reshape(3)
        kernels = _numba_kernels() if fast else None
        if kernels is None:
            pos, _ = self.positions(t, c)
            d2 = np.einsum("ij,ij->i", pos - c, pos - c)
            ok = (d2 < spec.radius_m**2) & (d2 > spec.min_distance_m**2)
            if view is not None:
                ok &= self._in_view(pos, view, near, exposure_s, camera_speed)
            keep = np.nonzero(ok)[0]
            return pos[keep], keep
        pos, keep = self._cull_fast(kernels, t, c, exposure_s, camera_speed, view, near)
        return pos[keep], keep

    def _cull_fast(
        self,
        kernels: Any,
        t: float,
        c: np.ndarray,
        exposure_s: float,
        camera_speed: float,
        view: tuple[np.ndarray, np.ndarray, int, int] | None,
        near: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The numba twin of the reference branch of :meth:`visible`: ([N, 3] positions of all
        particles, kept indices)."""
        spec = self.spec
        self._check_frame(t, c)
        shift = (c - self.anchor_) @ self.basis.T + spec.box_low
        if view is None:
            W, kparams, size_px, near_, reach = np.eye(4), np.ones(4), np.zeros(2), -np.inf, 0.0
        else:
            W = np.asarray(view[0], np.float64)
            Kv = np.asarray(view[1], np.float64)
            kparams = np.array([Kv[0, 0], Kv[1, 1], Kv[0, 2], Kv[1, 2]])
            size_px = np.array([float(view[2]), float(view[3])])
            near_ = float(near)
            reach = 3.0 * self.max_extent(exposure_s=exposure_s, camera_speed=camera_speed)
        pos = np.empty((self.count, 3))
        ok = np.empty(self.count, np.bool_)
        kernels.field_kernel(
            self.initial,
            self.velocity_box,
            self.turb_amp,
            self.turb_omega,
            self.turb_phase,
            self.turb_offset,
            self.spec.turbulence_m_s > 0,
            float(t),
            shift,
            spec.box_size,
            spec.box_low,
            np.uint64(self.seed & 0xFFFFFFFFFFFFFFFF),  # the reference's _hash_uniform takes these bits
            self.basis,
            c,
            spec.radius_m**2,
            spec.min_distance_m**2,
            view is not None,
            np.ascontiguousarray(W[:3, :4]),
            kparams,
            size_px,
            near_,
            reach,
            pos,
            ok,
        )
        return pos, np.nonzero(ok)[0]

    def max_extent(self, *, exposure_s: float, camera_speed: float = 0.0) -> float:
        """Upper bound of any particle's longest standard deviation (m), for view culling."""
        if self.count == 0:
            return 0.0
        spec = self.spec
        if spec.physical:
            ratio = spec.flake_ratio if spec.kind == "snow" else 1.0
            base = spec.max_diameter_mm * ratio * 1e-3 / 4.0
        else:
            assert spec.scale_m is not None
            base = max(spec.scale_m)
        if spec.kind != "rain" or not spec.stretch_with_exposure:
            return float(base)
        # The flutter's speed never exceeds sum(a_k) = sqrt(2 K) times its RMS per axis.
        flutter = spec.turbulence_m_s * math.sqrt(2.0 * _TURB_MODES) * math.sqrt(2.25)
        speed = self._speed_max + flutter + camera_speed
        return float(math.hypot(base, speed * exposure_s / math.sqrt(12.0)))  # no overflow of the squares

    def _in_view(
        self,
        pos: np.ndarray,
        view: tuple[np.ndarray, np.ndarray, int, int],
        near: float,
        exposure_s: float,
        camera_speed: float,
    ) -> np.ndarray:
        """[N] bool: the particle's 3-sigma extent may reach the image and it is beyond ``near``."""
        world_to_camera, K, width, height = view
        W = np.asarray(world_to_camera, np.float64)
        K = np.asarray(K, np.float64)
        cam = apply_linear(pos, W[:3, :3].T) + W[:3, 3]
        z = cam[:, 2]
        ok = z > near
        zs = np.where(ok, z, 1.0)
        # A focal length near 0 (or z near 0) gives unbounded normalised coordinates: they compare
        # as +-Inf, and a NaN bound culls, as in the kernel.
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            reach = 3.0 * self.max_extent(exposure_s=exposure_s, camera_speed=camera_speed) / zs
            # Compare in normalised coordinates: |x/z - x_edge| within the extent (+ 3 px of dilation).
            xn, yn = cam[:, 0] / zs, cam[:, 1] / zs
            pad_x, pad_y = reach + 3.0 / K[0, 0], reach + 3.0 / K[1, 1]
            x_lo, x_hi = -K[0, 2] / K[0, 0], (width - K[0, 2]) / K[0, 0]
            y_lo, y_hi = -K[1, 2] / K[1, 1], (height - K[1, 2]) / K[1, 1]
            return ok & (xn > x_lo - pad_x) & (xn < x_hi + pad_x) & (yn > y_lo - pad_y) & (yn < y_hi + pad_y)

    def gaussians(
        self,
        t: float,
        camera_center: np.ndarray,
        *,
        exposure_s: float = 0.01,
        camera_velocity: np.ndarray | None = None,
        view: tuple[np.ndarray, np.ndarray, int, int] | None = None,
        near: float = 0.01,
        dilation_eps2d: float | None = None,
        out: ParticleGaussians | None = None,
        fast: bool = True,
    ) -> ParticleGaussians:
        """The particles of time ``t`` as Gaussians, dropped where they would be invisible.

        Particles farther than ``radius_m`` or nearer than ``min_distance_m`` from the camera are
        dropped; opacity fades to 0 over ``fade_m`` before ``radius_m`` (no popping at the box
        faces) and over ``min_distance_m`` after the near limit. With ``view``, particles whose
        3-sigma extent cannot reach the image are dropped before their shapes are computed.

        Parameters
        ----------
        t : float
            Seconds since the time origin.
        camera_center : ndarray [3]
            World camera position (m).
        exposure_s : float
            Camera exposure (s): a streak spans the relative motion during it.
        camera_velocity : ndarray [3], optional
            World velocity of the camera (m/s); streaks follow the velocity relative to it.
        view : (ndarray [4, 4], ndarray [3, 3], int, int), optional
            World-to-camera matrix (OpenCV axes), intrinsics, width and height of the image.
        near : float
            With ``view``: particles with camera z <= near are dropped (m).
        dilation_eps2d : float, optional
            With ``view``: scale opacities by :func:`particle_dilation_compensation` for a
            rasterizer that dilates 2D covariances by this many px^2.
        out : ParticleGaussians, optional
            Buffers of at least :attr:`max_gaussians` rows to write into (float32 arrays, int64
            ``particle``); the result is then made of views of their first rows. Lets a renderer
            put the particles straight behind its scene Gaussians without a copy.
        fast : bool
            Use the numba kernels when numba is available (the numpy path is their reference).

        Returns
        -------
        ParticleGaussians
            One Gaussian per raindrop, three per snowflake.

        Raises
        ------
        ValueError
            If ``exposure_s`` is negative or not finite, ``dilation_eps2d`` is given without
            ``view`` or is negative or not finite, ``out`` is too small, the view is not finite (K
            with positive focal lengths, positive integer sizes), or ``t``, ``camera_center``,
            ``camera_velocity`` and ``exposure_s`` give positions, speeds or streak lengths beyond
            what float32 Gaussians hold (see :meth:`_check_frame`; docs/design.md §9).
        """
        if not math.isfinite(exposure_s) or exposure_s < 0:
            raise ValueError(f"exposure_s must be finite and >= 0 seconds, got {exposure_s}")
        if dilation_eps2d is not None and view is None:
            raise ValueError("dilation_eps2d needs the view it compensates for")
        if dilation_eps2d is not None and not 0 <= dilation_eps2d < math.inf:
            raise ValueError(f"dilation_eps2d must be finite and >= 0 px^2, got {dilation_eps2d}")
        if out is not None and len(out) < self.max_gaussians:
            raise ValueError(f"out holds {len(out)} Gaussians, this field needs up to {self.max_gaussians}")
        if view is not None:
            _check_view(view, near)
        c = np.asarray(camera_center, np.float64).reshape(-1)
        self._check_frame(t, c)
        cam_vel = np.zeros(3) if camera_velocity is None else np.asarray(camera_velocity, np.float64).reshape(-1)
        if cam_vel.shape != (3,) or not np.all(np.abs(cam_vel) <= _MAX_F32_MAGNITUDE):
            raise ValueError(f"camera_velocity must be a finite [3] velocity within +-{_MAX_F32_MAGNITUDE:g} m/s, "
                             f"got {camera_velocity!r}")
        cam_speed = float(np.linalg.norm(cam_vel))
        reach = self.max_extent(exposure_s=exposure_s, camera_speed=cam_speed)
        if not (self._speed_max + self._flutter_speed + cam_speed <= _MAX_F32_MAGNITUDE
                and reach <= _MAX_F32_MAGNITUDE):
            raise ValueError(f"streaks of {reach:.3g} m (speeds up to {self._speed_max + cam_speed:.3g} m/s over "
                             f"{exposure_s} s) are beyond float32")
        if self.count == 0:
            return ParticleGaussians.empty()
        kernels = _numba_kernels() if fast else None
        if kernels is not None:
            return self._gaussians_fast(kernels, t, c, exposure_s, cam_vel, view, near, dilation_eps2d, out)
        g = self._gaussians_reference(t, c, exposure_s, cam_vel, view, near)
        if dilation_eps2d is not None and len(g):
            assert view is not None
            g.opacities = g.opacities * particle_dilation_compensation(
                g.means, g.quats, g.scales, view[0], view[1], eps2d=dilation_eps2d
            )
        if out is None:
            return g
        k = len(g)
        for f in fields(ParticleGaussians):
            getattr(out, f.name)[:k] = getattr(g, f.name)
        return out.head(k)

    @property
    def max_gaussians(self) -> int:
        """Most Gaussians one frame can have: the particle count (rain) or three times it (snow)."""
        return self.count * (1 if self.spec.kind == "rain" else 3)

    def _gaussians_fast(
        self,
        kernels: Any,
        t: float,
        c: np.ndarray,
        exposure_s: float,
        cam_vel: np.ndarray,
        view: tuple[np.ndarray, np.ndarray, int, int] | None,
        near: float,
        dilation_eps2d: float | None,
        out: ParticleGaussians | None,
    ) -> ParticleGaussians:
        """The numba twin of :meth:`_gaussians_reference` plus the dilation compensation."""
        spec = self.spec
        pos, keep = self._cull_fast(kernels, t, c, exposure_s, float(np.linalg.norm(cam_vel)), view, near)
        rows = keep.size * (1 if spec.kind == "rain" else 3)
        if out is None:
            out = ParticleGaussians.allocate(rows)
        if view is None:
            W, fx, fy = np.zeros((3, 4)), 1.0, 1.0
        else:
            W = np.ascontiguousarray(np.asarray(view[0], np.float64)[:3, :4])
            fx, fy = float(view[1][0][0]), float(view[1][1][1])
        if spec.physical:
            size_ratio = spec.flake_ratio if spec.kind == "snow" else 1.0
            short_ratio = _SHORT_OVER_LONG if spec.kind == "snow" else 1.0
            scale_m = np.ones(3)
        else:
            assert spec.scale_m is not None
            size_ratio = short_ratio = 1.0
            scale_m = np.asarray(spec.scale_m, np.float64)
        kernels.shape_kernel(
            keep,
            pos,
            c,
            float(t),
            self.velocity_box,
            self.turb_amp,
            self.turb_omega,
            self.turb_phase,
            spec.turbulence_m_s > 0,
            self.basis,
            cam_vel,
            float(exposure_s),
            spec.kind == "rain",
            spec.physical,
            spec.stretch_with_exposure,
            self.diameter_mm,
            float(size_ratio),
            float(short_ratio),
            scale_m,
            float(min(spec.opacity, _MAX_SINGLE_OPACITY)),
            float(spec.fade_m),
            float(spec.radius_m),
            float(spec.min_distance_m),
            float(self.represented),
            self.orientation,
            self.spin_rate,
            dilation_eps2d is not None,
            W,
            fx,
            fy,
            0.0 if dilation_eps2d is None else float(dilation_eps2d),
            np.asarray(spec.color, np.float32),
            out.means,
            out.quats,
            out.scales,
            out.opacities,
            out.colors,
            out.particle,
            out.velocity,
        )
        return out.head(rows)

    def _gaussians_reference(
        self,
        t: float,
        c: np.ndarray,
        exposure_s: float,
        cam_vel: np.ndarray,
        view: tuple[np.ndarray, np.ndarray, int, int] | None,
        near: float,
    ) -> ParticleGaussians:
        """The numpy reference of :meth:`gaussians` (no dilation compensation, no buffers)."""
        spec = self.spec
        pos, keep = self.visible(
            t,
            c,
            exposure_s=exposure_s,
            camera_speed=float(np.linalg.norm(cam_vel)),
            view=view,
            near=near,
            fast=False,
        )
        dist = np.sqrt(np.einsum("ij,ij->i", pos - c, pos - c))
        fade = np.ones(keep.size)
        with np.errstate(over="ignore"):  # a denormal fade length: the ramp is a step (Inf clips to 1)
            if spec.fade_m > 0:
                fade *= np.clip((spec.radius_m - dist) / spec.fade_m, 0.0, 1.0)
            if spec.min_distance_m > 0:
                fade *= np.clip((dist - spec.min_distance_m) / spec.min_distance_m, 0.0, 1.0)
        vel = apply_linear(self._velocity_box(t, keep), self.basis)
        rel_vel = vel - cam_vel

        if spec.physical:
            if spec.kind == "rain":
                base = np.repeat((self.diameter_mm[keep] * 1e-3 / 4.0)[:, None], 3, axis=1)  # sigma = D / 4
            else:
                long = self.diameter_mm[keep] * spec.flake_ratio * 1e-3 / 4.0
                base = np.stack([long, long * _SHORT_OVER_LONG, long * _SHORT_OVER_LONG], 1)
        else:
            assert spec.scale_m is not None
            base = np.broadcast_to(np.asarray(spec.scale_m, np.float64), (keep.size, 3)).copy()
        opacity = np.full(keep.size, min(spec.opacity, _MAX_SINGLE_OPACITY))

        if spec.kind == "rain":
            scales = base
            if spec.stretch_with_exposure:
                # A uniform segment of length |v| t_exp has variance (|v| t_exp)^2 / 12; the streak
                # keeps the drop's integrated opacity, so the peak drops by the stretch factor.
                travel = np.linalg.norm(rel_vel, axis=1) * exposure_s
                long = np.sqrt(scales[:, 2] ** 2 + travel**2 / 12.0)
                opacity = opacity * scales[:, 2] / long
                scales = np.concatenate([scales[:, :2], long[:, None]], 1)
            quats = quat_from_axis_to(rel_vel)
            particle = keep
            means, velocity = pos, vel
        else:
            angle = self.spin_rate[keep] * t
            arms = np.arange(3) * (np.pi / 3.0)  # three arms at 60 degrees
            spin = _quat_about_z(angle[:, None] + arms[None, :])  # [K, 3, 4]
            quats = quat_multiply(self.orientation[keep][:, None, :], spin).reshape(-1, 4)
            scales = np.repeat(base, 3, axis=0)
            means = np.repeat(pos, 3, axis=0)
            velocity = np.repeat(vel, 3, axis=0)
            particle = np.repeat(keep, 3)
            opacity = np.repeat(opacity, 3)
            fade = np.repeat(fade, 3)

        if self.represented > 1.0:
            # k = physical / simulated drops per particle: optical depth of k independent drops.
            opacity = -np.expm1(self.represented * np.log1p(-np.minimum(opacity, _MAX_SINGLE_OPACITY)))
        opacity = np.clip(opacity * fade, 0.0, 1.0)
        colors = np.broadcast_to(np.asarray(spec.color, np.float32), (means.shape[0], 3))
        return ParticleGaussians(
            means=means.astype(np.float32),
            quats=quats.astype(np.float32),
            scales=scales.astype(np.float32),
            opacities=opacity.astype(np.float32),
            colors=np.ascontiguousarray(colors),
            particle=np.asarray(particle, np.int64),
            velocity=velocity.astype(np.float32),
        )

    # ---- bookkeeping ----------------------------------------------------------------------

    def haze_density(self) -> float:
        """:func:`haze_density` of this field's spec (m^-1)."""
        return haze_density(self.spec)

    def info(self) -> dict[str, Any]:
        """JSON-ready description of the population (for ``info.json``)."""
        spec = self.spec
        return {
            "kind": spec.kind,
            "mode": "physical" if spec.physical else "fixed_count",
            "rate_mm_h": spec.rate_mm_h if spec.physical else None,
            "density_per_m3": self.density_per_m3,
            "box_m": [float(x) for x in spec.box_size],
            "physical_count": self.physical_count,
            "simulated_count": self.count,
            "gaussians_per_particle": 1 if spec.kind == "rain" else 3,
            "capped": bool(spec.physical and self.physical_count > spec.max_particles),
            "represented_per_particle": self.represented,
            "opacity_scaling": (
                "opacity' = 1 - (1 - opacity)^k with k = physical_count / simulated_count"
                if self.represented > 1.0
                else "none"
            ),
            "haze_density_per_m": self.haze_density(),
            "haze_model": spec.haze_model if spec.haze and spec.physical else None,
            "wind_m_s": [float(x) for x in self.wind_vector],
            "mean_fall_speed_m_s": float(self.fall_speed.mean()) if self.count else None,
            "seed": int(self.seed),
        }


def _check_view(view: tuple[np.ndarray, np.ndarray, int, int], near: float) -> None:
    """A view is a finite world-to-camera matrix, finite intrinsics with positive focal lengths and
    a positive integer size; ``near`` is finite (docs/design.md §9)."""
    W, K, width, height = view
    Wm, Km = np.asarray(W, np.float64), np.asarray(K, np.float64)
    if Wm.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(Wm)):
        raise ValueError(f"view: the world-to-camera matrix must be finite [4, 4], got shape {Wm.shape}")
    if Km.shape != (3, 3) or not np.all(np.isfinite(Km)) or not (Km[0, 0] > 0 and Km[1, 1] > 0):
        raise ValueError(f"view: K must be finite [3, 3] intrinsics with positive focal lengths, got {Km.tolist()}")
    if int(width) != width or int(height) != height or width < 1 or height < 1:
        raise ValueError(f"view: width and height must be positive integers, got {width} x {height}")
    if not math.isfinite(near):
        raise ValueError(f"near must be finite metres, got {near}")


# --------------------------------------------------------------------------------------------
# numba kernels (the numpy code above is their reference)


def _numba_kernels() -> Any:
    """The compiled kernels' module, or ``None`` when numba is unavailable (numpy is used)."""
    return load_numba_kernels("weather.particle_kernels")
