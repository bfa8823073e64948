"""``filter2d``: a classical image-space weather baseline (no 3D, no learning).

Each frame is edited on its own, as 2D photo filters do:

* fog: Beer-Lambert with a flat-ground distance guess per image row (rows above the horizon are
  treated as far away), t = exp(-beta d), C = t I + (1 - t) c_fog, at the visibility and colour of
  the scene's requested fog (the run's one weather spec, :mod:`wcbench.methods.weather_spec`: on a
  ``synth_*`` scene the 150 m its truth was made with, elsewhere the fog preset's) unless
  ``visibility_m`` says otherwise;
* rain: darker, bluer, lower-contrast image plus seeded motion-blurred streaks;
* snow: brighter, lower-contrast image plus seeded soft flakes.

Rain and snow are 2D grades with no rate: ``info.json`` records them as unverified against the
requested rate (``parameters.physics``).

Streaks and flakes are drawn afresh per frame from (seed, frame), so the baseline is deterministic
but, like any per-frame editor, not temporally coherent: exactly what flicker metrics should see.

Two options make it a stand-in for a 2D editor's output as training supervision (the WeatherCity
method trains on edited frames): ``effects=False`` leaves out the streaks and flakes (particles
come from the physics, as the paper's edited backgrounds leave them out), and ``jitter`` in [0, 1]
adds seeded per-frame tone, color and local-structure perturbations, the way frame-by-frame
editors flicker. Its pieces (:func:`tone_jitter`, :func:`smooth_warp`, :func:`smear_blotches`) and
:func:`overlay_strokes` are public: ``sim-editor`` (:mod:`wcbench.methods.sim_editor`) builds its
simulated editor errors from them.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, ClassVar

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, to_uint8
from wcbench.core.options import Option, Range
from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer
from wcbench.methods.weather_spec import physics_record, resolve_physics
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.fog import visibility_from_density
from wcbench.scenes.scene import Scene

FOG_COLOR = (0.80, 0.80, 0.85)  # paper's c_fog (also the fog preset's colour)
_PARAMS: dict[str, dict[str, Any]] = {
    "clear": {},
    # the visibility and colour come from the scene's requested fog (:meth:`Filter2DMethod.fog_weather`)
    "fog": {"camera_height_m": 1.6, "far_m": 1000.0},
    "rain": {"darken": 0.78, "tint": (0.92, 0.96, 1.05), "streaks_per_megapixel": 1500, "streak_px": 0.06},
    "snow": {"brighten": 0.12, "flakes_per_megapixel": 2500, "flake_px": 0.004},
}


def _rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, index, 0x2D])


def fog_filter(img: np.ndarray, K: np.ndarray, *, visibility_m: float, fog_color: tuple[float, float, float],
               camera_height_m: float, far_m: float) -> np.ndarray:
    """Flat-ground Beer-Lambert fog on float RGB.

    Parameters
    ----------
    img : ndarray [H, W, 3] float
        RGB in [0, 1].
    K : ndarray [3, 3]
        Camera intrinsics of ``img`` (px).
    visibility_m : float
        Visibility V (m), beta = 2.996 / V (``inf``: no fog).
    fog_color : (float, float, float)
        RGB of the fog in [0, 1].
    camera_height_m : float
        Height of the camera above the assumed flat ground (m): row r below the principal point is
        at distance h f_y / (r - c_y).
    far_m : float
        Distance of the rows at or above the horizon, and the cap of every distance (m).

    Returns
    -------
    ndarray [H, W, 3] float64
        t I + (1 - t) c_fog with t = exp(-beta d) per row.
    """
    h = img.shape[0]
    beta = 2.996 / visibility_m
    rows = np.arange(h, dtype=np.float64) + 0.5 - K[1, 2]
    with np.errstate(divide="ignore"):
        dist = np.where(rows > 0, camera_height_m * K[1, 1] / rows, far_m)
    t = np.exp(-beta * np.minimum(dist, far_m))[:, None, None]
    return t * img + (1 - t) * np.asarray(fog_color)


def overlay_strokes(img: np.ndarray, rng: np.random.Generator, *, count: int, length: float, angle: float,
                    thickness: int, intensity: float, blur: int) -> np.ndarray:
    """Draw ``count`` seeded straight strokes (rain streaks, or snowflakes when short and thick).

    Parameters
    ----------
    img : ndarray [H, W, 3] float
        RGB in [0, 1].
    rng : numpy.random.Generator
        Where the stroke positions and lengths come from (three draws of ``count`` values).
    count : int
        Number of strokes.
    length : float
        Longest stroke in pixels (each is 0.5-1 times it).
    angle : float
        Radians from the image's down direction (positive: leaning right).
    thickness : int
        Line width in pixels.
    intensity : float
        Opacity of a stroke's core.
    blur : int
        Gaussian blur kernel of the stroke layer (softens edges; <= 1: none).

    Returns
    -------
    ndarray [H, W, 3] float
        ``img`` blended toward near-white (0.9) under the strokes.
    """
    h, w = img.shape[:2]
    layer = np.zeros((h, w), np.float32)
    xs, ys = rng.uniform(0, w, count), rng.uniform(0, h, count)
    ls = length * rng.uniform(0.5, 1.0, count)
    dx, dy = np.sin(angle), np.cos(angle)
    for x, y, ln in zip(xs, ys, ls):
        cv2.line(layer, (int(x), int(y)), (int(x + dx * ln), int(y + dy * ln)), 1.0, thickness, cv2.LINE_AA)
    if blur > 1:
        layer = cv2.GaussianBlur(layer, (blur | 1, blur | 1), 0)
    a = np.clip(layer * intensity, 0, 1)[..., None]
    return img * (1 - a) + a * 0.9


def tone_jitter(img: np.ndarray, rng: np.random.Generator, strength: float, *, contrast: float = 0.08,
                exposure: float = 0.08, channel: float = 0.04) -> np.ndarray:
    """A seeded per-frame change of contrast, exposure and per-channel gain (an editor's grade drifting).

    Parameters
    ----------
    img : ndarray [H, W, 3] float32
        RGB in [0, 1].
    rng : numpy.random.Generator
        Five normal draws: contrast, exposure, then three channel gains.
    strength : float
        Multiplies every standard deviation (0: unchanged, though the draws are still made).
    contrast, exposure, channel : float
        Standard deviations of the relative contrast, exposure and channel gain changes at strength 1.

    Returns
    -------
    ndarray [H, W, 3] float32
        Not clipped.
    """
    s = float(strength)
    mean = float(img.mean())
    out = (img - mean) * (1.0 + s * rng.normal(0.0, contrast)) + mean
    return out * (1.0 + s * rng.normal(0.0, exposure)) * (1.0 + s * rng.normal(0.0, channel, 3)).astype(np.float32)


def smooth_warp(img: np.ndarray, rng: np.random.Generator, amplitude: float, *, grid: tuple[int, int] = (4, 6),
                weight: np.ndarray | None = None) -> np.ndarray:
    """Displace ``img`` by a seeded smooth random field (structures wobble by a few pixels).

    Parameters
    ----------
    img : ndarray [H, W, 3] float
    rng : numpy.random.Generator
        Two draws of ``grid`` normals (x, then y displacement), upsampled bicubically.
    amplitude : float
        Standard deviation of the displacement in pixels.
    grid : (int, int)
        Rows and columns of the random field before upsampling (more: finer, more local wobble).
    weight : ndarray [H, W] float, optional
        Scales the displacement per pixel (0: the pixel stays exactly where it is).

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    h, w = img.shape[:2]
    field = [cv2.resize(rng.normal(0.0, 1.0, grid).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
             for _ in range(2)]
    dx, dy = amplitude * field[0], amplitude * field[1]
    if weight is not None:
        dx, dy = dx * weight, dy * weight
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(img.astype(np.float32), gx + dx, gy + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def smear_blotches(img: np.ndarray, rng: np.random.Generator, strength: float, *, rate: float = 3.0,
                   local: bool = False) -> np.ndarray:
    """Smear local structure away in a few seeded soft ellipses (an editor erasing what was there).

    Parameters
    ----------
    img : ndarray [H, W, 3] float32
    rng : numpy.random.Generator
        A Poisson count, then five draws per ellipse.
    strength : float
        Scales the expected count (``rate * strength``) and the opacity (``min(1, 0.8 strength)``).
    rate : float
        Expected number of ellipses at strength 1.
    local : bool
        Blur only around the ellipses instead of the whole frame (a full-HD frame's smear blur
        alone takes 0.2 s). The result matches the whole-frame blur to float rounding (OpenCV's
        vectorised blur rounds a crop's pixels slightly differently), so :func:`jitter_frame`
        keeps the whole-frame blur and with it filter2d's frames to the bit.

    Returns
    -------
    ndarray [H, W, 3] float32
        Clipped to [0, 1].
    """
    s = float(strength)
    h, w = img.shape[:2]
    sigma_mask, sigma_smear = max(1.0, 0.01 * h), max(1.0, 0.02 * h)
    smeared = None if local else cv2.GaussianBlur(img, (0, 0), sigma_smear)
    mask = np.zeros((h, w), np.float32)
    for _ in range(int(rng.poisson(rate * s))):
        center = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        axes = (max(1, int(rng.uniform(0.03, 0.08) * h)), max(1, int(rng.uniform(0.03, 0.08) * h)))
        cv2.ellipse(mask, center, axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    if smeared is not None:
        mask = cv2.GaussianBlur(mask, (0, 0), sigma_mask)[..., None] * min(1.0, 0.8 * s)
        return np.clip(img * (1 - mask) + smeared * mask, 0.0, 1.0)
    out = np.clip(img, 0.0, 1.0)
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return out
    # the blurred mask reaches one kernel radius beyond the ellipses; outside that the frame is kept
    r_mask = _gauss_radius(sigma_mask)
    y0, y1 = max(0, int(rows.min()) - r_mask), min(h, int(rows.max()) + 1 + r_mask)
    x0, x1 = max(0, int(cols.min()) - r_mask), min(w, int(cols.max()) + 1 + r_mask)
    soft = _blur_region(mask, (y0, y1, x0, x1), r_mask, sigma_mask)[..., None] * min(1.0, 0.8 * s)
    part = _blur_region(img, (y0, y1, x0, x1), _gauss_radius(sigma_smear), sigma_smear)
    out[y0:y1, x0:x1] = np.clip(img[y0:y1, x0:x1] * (1 - soft) + part * soft, 0.0, 1.0)
    return out


def _gauss_radius(sigma: float) -> int:
    """Half the kernel OpenCV's GaussianBlur picks for float images with ksize (0, 0), plus one pixel
    (a margin too wide costs nothing; one too narrow would cut the kernel)."""
    return (round(sigma * 4 * 2 + 1) | 1) // 2 + 1


def _blur_region(img: np.ndarray, box: tuple[int, int, int, int], radius: int, sigma: float) -> np.ndarray:
    """``cv2.GaussianBlur(img, (0, 0), sigma)[y0:y1, x0:x1]`` (to float rounding), blurring only the
    box and a margin of ``radius`` around it (the image's own border handling where it leaves it)."""
    h, w = img.shape[:2]
    y0, y1, x0, x1 = box
    py0, py1, px0, px1 = max(0, y0 - radius), min(h, y1 + radius), max(0, x0 - radius), min(w, x1 + radius)
    part = cv2.GaussianBlur(np.ascontiguousarray(img[py0:py1, px0:px1]), (0, 0), sigma)
    return part[y0 - py0:y1 - py0, x0 - px0:x1 - px0]


def jitter_frame(img: np.ndarray, rng: np.random.Generator, strength: float) -> np.ndarray:
    """A frame-by-frame editor's inconsistency on float RGB [H, W, 3]: seeded exposure, contrast and
    per-channel gain changes, a smooth displacement of a few pixels (structures wobble) and a few
    blotches where local structure is smeared away. ``strength`` 0 returns the frame unchanged."""
    if strength <= 0:
        return img
    s = float(strength)
    out = tone_jitter(img, rng, s)
    out = smooth_warp(out, rng, 2.0 * s * img.shape[0] / 270.0)  # px, relative to a 270-row frame
    return smear_blotches(out, rng, s)


class Filter2DMethod(FrameRenderer):
    """Per-frame image filters for rain, snow and fog (see module docstring).

    Parameters
    ----------
    effects : bool
        Draw rain streaks and snowflakes (``False``: the weather's grade only).
    jitter : float
        Strength in [0, 1] of the per-frame perturbations of :func:`jitter_frame`.
    visibility_m : float, optional
        Fog visibility (m), winning over the scene's requested one. The default is the fog every
        method resolves for the scene (``resolve_physics(scene, "auto")``: the weather a scene's
        truth requested where it records one, 150 m on the ``synth_*`` scenes, else the fog
        preset's, 150 m); WeatherCity trained on filter2d sets its physics fog's.
    """

    info = MethodInfo(
        name="filter2d",
        description="Classical image-space weather filters (per-frame 2D baseline)",
        kind="runnable",
        weathers=WEATHERS,
        layout="writes <out>/filter2d/<scene>/<weather>/{frame:03d}.png + info.json",
    )

    OPTIONS: ClassVar[dict[str, Option]] = {
        "effects": Option("effects", "bool", "draw the rain streaks and snowflakes", default=True),
        "jitter": Option("jitter", "float", "seeded per-frame tone, colour and structure perturbation",
                         default=0.0, range=Range(0, 1)),
        "visibility_m": Option("visibility_m", "float", "fog visibility (m); default the scene's requested fog's",
                               range=Range(0, low_open=True), nullable=True),
    }

    def __init__(self, *, effects: bool = True, jitter: float = 0.0, visibility_m: float | None = None):
        if not 0.0 <= float(jitter) <= 1.0:
            raise InputError(f"filter2d: jitter must be in [0, 1], got {jitter}")
        if visibility_m is not None and not 0 < float(visibility_m) < float("inf"):
            raise InputError(f"filter2d: visibility_m must be a finite visibility > 0 m, got {visibility_m}")
        self.effects, self.jitter = bool(effects), float(jitter)
        self.visibility_m = None if visibility_m is None else float(visibility_m)
        self._fog: dict[str, tuple[Weather, float, tuple[float, float, float]]] = {}

    def parameters(self, weather: str) -> dict[str, Any]:
        """The filter settings used for ``weather`` (the fog's weather: :meth:`physics`)."""
        out = dict(_PARAMS[weather])
        if weather == "fog":
            out["visibility_m"] = self.visibility_m if self.visibility_m is not None else "the scene's requested"
        if not self.effects or self.jitter:  # the defaults leave the record (and render keys) as they were
            out.update(effects=self.effects, jitter=self.jitter)
        return out

    def fog_weather(self, scene: Scene) -> tuple[Weather, float, tuple[float, float, float]]:
        """The fog ``scene`` is filtered with: (Weather, visibility m, RGB colour in [0, 1]).

        The scene's requested fog (``resolve_physics(scene, "auto")``, the same resolved weather as
        every other method's), its visibility replaced by ``visibility_m`` when that is given;
        ``inf`` m when the weather has no haze. Read once per scene folder.
        """
        key = str(scene.root)
        if key not in self._fog:
            # filter2d draws no physics particles: the seed is not used (draws=False)
            fog = resolve_physics(scene, "auto", draws=False)["fog"]
            if self.visibility_m is not None:
                fog = replace(fog, visibility_m=self.visibility_m, fog_density=None)
            beta, color, _ = fog.haze()
            visibility = visibility_from_density(beta) if beta > 0 else math.inf
            self._fog[key] = (fog, visibility, (float(color[0]), float(color[1]), float(color[2])))
        return self._fog[key]

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """Fog: the physics record of the fog it filters with. Rain and snow: 2D grades with no rate,
        recorded as unverified next to the weather the scene requested. Clear: none."""
        if weather == "clear":
            return "none: clear is the raw frame"
        if weather == "fog":
            return physics_record(self.fog_weather(scene)[0])
        requested = resolve_physics(scene, "auto", seed=seed, draws=False)[weather]
        rate = requested.precipitation_rate()
        return {"unverified": f"filter2d's {weather} is a 2D grade with no rate: not checked against the "
                              f"requested {rate:g} mm/h", "requested": physics_record(requested)}

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> np.ndarray:
        """Edit raw frame ``index``; uint8 RGB out."""
        raw = read_rgb8(scene.frames[index].image_path).astype(np.float32) / 255.0
        p = _PARAMS[weather]
        out: np.ndarray
        if weather == "clear":
            out = raw
        elif weather == "fog":
            _, visibility, color = self.fog_weather(scene)
            out = fog_filter(raw, scene.frames[index].camera.K, visibility_m=visibility, fog_color=color, **p)
        else:
            h, w = raw.shape[:2]
            mpx = h * w / 1e6
            rng = _rng(seed, index)
            gray = raw.mean(axis=2, keepdims=True)
            if weather == "rain":
                out = (0.7 * raw + 0.3 * gray) * p["darken"] * np.asarray(p["tint"], np.float32)
                if self.effects:
                    out = overlay_strokes(out, rng, count=max(1, int(p["streaks_per_megapixel"] * mpx)),
                                          length=p["streak_px"] * h, angle=0.15, thickness=1, intensity=0.35,
                                          blur=3)
            else:
                out = raw * (1 - p["brighten"]) + p["brighten"]
                if self.effects:
                    out = overlay_strokes(out, rng, count=max(1, int(p["flakes_per_megapixel"] * mpx)),
                                          length=max(1.0, p["flake_px"] * h), angle=0.3,
                                          thickness=max(1, int(p["flake_px"] * h)), intensity=0.8, blur=3)
        if self.jitter:
            # its own stream: jitter does not move the streaks of the same seed
            out = jitter_frame(np.asarray(out, np.float32), np.random.default_rng([seed, index, 0x71]), self.jitter)
        return to_uint8(np.asarray(out))
