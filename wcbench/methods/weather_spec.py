"""One weather spec for a run: the physics weather of each kind, read by everything that makes weather.

A run's weather of each edited kind is one
:class:`~wcbench.reference_model.weather.conditions.Weather` (rain or snow rate, fog visibility,
haze, wind, particle seed). WeatherCity's particles and haze, the haze its training renders pass
through, the built-in editors that make its supervision (``physical-editor``, ``filter2d``'s fog)
and ``lidar-init`` all read that object (docs/design.md §4):

* :func:`parse_physics` turns the ``physics`` option (``"auto"``, ``"truth"``, ``"presets"`` or a
  dict of Weather fields per kind) into a spec; :func:`resolve_physics` gives a scene's weathers
  under it: ``"auto"`` (the default) is the scene's *requested* weather where it records one
  (``truth/weather.json`` of the ``synth_*`` scenes: preset, rate, visibility, wind...), else the
  presets;
* a Weather's fields are requests (what a user asks for) except its particle ``seed``, a random
  draw: a scene's record never gives it. The seed is the run's (``--seed``), or one a ``physics``
  dict names; a method that draws particles is refused a run seed that equals the truth's
  (:func:`resolve_physics`), so no method renders the truth's own particles unless asked to by
  name, and :func:`truth_draw` records which draw a render used (``info.json``
  ``parameters.truth_draw``);
* :func:`check_consistent` compares the weather a supervision says it made with the run's physics
  and refuses a contradiction, naming the two values; :func:`physics_record` is what a render
  records (``info.json`` ``parameters.physics``) so that the check can be made later.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.options import Option
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.fog import visibility_from_density
from wcbench.scenes.scene import Scene

__all__ = [
    "DRAWS",
    "EDITED",
    "OLD_OPTION",
    "OPTION",
    "PhysicsSpec",
    "WeatherRequest",
    "check_consistent",
    "describe_option",
    "has_truth_weather",
    "old_physics_option",
    "parse_physics",
    "physics_argument",
    "physics_option",
    "physics_record",
    "requested_fields",
    "resolve_physics",
    "truth_draw",
    "truth_physics",
    "truth_seeds",
]

EDITED = ("rain", "snow", "fog")
#: The fields of a Weather that are random draws, not requests: never taken from a scene's record.
DRAWS = ("seed",)
#: Relative difference above which two rates or visibilities contradict each other.
_TOLERANCE = 0.01
#: The method option giving the spec; ``weathers`` is its old name (deprecated for one release: on
#: the command line ``--weathers`` lists weather kinds, docs/design.md §4).
OPTION = "physics"
OLD_OPTION = "weathers"


@dataclass(frozen=True)
class WeatherRequest:
    """A weather asked for in a ``physics`` dict.

    Attributes
    ----------
    weather : Weather
        The requested fields (its own ``seed`` is not used).
    seed : int, optional
        The particle seed, when the dict names one (``{"rain": {"seed": 3}}``); ``None``: the run's.
    """

    weather: Weather
    seed: int | None = None


#: ``"auto"``, ``"truth"``, ``"presets"`` or a request per kind.
PhysicsSpec = str | dict[str, WeatherRequest]


def _truth_file(scene: Scene) -> Path:
    return Path(scene.root) / "truth" / "weather.json"


def truth_physics(scene: Scene) -> dict[str, Weather]:
    """The physics weathers the scene's ground truth was rendered with, as recorded
    (``truth/weather.json`` of the ``synth_*`` scenes: rate, visibility, wind and particle seed per
    edited weather).

    This is the record, random draws included: it is for comparing with the truth (what rate,
    which seed), never for rendering; :func:`resolve_physics` takes its requested fields only.

    Raises
    ------
    InputError
        The scene has no such file, or it does not describe a weather per kind.
    """
    path = _truth_file(scene)
    if not path.is_file():
        raise InputError(f"{path}: not found; physics='truth' renders the weather a scene's ground truth "
                         "requested, and only the synth_* scenes record it")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        return {kind: Weather.from_json(entry["weather"]) for kind, entry in doc.items()
                if isinstance(entry, dict) and "weather" in entry}
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{path}: expected {{kind: {{'weather': Weather fields, ...}}}} per edited weather "
                         f"({exc})") from None


def truth_seeds(scene: Scene) -> dict[str, int]:
    """The particle seed of each weather the scene's truth was rendered with (empty: no record)."""
    return {kind: int(w.seed) for kind, w in truth_physics(scene).items()} if has_truth_weather(scene) else {}


