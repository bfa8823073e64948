"""The parameters of a particle population and the Gaussians of one frame (docs/design.md §7).

:class:`ParticleSpec` holds everything that defines a rain or snow population (``presets.toml``),
:class:`Wind` a uniform wind, :class:`ParticleGaussians` the particles of one frame as Gaussians.
Every number is checked finite and within float32 on construction (docs/design.md §9).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from wcbench.reference_model.weather.microphysics import HAZE_MODELS, KINDS

__all__ = ["MAX_F32_MAGNITUDE", "ParticleGaussians", "ParticleSpec", "Wind"]

SHORT_OVER_LONG = 0.625  # the paper flake's axis ratio, 0.004 / 0.0064
#: Largest magnitude of a position, speed or length written to the float32 Gaussians (an eighth of
#: float32's range: sums of a few such terms stay finite; docs/design.md §9).
MAX_F32_MAGNITUDE = 4e37
#: Shortest standard deviation of a particle Gaussian (m): normal in float32, and a streak's
#: length stays > 0 (its opacity is scaled by width / length).
MIN_SIGMA_M = 1e-30


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
        if not 0 <= self.speed_m_s <= MAX_F32_MAGNITUDE:
            raise ValueError(f"wind speed_m_s must be in [0, {MAX_F32_MAGNITUDE:g}], got {self.speed_m_s}")
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
    ``count`` (fixed count with fixed ``scale_m``/``opacity``: the paper's, docs/design.md §7) is used;
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
            if not 0 < getattr(self, name) <= MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in (0, {MAX_F32_MAGNITUDE:g}] m, got {getattr(self, name)}")
        for name in ("fade_m", "min_distance_m"):
            if not 0 <= getattr(self, name) <= MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in [0, {MAX_F32_MAGNITUDE:g}] m, got {getattr(self, name)}")
        for name in ("turbulence_m_s", "spin_rad_s"):
            if not 0 <= getattr(self, name) <= MAX_F32_MAGNITUDE:
                raise ValueError(f"{name} must be in [0, {MAX_F32_MAGNITUDE:g}], got {getattr(self, name)}")
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
        if self.scale_m is not None and (len(self.scale_m) != 3 or not all(MIN_SIGMA_M <= v <= MAX_F32_MAGNITUDE
                                                                          for v in self.scale_m)):
            raise ValueError(f"scale_m must be three lengths in [{MIN_SIGMA_M:g}, {MAX_F32_MAGNITUDE:g}] m "
                             f"(float32), got {self.scale_m}")
        if self.count is None:  # sizes from the drop-size distribution: sigma = D / 4 (times the flake ratio)
            ratio = self.flake_ratio if self.kind == "snow" else 1.0
            short = SHORT_OVER_LONG if self.kind == "snow" else 1.0
            lo = self.min_diameter_mm * 1e-3 / 4.0 * ratio * short
            hi = self.max_diameter_mm * 1e-3 / 4.0 * ratio
            if not (MIN_SIGMA_M <= lo and hi <= MAX_F32_MAGNITUDE):
                raise ValueError(f"diameters in [{self.min_diameter_mm}, {self.max_diameter_mm}] mm give particle "
                                 f"sizes in [{lo:.3g}, {hi:.3g}] m, outside [{MIN_SIGMA_M:g}, "
                                 f"{MAX_F32_MAGNITUDE:g}] m (float32)")
        if self.count is not None and (self.scale_m is None or self.fall_speed_m_s is None):
            raise ValueError("a fixed-count spec needs scale_m and fall_speed_m_s")
        if self.fall_speed_m_s is not None and not abs(self.fall_speed_m_s) <= MAX_F32_MAGNITUDE:
            raise ValueError(f"fall_speed_m_s must be finite, within +-{MAX_F32_MAGNITUDE:g} m/s, "
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
