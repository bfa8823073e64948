"""``sim-editor``: a simulated frame-by-frame 2D weather editor, with a severity knob.

Real 2D editors (diffusion image editors run frame by frame) get the weather roughly right but make
errors no single frame shows: each frame is edited on its own. ``sim-editor`` reproduces those
errors on top of the **ground truth** of the weather (``Scene.references``; the raw frames for
``clear``), so that how far a metric moves with ``severity`` can be checked against how far the
frames really are from the truth (the validity table). Per frame, from seeded streams of
(seed, frame, weather), it applies:

* **warps** of the structures an editor redraws: a smooth random displacement field weighted to the
  vehicles (the scene's dynamic masks, when present) and the lane lines (bright, low-saturation
  thin marks in the lower half of the raw frame); a global smooth warp when neither is found;
* **hallucinated structures**: feathered patches of the frame pasted somewhere else;
* **erased structures**: soft ellipses where local structure is smeared away;
* **flickering weather**: rain streaks or snowflakes drawn afresh every frame on top of the truth's
  physically simulated ones, and for fog a per-frame haze density change;
* **tone and colour jitter**: per-frame contrast, exposure and per-channel gain changes.

``severity`` in [0, 1] scales every amplitude and the expected number of local errors; 0 returns
the truth frames exactly. The tone changes, the warp fields and the candidate patches of a frame
are the same draws at every severity (amplitudes scaled by it; a patch kept when its uniform draw
is below it), so a higher severity makes the same errors larger and adds more; the erased spots
and particles grow in expected number. Distance to the truth grows steadily with the severity.

The frames can also be WeatherCity's training supervision (``--supervision sim-editor:0.3``,
:func:`supervision_frames`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, resize_rgb8, to_uint8
from wcbench.core.options import Option, Range
from wcbench.core.storage import sha256_file, sha256_json
from wcbench.core.weathers import WEATHERS
from wcbench.methods.filter2d import FOG_COLOR, overlay_strokes, smear_blotches, smooth_warp, tone_jitter
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer
from wcbench.methods.weather_spec import truth_draw
from wcbench.scenes.scene import Scene

__all__ = [
    "DEFAULT_SEVERITY", "ERRORS", "NAME", "SimEditorMethod", "edit_frame", "lane_mask", "structure_weight",
    "supervision_frames", "supervision_severity", "truth_paths", "warp_structures",
]

NAME = "sim-editor"
#: Bumped whenever the same (truth, seed, severity) would give other frames.
VERSION = "1"
DEFAULT_SEVERITY = 0.5
#: Error amplitudes at severity 1 (each scales linearly with the severity). Pixel amounts are for a
#: 270-row frame and scale with the frame height.
ERRORS: dict[str, dict[str, Any]] = {
    "tone": {"contrast_sd": 0.10, "exposure_sd": 0.10, "channel_sd": 0.05},
    "warp": {"structure_px": 4.0, "global_px": 2.0, "structure_grid": [6, 10], "global_grid": [4, 6]},
    "hallucinated": {"candidates": 6, "rows": [0.05, 0.14]},
    "erased": {"rate": 4.0},
    "particles": {
        "rain": {"per_megapixel": 1500, "length_rows": 0.06, "angle": 0.15, "angle_sd": 0.15, "thickness_rows": 0.0,
                 "intensity": 0.35},
        "snow": {"per_megapixel": 2500, "length_rows": 0.004, "angle": 0.3, "angle_sd": 0.3, "thickness_rows": 0.004,
                 "intensity": 0.8},
    },
    "haze": {"fog_sd": 0.08},
}
#: Per-error stream tags: each error draws from its own generator, so changing one (or how many
#: draws it makes at a severity) never moves another.
_STREAMS = {"tone": 1, "warp": 2, "hallucinated": 3, "erased": 4, "particles": 5, "haze": 6}
#: Structure detection works at most at this many rows (the weight is smooth anyway; large frames
#: would make the morphology slow for nothing).
_DETECT_ROWS = 360


def _rng(seed: int, index: int, weather: str, stream: str) -> np.random.Generator:
    # the weather is part of the stream: an editor's errors under rain are not those under snow
    return np.random.default_rng([seed, index, WEATHERS.index(weather), _STREAMS[stream], 0x5E])


def supervision_severity(spec: str) -> float | None:
    """The severity of a ``--supervision`` value naming sim-editor, else ``None``.

    Parameters
    ----------
    spec : str
        ``"sim-editor"`` (the default severity), ``"sim-editor:SEVERITY"`` (e.g. ``"sim-editor:0.3"``)
        or anything else (``"filter2d"``, ``READER:DIR``), which is not sim-editor's.

    Returns
    -------
    float or None

    Raises
    ------
    InputError
        If the severity is not a number in [0, 1].
    """
    name, sep, value = spec.partition(":")
    if name != NAME:
        return None
    if not sep:
        return DEFAULT_SEVERITY
    try:
        severity = float(value)
    except ValueError:
        raise InputError(f"--supervision {spec!r}: the severity must be a number in [0, 1] "
                         f"(e.g. {NAME}:0.3)") from None
    if not 0.0 <= severity <= 1.0:
        raise InputError(f"--supervision {spec!r}: the severity must be in [0, 1], got {value}")
    return severity


def _check_severity(severity: float) -> float:
    try:
        s = float(severity)
    except (TypeError, ValueError):
        raise InputError(f"{NAME}: severity must be a number in [0, 1], got {severity!r}") from None
    if not 0.0 <= s <= 1.0:
        raise InputError(f"{NAME}: severity must be in [0, 1], got {severity}")
    return s


def truth_paths(scene: Scene, weather: str) -> list[Path]:
    """The ground-truth frames sim-editor edits for ``weather`` (the raw frames for ``clear``).

    Raises
    ------
    InputError
        The scene has no truth of ``weather``, or not one per frame.
    """
    paths = scene.reference_paths(weather)
    if paths is None:
        have = ", ".join(["clear (the raw frames)", *sorted(scene.references)])
        raise InputError(
            f"{NAME} needs ground-truth frames of {weather!r}, and scene {scene.id!r} has none (it has truth "
            f"for: {have}). The synth_* scene sets ship truth frames of every weather; on other scenes run "
            f"it with --weathers clear"
        )
    if len(paths) != len(scene):
        raise InputError(f"{NAME}: scene {scene.id!r} has {len(paths)} ground-truth frames of {weather!r} "
                         f"for {len(scene)} frames")
    return list(paths)


def _read_mask(path: Path, size: tuple[int, int]) -> np.ndarray:
    """A mask file (nonzero = set) as bool [H, W] at ``size`` (width, height)."""
    data = np.fromfile(path, dtype=np.uint8) if path.is_file() else np.zeros(0, np.uint8)
    mask = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if mask is None:
        raise InputError(f"{path}: not a readable mask image")
    if mask.shape[::-1] != size:
        mask = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
    return mask > 0


def lane_mask(raw: np.ndarray) -> np.ndarray:
    """Lane-line pixels of a frame: bright, low-saturation thin marks in its lower half.

    A white top-hat finds marks brighter than the road around them, so a bright (snowy or sunlit)
    road as a whole is not taken for a marking.

    Parameters
    ----------
    raw : ndarray [H, W, 3] uint8
        RGB frame.

    Returns
    -------
    ndarray [H, W] bool
    """
    h = raw.shape[0]
    hsv = cv2.cvtColor(raw, cv2.COLOR_RGB2HSV)
    sat, val = hsv[..., 1], hsv[..., 2]
    k = max(3, h // 12) | 1  # wider than a lane line near the camera
    tophat = cv2.morphologyEx(val, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    marks = (tophat > 40) & (sat < 60) & (val > 120)
    marks[: h // 2] = False  # road markings are below the horizon of a forward camera
    return marks


def structure_weight(raw: np.ndarray, dynamic: np.ndarray | None) -> tuple[np.ndarray | None, list[str]]:
    """Where an editor's structure warps go: the vehicles (``dynamic``) and the lane lines of ``raw``.

    Parameters
    ----------
    raw : ndarray [H, W, 3] uint8
        The raw frame (what an editor takes in and redraws).
    dynamic : ndarray [H, W] bool, optional
        The scene's dynamic-object mask of the frame.

    Returns
    -------
    weight : ndarray [H, W] float32 or None
        1 on and just around the structures, falling smoothly to 0 (a warp near them pulls their
        edges too); ``None`` when neither is found.
    targets : list of str
        ``"lane lines"`` and/or ``"vehicles"``, or ``["global"]`` when ``weight`` is ``None``.
    """
    h, w = raw.shape[:2]
    scale = min(1.0, _DETECT_ROWS / h)
    small = (max(1, round(w * scale)), max(1, round(h * scale)))
    img = raw if scale == 1.0 else resize_rgb8(raw, small)
    found = np.zeros(small[::-1], bool)
    targets = []
    lanes = lane_mask(img)
    if lanes.sum() >= max(4, lanes.size // 10_000):  # a few speckles are not lane lines
        found |= lanes
        targets.append("lane lines")
    if dynamic is not None and dynamic.any():
        if scale != 1.0:
            dynamic = cv2.resize(dynamic.astype(np.uint8), small, interpolation=cv2.INTER_NEAREST) > 0
        found |= dynamic
        targets.append("vehicles")
    if not targets:
        return None, ["global"]
    sh = small[1]
    r = max(1, round(0.02 * sh))
    grown = cv2.dilate(found.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    weight = cv2.GaussianBlur(grown.astype(np.float32), (0, 0), max(1.0, 0.01 * sh))
    weight = np.clip(weight / max(float(weight.max()), 1e-6), 0.0, 1.0)
    if scale != 1.0:
        weight = cv2.resize(weight, (w, h), interpolation=cv2.INTER_LINEAR)
    return weight, targets


def warp_structures(img: np.ndarray, rng: np.random.Generator, severity: float,
                    weight: np.ndarray | None) -> np.ndarray:
    """Wobble the structures under ``weight`` by a smooth random field; the whole frame when ``None``.

    Parameters
    ----------
    img : ndarray [H, W, 3] float32
    rng : numpy.random.Generator
    severity : float
        In [0, 1]; the displacement's standard deviation is ``severity`` times ``ERRORS["warp"]``'s
        pixels (scaled to the frame height).
    weight : ndarray [H, W] float32, optional
        From :func:`structure_weight`; pixels where it is 0 do not move.

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    p, rows = ERRORS["warp"], img.shape[0] / 270.0
    if weight is None:
        return smooth_warp(img, rng, severity * p["global_px"] * rows, grid=tuple(p["global_grid"]))
    return smooth_warp(img, rng, severity * p["structure_px"] * rows, grid=tuple(p["structure_grid"]), weight=weight)