def has_truth_weather(scene: Scene) -> bool:
    """Whether ``scene`` records the weather of its ground truth (``truth/weather.json``)."""
    return _truth_file(scene).is_file()


def requested_fields(weather: Weather) -> dict[str, Any]:
    """The fields of ``weather`` a user asks for (JSON-ready): all but the random draws (:data:`DRAWS`)."""
    desc = weather.to_json()
    for name in DRAWS:
        desc.pop(name, None)
    return desc


def parse_physics(value: Any, *, who: str, name: str = OPTION) -> PhysicsSpec:
    """The ``physics`` option of a method: ``None`` or ``"auto"``, ``"truth"``, ``"presets"``, or a dict
    of kind -> Weather fields (a :class:`Weather` or a :class:`WeatherRequest` is taken as it is).

    A dict entry's ``seed`` is the particle seed asked for by name; without one the run's seed is
    used. A :class:`Weather` object stands for its requested fields (its seed is not a request).

    Parameters
    ----------
    value : any
    who : str
        The method (or command) the option was given to, first in every message.
    name : str
        The option's name as the user gave it, in every message (``"weathers"``: the deprecated
        name, :data:`OLD_OPTION`).

    Raises
    ------
    InputError
        Another string, an unknown kind or bad Weather fields.
    """
    if value is None:
        return "auto"
    if isinstance(value, str):
        if value not in ("auto", "truth", "presets"):
            raise InputError(f"{who}: {name} must be 'auto', 'truth', 'presets' or a dict of kind -> Weather "
                             f"fields, got {value!r}")
        return value
    if not isinstance(value, Mapping):
        raise InputError(f"{who}: {name} must be a dict of kind -> Weather fields, got {type(value).__name__}")
    out: dict[str, WeatherRequest] = {}
    for kind, fields in value.items():
        if kind not in EDITED:
            raise InputError(f"{who}: {name}[{kind!r}]: not an edited weather (one of {', '.join(EDITED)}; clear "
                             "has no physics)")
        if isinstance(fields, WeatherRequest):
            out[kind] = fields
            continue
        if isinstance(fields, Weather):
            out[kind] = WeatherRequest(fields)
            continue
        if not isinstance(fields, Mapping):
            raise InputError(f"{who}: {name}[{kind!r}]: expected a dict of Weather fields, got {fields!r}")
        given = dict(fields)
        seed = given.pop("seed", None)
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise InputError(f"{who}: {name}[{kind!r}]: seed must be an integer >= 0, got {seed!r}")
        try:
            out[kind] = WeatherRequest(Weather(kind=kind, **given), seed=seed)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{who}: {name}[{kind!r}]: {exc}") from None
    return out


def physics_argument(physics: Any = None, weathers: Any = None, *, who: str) -> PhysicsSpec:
    """The spec of a method's ``physics`` keyword, or of its deprecated name ``weathers`` (one release).

    Raises
    ------
    InputError
        Both given (naming both), or a value :func:`parse_physics` refuses.

    Warns
    -----
    DeprecationWarning
        ``weathers`` given: it is the old name of ``physics``.
    """
    if weathers is None:
        return parse_physics(physics, who=who)
    if physics is not None:
        raise InputError(f"{who}: {OLD_OPTION} and {OPTION} both given: {OLD_OPTION} is the deprecated name of "
                         f"{OPTION}; give {OPTION} only")
    warnings.warn(f"{who} option {OLD_OPTION} is deprecated, use {OPTION}", DeprecationWarning, stacklevel=3)
    return parse_physics(weathers, who=who, name=OLD_OPTION)


