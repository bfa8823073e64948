"""One weather spec for a run: the physics weather of each kind, read by everything that makes weather.

A run's weather of each edited kind is one
:class:`~wcbench.reference_model.weather.conditions.Weather` (rain or snow rate, fog visibility,
haze, wind, particle seed). WeatherCity's particles and haze, the haze its training renders pass
through, and the built-in editors that make its supervision (``physical-editor``, and ``filter2d``'s
fog) all read that object (docs/design.md §4):

* :func:`parse_weathers` turns the ``weathers`` option (``"auto"``, ``"truth"``, ``"presets"`` or a
  dict of Weather fields per kind) into a spec; :func:`resolve_physics` gives a scene's weathers
  under it: ``"auto"`` (the default) is the scene's own recorded weather where it ships one
  (``truth/weather.json`` of the ``synth_*`` scenes), else the presets;
* :func:`check_consistent` compares the weather a supervision says it made with the run's physics
  and refuses a contradiction, naming the two values; :func:`physics_record` is what an edited
  folder records (``info.json`` ``parameters.physics``) so that the check can be made later.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.fog import visibility_from_density
from wcbench.scenes.scene import Scene

__all__ = ["EDITED", "WeathersOption", "check_consistent", "describe_option", "has_truth_weather", "parse_weathers",
           "physics_record", "resolve_physics", "truth_physics"]

EDITED = ("rain", "snow", "fog")
#: ``"auto"``, ``"truth"``, ``"presets"`` or a Weather per kind.
WeathersOption = str | dict[str, Weather]
#: Relative difference above which two rates or visibilities contradict each other.
_TOLERANCE = 0.01


def truth_physics(scene: Scene) -> dict[str, Weather]:
    """The physics weathers the scene's ground truth was rendered with (``truth/weather.json`` of the
    ``synth_*`` scenes: rate, visibility, wind and particle seed per edited weather).

    Raises
    ------
    InputError
        The scene has no such file, or it does not describe a weather per kind.
    """
    path = Path(scene.root) / "truth" / "weather.json"
    if not path.is_file():
        raise InputError(f"{path}: not found; weathers='truth' renders with the physics a scene's ground truth "
                         "was made with, and only the synth_* scenes ship it")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        return {kind: Weather.from_json(entry["weather"]) for kind, entry in doc.items()
                if isinstance(entry, dict) and "weather" in entry}
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{path}: expected {{kind: {{'weather': Weather fields, ...}}}} per edited weather "
                         f"({exc})") from None


def has_truth_weather(scene: Scene) -> bool:
    """Whether ``scene`` records the weather of its ground truth (``truth/weather.json``)."""
    return (Path(scene.root) / "truth" / "weather.json").is_file()


def parse_weathers(value: Any, *, who: str) -> WeathersOption:
    """The ``weathers`` option of a method: ``None`` or ``"auto"``, ``"truth"``, ``"presets"``, or a dict
    of kind -> :class:`Weather` (or its fields).

    Raises
    ------
    InputError
        Another string, an unknown kind or bad Weather fields (``who`` names the method).
    """
    if value is None:
        return "auto"
    if isinstance(value, str):
        if value not in ("auto", "truth", "presets"):
            raise InputError(f"{who}: weathers must be 'auto', 'truth', 'presets' or a dict of kind -> Weather "
                             f"fields, got {value!r}")
        return value
    if not isinstance(value, Mapping):
        raise InputError(f"{who}: weathers must be a dict of kind -> Weather fields, got {type(value).__name__}")
    out: dict[str, Weather] = {}
    for kind, fields in value.items():
        if kind not in EDITED:
            raise InputError(f"{who}: weathers[{kind!r}]: not an edited weather (one of {', '.join(EDITED)})")
        try:
            out[kind] = fields if isinstance(fields, Weather) else Weather(kind=kind, **dict(fields))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{who}: weathers[{kind!r}]: {exc}") from None
    return out


def describe_option(option: WeathersOption, kind: str) -> dict[str, Any] | str:
    """What ``option`` says of ``kind`` without a scene (recorded in a method's parameters)."""
    if option == "truth":
        return "truth (each scene's truth/weather.json, seed included)"
    if option == "auto":
        return "auto (a scene's truth/weather.json where it ships one, else the presets)"
    weather = option.get(kind, Weather(kind=kind)) if isinstance(option, dict) else Weather(kind=kind)
    desc = weather.to_json()
    desc.pop("seed", None)
    return desc


def resolve_physics(scene: Scene, option: WeathersOption, *, seed: int = 0,
                    truth: Mapping[str, Weather] | None = None) -> dict[str, Weather]:
    """The physics weather of every edited kind for ``scene`` under ``option``.

    Parameters
    ----------
    scene : Scene
    option : WeathersOption
        ``"auto"``: the scene's recorded weather (its truth's, seed included) where it ships one,
        else the presets; ``"truth"``: the recorded one, required; ``"presets"``: each kind's
        default preset; a dict: those weathers (the presets for kinds it does not give).
    seed : int
        Particle seed of the weathers that do not come from the scene's record.
    truth : mapping, optional
        :func:`truth_physics` of the scene, when the caller has read it already.

    Raises
    ------
    InputError
        ``"truth"`` on a scene without a recorded weather, or one missing a kind.
    """
    if option == "truth" or (option == "auto" and has_truth_weather(scene)):
        recorded = dict(truth) if truth is not None else truth_physics(scene)
        missing = [k for k in EDITED if k not in recorded]
        if missing:
            raise InputError(f"{Path(scene.root) / 'truth' / 'weather.json'}: no entry for {', '.join(missing)}")
        return {k: recorded[k] for k in EDITED}
    given = option if isinstance(option, dict) else {}
    return {k: replace(given.get(k, Weather(kind=k)), seed=seed) for k in EDITED}


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
                         f"weathers to the supervision's")
    if _differs(record.get("visibility_m"), mine["visibility_m"]):
        def show(v: Any) -> str:
            return "no haze" if v is None else f"{float(v):.4g} m"

        raise InputError(f"{source}: its {kind} was made with visibility {show(record.get('visibility_m'))}, "
                         f"the run's physics {kind} has visibility {show(mine['visibility_m'])}; edit with the "
                         f"run's visibility or set the run's weathers to the supervision's")