def paste_patches(img: np.ndarray, rng: np.random.Generator, severity: float) -> tuple[np.ndarray, int]:
    """Hallucinate structures: feathered patches of the frame pasted elsewhere in it.

    Every candidate of ``ERRORS["hallucinated"]`` is drawn whatever the severity and kept when its
    uniform draw is below it, so a lower severity's patches are a subset of a higher one's.

    Returns
    -------
    out : ndarray [H, W, 3] float32
    count : int
        Patches pasted.
    """
    h, w = img.shape[:2]
    p = ERRORS["hallucinated"]
    out = img.copy()
    count = 0
    for _ in range(p["candidates"]):
        keep = rng.uniform() < severity
        ph = min(h, max(4, int(rng.uniform(*p["rows"]) * h)))
        pw = min(w, max(4, int(ph * rng.uniform(1.0, 2.0))))
        sy, sx = int(rng.integers(0, h - ph + 1)), int(rng.integers(0, w - pw + 1))
        dy, dx = int(rng.integers(0, h - ph + 1)), int(rng.integers(0, w - pw + 1))
        if not keep:
            continue
        alpha = np.zeros((ph, pw), np.float32)
        cv2.ellipse(alpha, (pw // 2, ph // 2), (max(1, pw // 2 - 1), max(1, ph // 2 - 1)), 0.0, 0, 360, 1.0, -1)
        alpha = cv2.GaussianBlur(alpha, (0, 0), max(1.0, 0.15 * min(ph, pw)))[..., None] * (0.6 + 0.4 * severity)
        src = img[sy:sy + ph, sx:sx + pw]
        out[dy:dy + ph, dx:dx + pw] = out[dy:dy + ph, dx:dx + pw] * (1 - alpha) + src * alpha
        count += 1
    return out, count


def _particles(img: np.ndarray, rng: np.random.Generator, severity: float, weather: str) -> tuple[np.ndarray, int]:
    """Rain streaks or snowflakes drawn afresh for this frame alone (they flicker)."""
    p = ERRORS["particles"][weather]
    h, w = img.shape[:2]
    count = round(severity * p["per_megapixel"] * h * w / 1e6)
    angle = p["angle"] + severity * rng.normal(0.0, p["angle_sd"])  # the editor's wind changes per frame
    if count == 0:
        return img, 0
    out = overlay_strokes(img, rng, count=count, length=max(1.0, p["length_rows"] * h), angle=angle,
                          thickness=max(1, int(p["thickness_rows"] * h)), intensity=p["intensity"], blur=3)
    return out, count


def _haze(img: np.ndarray, rng: np.random.Generator, severity: float) -> np.ndarray:
    """Fog whose density changes per frame: toward the fog colour or away from it."""
    a = severity * rng.normal(0.0, ERRORS["haze"]["fog_sd"])
    return img + np.float32(a) * (np.asarray(FOG_COLOR, np.float32) - img)


def edit_frame(truth: np.ndarray, raw: np.ndarray, weather: str, *, severity: float, seed: int, index: int,
               dynamic: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """The simulated editor's frame: ``truth`` with seeded per-frame errors (see the module docstring).

    Parameters
    ----------
    truth : ndarray [H, W, 3] uint8
        The ground-truth frame of ``weather``.
    raw : ndarray [H, W, 3] uint8
        The raw frame (the editor's input: where its lane lines are found).
    weather : str
    severity : float
        In [0, 1]; 0 returns ``truth`` itself.
    seed, index : int
        The errors are a pure function of (seed, index, weather, severity).
    dynamic : ndarray [H, W] bool, optional
        Vehicles (the scene's dynamic mask): warped with the lane lines.

    Returns
    -------
    image : ndarray [H, W, 3] uint8
    facts : dict
        What was drawn: warp targets, pasted patches, particles.
    """
    if severity <= 0:
        return truth, {}
    s = float(severity)
    out = truth.astype(np.float32) / 255.0
    weight, targets = structure_weight(raw, dynamic)
    out = warp_structures(out, _rng(seed, index, weather, "warp"), s, weight)
    out, patches = paste_patches(out, _rng(seed, index, weather, "hallucinated"), s)
    out = smear_blotches(out, _rng(seed, index, weather, "erased"), s, rate=ERRORS["erased"]["rate"], local=True)
    facts: dict[str, Any] = {"warp": targets, "patches": patches}
    if weather in ERRORS["particles"]:
        out, facts["particles"] = _particles(out, _rng(seed, index, weather, "particles"), s, weather)
    elif weather == "fog":
        out = _haze(out, _rng(seed, index, weather, "haze"), s)
    t = ERRORS["tone"]
    out = tone_jitter(out, _rng(seed, index, weather, "tone"), s, contrast=t["contrast_sd"],
                      exposure=t["exposure_sd"], channel=t["channel_sd"])
    return to_uint8(np.clip(out, 0.0, 1.0)), facts


class SimEditorMethod(FrameRenderer):
    """A simulated per-frame 2D editor: the truth frames with an editor's errors (module docstring).

    Parameters
    ----------
    severity : float
        In [0, 1]: how large and how many the errors are; 0 gives the truth frames exactly.
    """

    info = MethodInfo(
        name=NAME,
        description="Simulated per-frame 2D editor: the truth frames with jitter, warps, hallucinations, "
                    "flicker (severity 0-1; needs ground truth, e.g. synth_* scenes)",
        kind="runnable",
        weathers=WEATHERS,
        layout=f"writes <out>/{NAME}/<scene>/<weather>/{{frame:03d}}.png + info.json; reads the scene's "
               "ground-truth frames of the weather (Scene.references; the raw frames for clear)",
    )
    version = VERSION

    OPTIONS: ClassVar[dict[str, Option]] = {
        "severity": Option("severity", "float", "amplitude of every simulated editor error (0: none)",
                           default=DEFAULT_SEVERITY, range=Range(0, 1)),
    }

    def __init__(self, *, severity: float = DEFAULT_SEVERITY):
        self.severity = _check_severity(severity)

    def parameters(self, weather: str) -> dict[str, Any]:
        """The severity, what is edited and the error amplitudes at this severity for ``weather``."""
        s = self.severity
        errors: dict[str, Any] = {
            "tone": {k: round(s * v, 6) for k, v in ERRORS["tone"].items()},
            "warp_px_at_270_rows": {"structures": round(s * ERRORS["warp"]["structure_px"], 6),
                                    "global": round(s * ERRORS["warp"]["global_px"], 6)},
            "hallucinated_patches_expected": round(s * ERRORS["hallucinated"]["candidates"], 6),
            "erased_expected": round(s * ERRORS["erased"]["rate"], 6),
        }
        if weather in ERRORS["particles"]:
            errors["particles_per_megapixel"] = round(s * ERRORS["particles"][weather]["per_megapixel"], 6)
        elif weather == "fog":
            errors["haze_sd"] = round(s * ERRORS["haze"]["fog_sd"], 6)
        return {"severity": s, "truth": "raw frames" if weather == "clear" else "scene references",
                "errors": errors}

    def _key(self, scene: Scene, weather: str, seed: int, frames: list[int]) -> str:
        """The render key over the truth frames too: they, not the raw frames, are what is edited
        (a regenerated truth must not leave old frames standing). Fails on a scene without truth
        before any folder is made."""
        key = super()._key(scene, weather, seed, frames)
        if weather == "clear":
            return key  # its truth is the raw frames, already in the key
        return sha256_json({"render": key, "truth": [sha256_file(p) for p in truth_paths(scene, weather)]})

    def check_scene(self, scene: Scene, weather: str) -> None:
        """The scene must have truth frames of ``weather`` (checked for every unit before any render)."""
        truth_paths(scene, weather)

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """None of its own: it edits the truth frames, whatever weather made them."""
        if weather == "clear":
            return "none: clear is the raw frame with an editor's errors"
        return f"none: {NAME} renders no weather; it edits the scene's ground-truth frames of {weather}"

    def truth_draw(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any]:
        """It reads the truth frames (their particles included): a calibration instrument of the
        validity bench, not a competitor."""
        if weather == "clear":
            return truth_draw(scene, None)
        return truth_draw(scene, None, reads=(
            f"reads the scene's ground-truth frames of {weather} (truth/{weather}/, the truth's own particles "
            "included) and adds an editor's errors: a calibration instrument of the validity bench, not a "
            "competitor"))

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:
        """Check the scene has truth frames of ``weather`` before any frame is drawn."""
        truth_paths(scene, weather)

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Frame ``index``: the truth of ``weather`` with this frame's errors; uint8 RGB and facts."""
        frame = scene.frames[index]
        raw = read_rgb8(frame.image_path)
        truth = raw if weather == "clear" else read_rgb8(truth_paths(scene, weather)[index])
        if truth.shape != raw.shape:
            truth = resize_rgb8(truth, (raw.shape[1], raw.shape[0]))  # a truth rendered at another size
        dynamic = None
        if frame.dynamic_mask_path is not None and self.severity > 0:
            dynamic = _read_mask(Path(frame.dynamic_mask_path), (raw.shape[1], raw.shape[0]))
        return edit_frame(truth, raw, weather, severity=self.severity, seed=seed, index=index, dynamic=dynamic)


def supervision_frames(scene: Scene, severity: float, weathers: Sequence[str],
                       seed: int) -> tuple[dict[str, list[np.ndarray]], dict[str, Any]]:
    """sim-editor's frames of every weather of ``weathers`` the scene has truth of, as training supervision.

    Parameters
    ----------
    scene : Scene
    severity : float
        In [0, 1].
    weathers : sequence of str
        The weathers to supervise; those without truth frames are left out and named in the record.
    seed : int

    Returns
    -------
    frames : dict of str to list of ndarray
        uint8 RGB frames per supervised weather, one per scene frame.
    record : dict
        ``method``, ``severity``, ``seed``, ``version``, per-weather ``parameters``, the sha256 of the
        ``truth`` frames edited, and ``not_supervised`` (weather -> why).

    Raises
    ------
    InputError
        When no weather of ``weathers`` has truth frames (nothing could be supervised).
    """
    editor = SimEditorMethod(severity=severity)
    frames: dict[str, list[np.ndarray]] = {}
    truth: dict[str, list[str]] = {}
    missing: dict[str, str] = {}
    for w in weathers:
        try:
            paths = truth_paths(scene, w)
        except InputError as exc:
            missing[w] = str(exc)
            continue
        frames[w] = [editor.render_frame(scene, w, k, seed=seed)[0] for k in range(len(scene))]
        truth[w] = [sha256_file(p) for p in paths]
    if weathers and not frames:
        raise InputError(f"--supervision {NAME}: scene {scene.id!r} has no ground-truth frames of "
                         f"{', '.join(weathers)}, which {NAME} edits (the synth_* scene sets ship them)")
    record = {"method": NAME, "severity": editor.severity, "seed": seed, "version": VERSION,
              "parameters": {w: editor.parameters(w) for w in frames}, "truth": truth, "not_supervised": missing}
    return frames, record