def _option(name: str, *, who: str, doc: str, renamed_to: str = "") -> Option:
    def check(value: Any) -> Any:
        try:
            parse_physics(value, who=who, name=name)
        except InputError as exc:
            raise ValueError(str(exc).removeprefix(f"{who}: ")) from None
        return value

    return Option(name, "custom", doc, default="auto", nullable=True, check=check, renamed_to=renamed_to,
                  allowed=f"'auto', 'truth', 'presets' or a table of rain/snow/fog -> Weather fields, e.g. "
                          f"{name}.rain.preset=heavy")


def physics_option(*, who: str) -> Option:
    """The declared ``physics`` option of a method ``who`` (checked by :func:`parse_physics`)."""
    return _option(OPTION, who=who, doc="the physics weather per kind: 'auto' (a scene's recorded weather, else "
                   "the presets), 'truth' (the record, required), 'presets', or Weather fields per kind")


def old_physics_option(*, who: str) -> Option:
    """``weathers``, the deprecated name of the ``physics`` option (one release): checked alike, then
    handed on as ``physics`` (:func:`wcbench.core.options.validate_options`)."""
    return _option(OLD_OPTION, who=who, doc=f"deprecated name of {OPTION}", renamed_to=OPTION)


def describe_option(option: PhysicsSpec, kind: str) -> dict[str, Any] | str:
    """What ``option`` says of ``kind`` without a scene (recorded in a method's parameters)."""
    if option == "truth":
        return "truth (the requested weather of each scene's truth/weather.json, required; never its seed)"
    if option == "auto":
        return "auto (the requested weather of a scene's truth/weather.json where it ships one, else the presets)"
    request = option.get(kind) if isinstance(option, dict) else None
    desc = requested_fields(request.weather if request is not None else Weather(kind=kind))
    if request is not None and request.seed is not None:
        desc["seed"] = request.seed  # asked for by name: a setting of the run like any other
    return desc


def resolve_physics(scene: Scene, option: PhysicsSpec, *, seed: int = 0,
                    truth: Mapping[str, Weather] | None = None, draws: bool = True) -> dict[str, Weather]:
    """The physics weather of every edited kind for ``scene`` under ``option``.

    Every field comes from a request (the scene's record, the presets or the option); the particle
    seed never comes from the scene's record: it is ``seed`` (the run's), or the one a ``physics``
    dict names for that kind.

    Parameters
    ----------
    scene : Scene
    option : PhysicsSpec
        ``"auto"``: the requested fields of the scene's recorded weather (``truth/weather.json``)
        where it ships one, else the presets; ``"truth"``: the same, the record required;
        ``"presets"``: each kind's default preset; a dict: those weathers (the presets for kinds
        it does not give).
    seed : int
        The run's particle seed (``--seed``), for every kind the option names no seed of.
    truth : mapping, optional
        :func:`truth_physics` of the scene, when the caller has read it already.
    draws : bool
        Whether the caller draws particles from the seeds (rain and snow rendered with the
        physics). Then a run ``seed`` equal to the seed the scene's truth of that kind was
        rendered with is refused: its particles would be the truth's own. ``False`` for callers
        that draw none (the editors, the training's hazes): no draw, nothing to refuse.

    Raises
    ------
    InputError
        ``"truth"`` on a scene without a recorded weather, or one missing a kind; with ``draws``, a
        run seed equal to the truth's particle seed (name the seed in the option to ask for it).
    """
    if truth is not None:
        recorded = dict(truth)
    elif option == "truth" or ((option == "auto" or draws) and has_truth_weather(scene)):
        recorded = truth_physics(scene)  # "truth" without a record: the error naming the file
    else:
        recorded = {}
    named: dict[str, int] = {}
    if option == "truth" or (option == "auto" and recorded):
        missing = [k for k in EDITED if k not in recorded]
        if missing:
            raise InputError(f"{_truth_file(scene)}: no entry for {', '.join(missing)}")
        base = {k: recorded[k] for k in EDITED}  # the seed is replaced below: it is a draw, not a request
    else:
        given = option if isinstance(option, dict) else {}
        base = {k: given[k].weather if k in given else Weather(kind=k) for k in EDITED}
        named = {k: r.seed for k, r in given.items() if r.seed is not None}
    out = {k: replace(base[k], seed=named.get(k, seed)) for k in EDITED}
    if draws:
        for k, weather in out.items():
            if weather.has_particles and k not in named and k in recorded and weather.seed == recorded[k].seed:
                raise InputError(
                    f"--seed {seed}: scene {scene.id!r}'s true {k} was rendered with this particle seed "
                    f"({_truth_file(scene)}), so a method drawing {k} with it would draw the truth's own "
                    f"particles. Choose another --seed, or name the seed in the physics option "
                    f"('physics={{\"{k}\": {{\"seed\": {seed}}}}}') to render them on purpose")
    return out


