"""Object editing through the scene graph: remove, keep only, translate or copy tracked objects.

An edit selects objects by track id or class and acts on their nodes at render time:

    remove class=Car except ids=3,7      hide every car but tracks 3 and 7
    keep-only ids=5,9                    hide every other object (the background stays)
    translate id=5 by=0,2,0              move track 5 by (0, 2, 0) m in the world frame
    insert id=5 by=0,4,0                 add a copy of track 5, 4 m along y
    insert id=5 at=12,-3,90              add a copy of track 5 standing on the ground at world
                                         (12, -3) m, turned 90 degrees about the up axis
    insert scene=OTHER id=5 at=12,-3,90  the same with track 5 of another trained scene, its
                                         colours carried into this scene's decoders
                                         (:mod:`.transfer`)

or the same as JSON objects (``{"op": "remove", "class": "Car", "except": ["3", "7"]}``; keys
``op``, ``ids``/``id``, ``class``, ``except``, ``by``, ``at``, ``scene``). Ids are the scene's track ids: drivestudio's
compact instance ids ``"0"``, ``"1"``, ... (docs/design.md §3). Classes match through the shared
vocabulary of :mod:`wcbench.core.classes`, case-insensitively: ``class=vehicle``, ``class=Car``
(PandaSet), ``class=Vehicle`` (Waymo) and ``class=vehicle.car`` (nuScenes) all select the vehicles.
A selection that matches no object is an error (a typo would otherwise edit nothing).
Edits apply in order; the result is a :class:`~wcbench.reference_model.model.scene_model.Placement`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from wcbench.core.classes import canonical_class
from wcbench.reference_model.model.objects import RigidObject
from wcbench.reference_model.model.scene_model import Placement

__all__ = ["OPS", "Edit", "parse_edit", "parse_edits", "placement_for"]

OPS = ("remove", "keep-only", "translate", "insert")


@dataclass(frozen=True)
class Edit:
    """One edit: an operation on the objects a selector picks.

    Attributes
    ----------
    op : {"remove", "keep-only", "translate", "insert"}
    ids : tuple of str
        Track ids selected.
    classes : tuple of str
        Track classes selected (case-insensitive).
    exclude : tuple of str
        Track ids never selected.
    by : tuple of 3 float or None
        World translation (m) of ``translate`` and ``insert``.
    at : tuple of 3 float or None
        ``insert`` at a fixed pose instead: world x, y (m) of the box's centre on the ground and its
        yaw (degrees, about the scene's up axis; 0 puts the box's length along the world x axis
        projected on the ground). One object, selected by ``id=``.
    scene : str or None
        ``insert ... at=`` an object of another trained scene (its name: a folder beside this
        scene's, or a path).
    """

    op: str
    ids: tuple[str, ...] = ()
    classes: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    by: tuple[float, float, float] | None = None
    at: tuple[float, float, float] | None = None
    scene: str | None = None

    def __post_init__(self) -> None:
        if self.op not in OPS:
            raise ValueError(f"edit: unknown operation {self.op!r}; operations: {', '.join(OPS)}")
        if not self.ids and not self.classes:
            raise ValueError(f"edit {self.op!r}: select objects with id=, ids= or class=")
        if self.at is not None or self.scene is not None:
            self._check_placed_insert()
            return
        needs_by = self.op in ("translate", "insert")
        if needs_by and self.by is None:
            raise ValueError(f"edit {self.op!r}: needs by=X,Y,Z (metres)"
                             + (" or at=X,Y,YAW" if self.op == "insert" else ""))
        if not needs_by and self.by is not None:
            raise ValueError(f"edit {self.op!r}: by= only goes with translate and insert")
        if self.by is not None and (len(self.by) != 3 or not np.all(np.isfinite(self.by))):
            raise ValueError(f"edit {self.op!r}: by= must be three finite numbers, got {self.by}")

    def _check_placed_insert(self) -> None:
        """``insert [scene=S] id=N at=X,Y,YAW``: one object, a pose, no translation."""
        if self.op != "insert":
            raise ValueError(f"edit {self.op!r}: at= and scene= only go with insert")
        if self.at is None:
            raise ValueError("edit 'insert' with scene=: needs at=X,Y,YAW (world metres and degrees)")
        if self.by is not None:
            raise ValueError("edit 'insert': by= and at= exclude each other (a copy moved along its track, "
                             "or one standing at a pose)")
        if len(self.at) != 3 or not np.all(np.isfinite(self.at)):
            raise ValueError(f"edit 'insert': at= must be three finite numbers X,Y,YAW, got {self.at}")
        if len(self.ids) != 1 or self.classes or self.exclude:
            raise ValueError("edit 'insert' with at=: select exactly one object with id=N "
                             f"(got ids {list(self.ids)}, classes {list(self.classes)})")
        if self.scene is not None and not self.scene.strip():
            raise ValueError("edit 'insert': scene= names a trained scene, got an empty name")

    def to_json(self) -> dict[str, Any]:
        """The edit as a JSON object (the form :func:`parse_edits` reads)."""
        out: dict[str, Any] = {"op": self.op}
        if self.ids:
            out["ids"] = list(self.ids)
        if self.classes:
            out["class"] = list(self.classes)
        if self.exclude:
            out["except"] = list(self.exclude)
        if self.by is not None:
            out["by"] = list(self.by)
        if self.at is not None:
            out["at"] = list(self.at)
        if self.scene is not None:
            out["scene"] = self.scene
        return out


def _list(value: Any) -> tuple[str, ...]:
    if isinstance(value, str):
        return tuple(v.strip() for v in value.split(",") if v.strip())
    if isinstance(value, Iterable):
        return tuple(str(v) for v in value)
    return (str(value),)


def _from_mapping(obj: Mapping[str, Any]) -> Edit:
    unknown = sorted(set(obj) - {"op", "id", "ids", "class", "except", "by", "at", "scene"})
    if unknown:
        raise ValueError(f"edit {dict(obj)}: unknown keys {unknown}")
    if "op" not in obj:
        raise ValueError(f"edit {dict(obj)}: missing 'op' ({', '.join(OPS)})")
    by_t = _triple(obj, "by", "X,Y,Z")
    at_t = _triple(obj, "at", "X,Y,YAW")
    scene = obj.get("scene")
    return Edit(op=str(obj["op"]), ids=_list(obj.get("ids", ())) + _list(obj.get("id", ())),
                classes=_list(obj.get("class", ())), exclude=_list(obj.get("except", ())),
                by=by_t, at=at_t, scene=None if scene is None else str(scene))  # type: ignore[arg-type]


def _triple(obj: Mapping[str, Any], key: str, form: str) -> tuple[float, ...] | None:
    """The three numbers of ``obj[key]`` (text ``"1,2,3"`` or a list), or None without the key."""
    value = obj.get(key)
    if value is None:
        return None
    try:
        out = tuple(float(v) for v in _list(value))
    except ValueError:
        raise ValueError(f"edit {dict(obj)}: {key}= must be numbers, got {value!r}") from None
    if len(out) != 3:
        raise ValueError(f"edit {dict(obj)}: {key}= needs three numbers {form}, got {value!r}")
    return out


def parse_edit(text: str) -> Edit:
    """One edit from its text form (see the module docstring).

    Raises
    ------
    ValueError
        Naming what is wrong (unknown operation or key, missing selector, malformed numbers).
    """
    words = text.split()
    if not words:
        raise ValueError("edit: empty")
    fields: dict[str, Any] = {"op": words[0]}
    i = 1
    while i < len(words):
        word = words[i]
        if word == "except":  # "except ids=3,7"
            if i + 1 >= len(words) or "=" not in words[i + 1]:
                raise ValueError(f"edit {text!r}: 'except' needs ids=...")
            key, _, value = words[i + 1].partition("=")
            if key not in ("id", "ids"):
                raise ValueError(f"edit {text!r}: 'except' takes ids=..., got {key}=")
            fields["except"] = value
            i += 2
            continue
        key, sep, value = word.partition("=")
        if not sep:
            raise ValueError(f"edit {text!r}: expected KEY=VALUE, got {word!r}")
        if key in fields:
            raise ValueError(f"edit {text!r}: {key}= given twice")
        fields[key] = value
        i += 1
    return _from_mapping(fields)


def parse_edits(spec: str | Sequence[str] | Sequence[Mapping[str, Any]]) -> list[Edit]:
    """Edits from text forms, a JSON list (text starting with ``[``) or JSON objects."""
    if isinstance(spec, str):
        text = spec.strip()
        if text.startswith("["):
            try:
                items = json.loads(text)
            except json.JSONDecodeError as exc:
                raise ValueError(f"edit list: not valid JSON ({exc})") from None
            if not isinstance(items, list):
                raise ValueError("edit list: expected a JSON list of edits")
            return [_from_mapping(x) if isinstance(x, Mapping) else parse_edit(str(x)) for x in items]
        return [parse_edit(text)]
    return [_from_mapping(x) if isinstance(x, Mapping) else parse_edit(str(x)) for x in spec]


def _selected(edit: Edit, objects: Mapping[str, RigidObject]) -> list[str]:
    classes = {canonical_class(c) for c in edit.classes}
    ids = set(edit.ids)
    keys = [k for k, o in objects.items()
            if (o.track_id in ids or canonical_class(o.class_name) in classes) and o.track_id not in set(edit.exclude)]
    if not keys:
        known = sorted({canonical_class(o.class_name) for o in objects.values()})
        raise ValueError(f"edit {edit.to_json()}: selects no object of the scene graph "
                         f"(classes: {', '.join(known) or 'none'}; {len(objects)} objects)")
    return keys


def placement_for(edits: Sequence[Edit], objects: Mapping[str, RigidObject], *,
                  placed: Mapping[int, str] | None = None) -> Placement:
    """The node placement that ``edits`` (applied in order) make of a model's ``objects``.

    Parameters
    ----------
    edits : sequence of Edit
    objects : mapping of node key to RigidObject
        :meth:`~wcbench.reference_model.model.scene_model.WeatherCityModel.objects`, with the objects
        that ``insert ... at=`` edits set down (:func:`~.transfer.placed_objects`) among them.
    placed : mapping of int to str, optional
        Edit index -> node key of the object its ``insert ... at=`` set down. That object enters
        the scene with its edit: an edit before it does not select it, one after it may (``remove
        class=Car`` after an insertion of a car removes it too).

    Raises
    ------
    ValueError
        If an edit selects no object, or an ``insert ... at=`` has no object in ``placed``.
    """
    placed = dict(placed or {})
    waiting = set(placed.values())  # objects whose edit has not come yet
    place = Placement(hidden=set(waiting))
    for i, edit in enumerate(edits):
        if edit.at is not None:
            key = placed.get(i)
            if key is None or key not in objects:
                raise ValueError(f"edit {edit.to_json()}: the object it sets down was not made "
                                 "(wcbench.reference_model.editing.transfer.placed_objects)")
            waiting.discard(key)
            place.hidden.discard(key)
            continue
        keys = _selected(edit, {k: o for k, o in objects.items() if k not in waiting})
        if edit.op == "remove":
            place.hidden.update(keys)
        elif edit.op == "keep-only":
            place.hidden.update(k for k in objects if k not in keys)
        elif edit.op == "translate":
            assert edit.by is not None
            for k in keys:
                place.offsets[k] = place.offsets.get(k, np.zeros(3)) + np.asarray(edit.by, np.float64)
        else:
            assert edit.by is not None
            for k in keys:
                base = place.offsets.get(k, np.zeros(3))
                place.copies.append((k, base + np.asarray(edit.by, np.float64)))
    return place
