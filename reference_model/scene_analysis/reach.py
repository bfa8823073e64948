"""How far and how high the scene's lidar sees, read off its own returns (docs/design.md §7,
"Beyond the lidar").

A lidar that returned from 200 m in every sweep would have returned from a facade 60 m away in its
field of view: a pixel inside that field that no return of any sweep lands near holds nothing
nearer than the lidar's reach (free space, the evidence an occupancy map reads from a ray that
comes back empty). The completion's guess for such a pixel (the surface below it continued, the
trees beside it smoothed in) can put a building that closes the street far down at the distance
of the car in front of it; under fog that building keeps its colour where the truth shows only
haze. :class:`LidarReach` holds what the returns show of the sensor: its reach, the per-sweep
99.9th percentile of the returns' distances from the camera (the median over sweeps: a lower
bound of the sensor's range, which a stray far return does not lift), and the band of elevations
(from the camera) of its returns farther than 20 m, where the offset between lidar and camera
moves an elevation by a degree at most.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from wcbench.reference_model.scene_analysis.motion import LidarReturns
from wcbench.reference_model.scene_analysis.views import AnalysisViews

__all__ = ["LidarReach", "lidar_reach"]

#: Returns nearer than this (m) leave the elevation band alone (the lidar-camera offset's parallax).
_FAR_M = 20.0
#: Percentiles: of each sweep's distances (its reach), of the far returns' elevations (the band).
_REACH_PERCENTILE, _BAND_PERCENTILES = 99.9, (0.5, 99.5)
#: Fewer far returns than this over the sequence read no band: no reach.
_MIN_FAR_RETURNS = 500


@dataclass(frozen=True)
class LidarReach:
    """What the returns show of the lidar's field.

    Attributes
    ----------
    range_m : float
        Distance from the camera (m) within which a surface in the field returns.
    elevation_deg : (float, float)
        Lowest and highest elevation above the horizontal, from the camera (degrees), of the field.
    """

    range_m: float
    elevation_deg: tuple[float, float]

    def __post_init__(self) -> None:
        lo, hi = self.elevation_deg
        if not (np.isfinite(self.range_m) and self.range_m > 0 and -90.0 <= lo < hi <= 90.0):
            raise ValueError(f"range_m > 0 and -90 <= low < high <= 90 degrees were expected, got {self.range_m} "
                             f"and {self.elevation_deg}")

    def facts(self) -> dict[str, Any]:
        """For ``info.json``."""
        return {"range_m": round(self.range_m, 1), "elevation_deg": [round(e, 1) for e in self.elevation_deg]}


def lidar_reach(views: AnalysisViews, returns: LidarReturns) -> LidarReach | None:
    """The lidar's reach and elevation band from every sweep's returns (see the module docstring).

    Parameters
    ----------
    views : AnalysisViews
        The frames' cameras (each sweep measured from its frame's camera centre) and ``up``.
    returns : LidarReturns
        Every sweep's returns, the dynamic ones included (a moving car returns like a wall).

    Returns
    -------
    LidarReach or None
        ``None`` without sweeps, or with fewer than 500 returns farther than 20 m.
    """
    up = np.asarray(views.up, np.float64)
    reaches, elevations = [], []
    for k, p in sorted(returns.points.items()):
        if not len(p) or k >= len(views):
            continue
        v = np.asarray(p, np.float64) - views.center(k)
        d = np.linalg.norm(v, axis=1)
        reaches.append(float(np.percentile(d, _REACH_PERCENTILE)))
        far = d > _FAR_M
        elevations.append(np.degrees(np.arcsin(np.clip((v[far] @ up) / d[far], -1.0, 1.0))))
    pooled = np.concatenate(elevations) if elevations else np.zeros(0)
    if len(pooled) < _MIN_FAR_RETURNS:
        return None
    lo, hi = np.percentile(pooled, _BAND_PERCENTILES)
    if not hi > lo:
        return None
    return LidarReach(range_m=float(np.median(reaches)), elevation_deg=(float(lo), float(hi)))
