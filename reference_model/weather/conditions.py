"""A weather in physical units, and the presets it starts from (numpy only, no torch).

A :class:`Weather` describes the weather (kind, preset from ``presets.toml``, rain/snow rate, fog
visibility or density, wind, seed, exposure, fog mode); :meth:`Weather.particle_spec` and
:meth:`Weather.fog_parameters` resolve it into the particle population and the fog the renderer
(:mod:`.renderer`) draws.
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from importlib import resources
from typing import Any

import numpy as np

from wcbench.core.weathers import WEATHERS
from wcbench.reference_model.weather.fog import density_from_visibility
from wcbench.reference_model.weather.particle_spec import ParticleSpec, Wind
from wcbench.reference_model.weather.particles import ParticleField, haze_density

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = ["FOG_MODES", "Weather", "load_presets", "preset_names"]

FOG_MODES = ("exact", "postprocess")
_PRESETS_FILE = "presets.toml"


# --------------------------------------------------------------------------------------------
# Presets


@functools.lru_cache(maxsize=1)
def load_presets() -> dict[str, Any]:
    """The parsed ``weather_presets.toml`` (cached; do not mutate)."""
    text = resources.files(__package__).joinpath(_PRESETS_FILE).read_text(encoding="utf-8")
    return tomllib.loads(text)


def preset_names(kind: str) -> list[str]:
    """Preset names of a weather kind (empty for ``clear``)."""
    if kind not in WEATHERS:
        raise ValueError(f"kind must be one of {WEATHERS}, got {kind!r}")
    return sorted(load_presets().get(kind, {}).get("presets", {}))


def _preset_table(kind: str, preset: str | None) -> tuple[str | None, dict[str, Any]]:
    """(resolved preset name, base table merged with the preset's overrides)."""
    table = load_presets().get(kind, {})
    base = {k: v for k, v in table.items() if k != "presets"}
    presets = table.get("presets", {})
    name = preset if preset is not None else base.get("default_preset")
    base.pop("default_preset", None)
    if name is None:
        return None, base
    if name not in presets:
        raise ValueError(f"preset: unknown {kind} preset {name!r}; known: {sorted(presets)}")
    return name, {**base, **presets[name]}


# --------------------------------------------------------------------------------------------
# The weather description


@dataclass(frozen=True)
class Weather:
    """A weather in physical units; unset fields come from the preset.

    Attributes
    ----------
    kind : {"clear", "rain", "snow", "fog"}
    preset : str, optional
        Name in ``weather_presets.toml`` (rain: light, moderate, heavy, paper; snow: light, heavy,
        paper; fog: light, moderate, dense, paper). Default: the kind's ``default_preset``.
    rate_mm_h : float, optional
        Rain or snow rate (mm/h of liquid water); on a fixed-count preset (``paper``) it switches
        to the kind's physical settings at that rate.
    count : int, optional
        Fixed particle count (rain drops or snowflakes) instead of a rate, with the ``paper``
        preset's shapes when the preset is physical. ``rate_mm_h`` and ``count`` exclude each other.
    visibility_m : float, optional
        Fog visibility V (m), the meteorological optical range (5 % contrast): beta = 2.996 / V.
        For rain and snow: overrides the haze of the rate.
    fog_density : float, optional
        Fog extinction beta (m^-1); wins over ``visibility_m``.
    fog_color : tuple of 3 float, optional
        RGB of the fog in [0, 1] (rain/snow: of the haze).
    wind : Wind
        Magnitude (m/s), tilt and azimuth (degrees).
    seed : int
        Particle seed.
    exposure_s : float, optional
        Camera exposure (s) for rain streaks; default from the presets' ``[common]`` table.
    max_particles : int, optional
        Cap on simulated particles (physical presets).
    fog_mode : {"exact", "postprocess"}
        Per-layer Beer-Lambert, or the paper's depth-map post-process (for comparison).
    """

    kind: str = "clear"
    preset: str | None = None
    rate_mm_h: float | None = None
    count: int | None = None
    visibility_m: float | None = None
    fog_density: float | None = None
    fog_color: tuple[float, float, float] | None = None
    wind: Wind = field(default_factory=Wind)
    seed: int = 0
    exposure_s: float | None = None
    max_particles: int | None = None
    fog_mode: str = "exact"

    def __post_init__(self) -> None:
        if self.kind not in WEATHERS:
            raise ValueError(f"kind must be one of {WEATHERS}, got {self.kind!r}")
        if self.fog_mode not in FOG_MODES:
            raise ValueError(f"fog_mode must be one of {FOG_MODES}, got {self.fog_mode!r}")
        if self.rate_mm_h is not None and (not math.isfinite(self.rate_mm_h) or self.rate_mm_h < 0):
            raise ValueError(f"rate_mm_h must be a finite rate >= 0 mm/h, got {self.rate_mm_h}")
        if self.count is not None and self.count < 0:
            raise ValueError(f"count must be >= 0, got {self.count}")
        if self.count is not None and self.rate_mm_h is not None:
            raise ValueError("give rate_mm_h or count, not both")
        if self.visibility_m is not None and not self.visibility_m > 0:
            raise ValueError(f"visibility_m must be > 0 metres, got {self.visibility_m}")
        if self.fog_density is not None and not (0 <= self.fog_density < math.inf):
            raise ValueError(f"fog_density must be finite and >= 0 m^-1, got {self.fog_density}")
        if self.exposure_s is not None and not (0 <= self.exposure_s < math.inf):
            raise ValueError(f"exposure_s must be finite and >= 0 s, got {self.exposure_s}")
        if self.max_particles is not None and self.max_particles < 0:
            raise ValueError(f"max_particles must be >= 0, got {self.max_particles}")
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.fog_color is not None:
            c = np.asarray(self.fog_color, np.float64)
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise ValueError(f"fog_color must be 3 finite numbers, got {self.fog_color!r}")
        if self.kind != "clear" and self.preset is not None:
            _preset_table(self.kind, self.preset)  # fail early on an unknown preset

    @property
    def has_particles(self) -> bool:
        """Whether this weather builds particles (rain and snow)."""
        return self.kind in ("rain", "snow")

    def resolved_preset(self) -> str | None:
        """The preset actually used (the kind's default when none was given)."""
        if self.kind == "clear":
            return None
        return _preset_table(self.kind, self.preset)[0]

    def precipitation_rate(self) -> float:
        """Rain or snow rate (mm/h of liquid water) this weather stands for; 0 for clear and fog.

        A fixed-count preset (``paper``) has no rate of its own: the kind's default preset's rate
        is taken (the surfaces' wetness and snow cover need one).
        """
        if not self.has_particles:
            return 0.0
        if self.rate_mm_h is not None:
            return float(self.rate_mm_h)
        _, table = _preset_table(self.kind, self.preset)
        if "rate_mm_h" not in table:
            table = _preset_table(self.kind, load_presets()[self.kind].get("default_preset"))[1]
        return float(table["rate_mm_h"])

    def exposure(self) -> float:
        """Exposure time (s)."""
        if self.exposure_s is not None:
            return float(self.exposure_s)
        return float(load_presets().get("common", {}).get("exposure_s", 0.01))

    def particle_spec(self) -> ParticleSpec | None:
        """The particle population, or ``None`` for clear and fog."""
        if not self.has_particles:
            return None
        _, table = _preset_table(self.kind, self.preset)
        if self.rate_mm_h is not None and "count" in table:
            # A rate on a fixed-count preset: the kind's physical settings at that rate.
            table = _preset_table(self.kind, load_presets()[self.kind].get("default_preset"))[1]
        if self.count is not None and "count" not in table:
            # A count on a physical preset: the paper's fixed shapes with that count.
            table = _preset_table(self.kind, "paper")[1]
        if self.rate_mm_h is not None:
            table = {**table, "rate_mm_h": self.rate_mm_h}
            table.pop("count", None)
        if self.count is not None:
            table = {**table, "count": self.count}
            table.pop("rate_mm_h", None)
        if self.max_particles is not None:
            table["max_particles"] = self.max_particles
        return ParticleSpec.from_mapping(self.kind, table)

    def fog_parameters(self, field_: ParticleField | None = None) -> tuple[float, np.ndarray, float]:
        """(beta m^-1, fog color [3], offset m) of the fog or haze; beta 0 when there is none.

        Parameters
        ----------
        field_ : ParticleField, optional
            The rain/snow population whose haze to use (its extinction, starting at its radius).
        """
        return self._fog(haze_density(field_.spec) if field_ is not None else 0.0)

    def haze(self) -> tuple[float, np.ndarray, float]:
        """:meth:`fog_parameters` of this weather's own particles (the haze a renderer of it adds),
        without drawing them: (beta m^-1, color [3], offset m)."""
        spec = self.particle_spec()
        return self._fog(haze_density(spec) if spec is not None else 0.0)

    def _fog(self, precipitation_beta: float) -> tuple[float, np.ndarray, float]:
        """:meth:`fog_parameters` with rain or snow of extinction ``precipitation_beta`` (m^-1)."""
        if self.kind == "clear":
            return 0.0, np.zeros(3, np.float32), 0.0
        _, table = _preset_table(self.kind, self.preset)
        if self.kind == "fog":
            color = table.get("color", (0.8, 0.8, 0.85))
            beta = table.get("density_per_m")
            if beta is None:
                beta = density_from_visibility(float(table["visibility_m"]))
            offset = 0.0
        else:
            color = table.get("haze_color", (0.6, 0.62, 0.66))
            beta = precipitation_beta
            offset = float(table.get("radius_m", 10.0))
        if self.visibility_m is not None:
            beta = density_from_visibility(self.visibility_m)
        if self.fog_density is not None:
            beta = self.fog_density
        if self.fog_color is not None:
            color = self.fog_color
        return float(beta), np.asarray(color, np.float32), offset

    def to_json(self) -> dict[str, Any]:
        """The description as given (JSON-ready)."""
        d = asdict(self)
        d["wind"] = asdict(self.wind)
        return d

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> Weather:
        """Inverse of :meth:`to_json`."""
        obj = dict(obj)
        wind = Wind(**obj.pop("wind", {}))
        if obj.get("fog_color") is not None:
            obj["fog_color"] = tuple(obj["fog_color"])
        return cls(wind=wind, **obj)
