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
from it. Rain and snow beyond the box are haze, with the extinction coefficient of the rate
(:func:`haze_density`).

The parts live beside this module: the drop-size distributions, fall speeds and extinction in
:mod:`.microphysics`, the spec and the frame's Gaussians in :mod:`.particle_spec`, orientations,
view checks and the dilation compensation in :mod:`.particle_geometry`, the counter-based hash of
the wrap re-draw in :mod:`.hashing`.

All lengths are metres, times seconds, diameters millimetres; colors float RGB in [0, 1]
(the images' values, as everywhere in wcbench).
Quaternions are (w, x, y, z).

The numpy code here is the reference; :mod:`.particle_kernels` computes the same frame in two
numba passes (``fast=True``, the default when numba imports) and the tests compare the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from wcbench.reference_model._numba_backend import load_numba_kernels
from wcbench.reference_model.transforms import apply_linear, quat_multiply
from wcbench.reference_model.weather.hashing import hash_uniform
from wcbench.reference_model.weather.microphysics import (
    extinction_coefficient,
    number_density,
    precipitation_extinction,
    rain_fall_speed,
    sample_diameters,
    size_distribution,
    snow_fall_speed,
)
from wcbench.reference_model.weather.particle_geometry import (
    check_view,
    horizontal_basis,
    particle_dilation_compensation,
    quat_about_z,
    quat_from_axis_to,
    random_quaternions,
)
from wcbench.reference_model.weather.particle_spec import (
    MAX_F32_MAGNITUDE,
    SHORT_OVER_LONG,
    ParticleGaussians,
    ParticleSpec,
    Wind,
)

__all__ = ["ParticleField", "haze_density"]

_KIND_CODE = {"rain": 1, "snow": 2}
_TURB_MODES = 3  # sinusoids per axis of the snow flutter
_TURB_FREQ_HZ = (0.2, 1.0)  # flutter frequencies of falling aggregates
_MAX_SINGLE_OPACITY = 0.99  # the rasterizer's clamp; (1 - a)^k needs a < 1
#: Largest |omega t| of the flutter and spin phases: the fast path's sine is exact for |x| < 1e7.
_MAX_PHASE_RAD = 1e6
#: Vertical wrap counts are exact integers up to 2^52 box heights (float64), then int64.
_MAX_WRAPS = 2.0**52


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
        if not np.all(np.abs(self.anchor_) <= MAX_F32_MAGNITUDE):
            raise ValueError(f"anchor must be a finite position within +-{MAX_F32_MAGNITUDE:g} m, got {self.anchor!r}")
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
        if not speed_bound <= MAX_F32_MAGNITUDE:
            raise ValueError(f"particle speeds up to {speed_bound:.3g} m/s (wind, fall and flutter) exceed "
                             f"{MAX_F32_MAGNITUDE:g} m/s, beyond float32")
        # Flake orientation: random rotation, then spin about its normal (local z).
        self.orientation = random_quaternions(rng.random((n, 3)))
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
        if not float(np.abs(c).max()) + extent <= MAX_F32_MAGNITUDE:
            raise ValueError(f"camera_center {c.tolist()} is beyond +-{MAX_F32_MAGNITUDE:g} m (float32 positions)")
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
                unwrapped[moved, axis] += size[axis] * hash_uniform(self.seed, moved, wraps[moved], axis)
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
            np.uint64(self.seed & 0xFFFFFFFFFFFFFFFF),  # the reference's hash_uniform takes these bits
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
            check_view(view, near)
        c = np.asarray(camera_center, np.float64).reshape(-1)
        self._check_frame(t, c)
        cam_vel = np.zeros(3) if camera_velocity is None else np.asarray(camera_velocity, np.float64).reshape(-1)
        if cam_vel.shape != (3,) or not np.all(np.abs(cam_vel) <= MAX_F32_MAGNITUDE):
            raise ValueError(f"camera_velocity must be a finite [3] velocity within +-{MAX_F32_MAGNITUDE:g} m/s, "
                             f"got {camera_velocity!r}")
        cam_speed = float(np.linalg.norm(cam_vel))
        reach = self.max_extent(exposure_s=exposure_s, camera_speed=cam_speed)
        if not (self._speed_max + self._flutter_speed + cam_speed <= MAX_F32_MAGNITUDE
                and reach <= MAX_F32_MAGNITUDE):
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
            short_ratio = SHORT_OVER_LONG if spec.kind == "snow" else 1.0
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
                base = np.stack([long, long * SHORT_OVER_LONG, long * SHORT_OVER_LONG], 1)
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
            spin = quat_about_z(angle[:, None] + arms[None, :])  # [K, 3, 4]
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



# --------------------------------------------------------------------------------------------
# numba kernels (the numpy code above is their reference)


def _numba_kernels() -> Any:
    """The compiled kernels' module, or ``None`` when numba is unavailable (numpy is used)."""
    return load_numba_kernels("weather.particle_kernels")
