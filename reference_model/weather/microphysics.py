"""Microphysics of rain and snow: drop-size distributions, fall speeds and extinction (docs/design.md §7).

Physical presets derive the density and sizes from a drop-size distribution
N(D) = N0 exp(-Lambda D) (Marshall-Palmer for rain, Gunn-Marshall for snow, D in mm); every
simulated drop or flake draws its diameter from it (:func:`sample_diameters`) and its fall speed
follows from that diameter. Rain and snow beyond the particle box are haze, with the extinction
coefficient of the rate: see :func:`precipitation_extinction` (empirical relations by default,
:func:`extinction_coefficient` for the geometric-optics form).

Diameters are millimetres, rates mm/h, speeds m/s, extinction coefficients m^-1.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from wcbench.reference_model.weather.particle_spec import ParticleSpec

__all__ = [
    "HAZE_MODELS",
    "KINDS",
    "RAIN_EXTINCTION_KM",
    "SNOW_AGGREGATES",
    "extinction_coefficient",
    "number_density",
    "precipitation_extinction",
    "rain_extinction",
    "rain_fall_speed",
    "sample_diameters",
    "size_distribution",
    "snow_extinction",
    "snow_fall_speed",
]

KINDS = ("rain", "snow")
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