def truth_draw(scene: Scene, weather: Weather | None, *, option: PhysicsSpec | None = None,
               reads: str | None = None) -> dict[str, Any]:
    """What of the scene's ground truth a render used (``info.json`` ``parameters.truth_draw``).

    Parameters
    ----------
    scene : Scene
    weather : Weather, optional
        The physics weather the render drew its particles from (``None``: it draws none).
    option : PhysicsSpec, optional
        The ``physics`` option it was resolved under (says whether a seed was named).
    reads : str, optional
        What of the truth the method reads besides (``sim-editor``: the truth frames); ``None``:
        nothing.

    Returns
    -------
    dict
        ``used`` (bool: the truth's frames, or its particle seed, went into the frames),
        ``particle_seed`` and ``truth_particle_seed`` (``None`` where there is none), ``seed_from``
        (``"run"``: ``--seed``; ``"physics option"``: named) and ``note``.
    """
    out: dict[str, Any] = {"used": reads is not None, "particle_seed": None, "truth_particle_seed": None,
                           "seed_from": None}
    if weather is not None and weather.has_particles:
        theirs = truth_seeds(scene).get(weather.kind)
        named = isinstance(option, dict) and weather.kind in option and option[weather.kind].seed is not None
        same = theirs is not None and int(weather.seed) == theirs
        out.update(used=bool(out["used"] or same), particle_seed=int(weather.seed), truth_particle_seed=theirs,
                   seed_from="physics option" if named else "run")
        if same:
            out["note"] = (f"the truth's own particle seed (from the {out['seed_from']}): its {weather.kind} "
                           "particles are the truth's")
    if reads is not None:
        out["note"] = reads
    out.setdefault("note", "no ground-truth frame, particle seed or other random draw of the truth")
    return out


def physics_record(weather: Weather) -> dict[str, Any]:
    """What an edited folder records of the weather it made (``info.json`` ``parameters.physics``): the
    Weather's fields and the resolved rate (mm/h) and visibility (m) the check compares."""
    beta, _, _ = weather.haze()
    return {"weather": weather.to_json(), "rate_mm_h": weather.precipitation_rate(),
            "visibility_m": None if beta <= 0 else visibility_from_density(beta)}


def _differs(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return (a is None) != (b is None)
    if math.isinf(a) and math.isinf(b):
        return False
    return abs(a - b) > _TOLERANCE * max(abs(a), abs(b), 1e-9)


def check_consistent(kind: str, physics: Weather, record: Mapping[str, Any], *, source: str) -> None:
    """Refuse a supervision of ``kind`` whose recorded weather contradicts the run's physics.

    Parameters
    ----------
    kind : str
    physics : Weather
        The run's weather of that kind.
    record : mapping
        :func:`physics_record` of the weather the supervision was made with.
    source : str
        Where the record was read (named in the error).

    Raises
    ------
    InputError
        Another rain or snow rate, or another visibility (beyond 1 %), with both values named.
    """
    mine = physics_record(physics)
    if kind in ("rain", "snow") and _differs(record.get("rate_mm_h"), mine["rate_mm_h"]):
        raise InputError(f"{source}: its {kind} was made at {record.get('rate_mm_h')} mm/h, the run's physics "
                         f"{kind} is {mine['rate_mm_h']} mm/h; edit at the run's rate or set the run's "
                         f"physics to the supervision's")
    if _differs(record.get("visibility_m"), mine["visibility_m"]):
        def show(v: Any) -> str:
            return "no haze" if v is None else f"{float(v):.4g} m"

        raise InputError(f"{source}: its {kind} was made with visibility {show(record.get('visibility_m'))}, "
                         f"the run's physics {kind} has visibility {show(mine['visibility_m'])}; edit with the "
                         f"run's visibility or set the run's physics to the supervision's")
