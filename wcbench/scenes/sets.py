"""Scene sets as data: one TOML spec per set in this folder.

A spec names a layout, loader options and scene folders relative to the data root::

    name = "waymo_5"
    description = "..."
    format = "drivestudio_waymo"      # loader (see wcbench.scenes.loaders)
    camera = 0                        # optional loader options: camera, start, count
    generator = "module:function"     # optional: builds the scenes itself (built-in sets)
    scenes = [{ id = "waymo_788", path = "waymo/processed/training/788" }]
    # optional per scene: aliases = ["23"], other names tools give the scene's folder (a prediction
    # folder may also be named like the scene id or the scene's data folder, here "788")

A scene is called by its ``id`` in progress lines, the output layout (``<out>/<method>/<scene>/``),
results and reports. A set of one scene calls it by the set's name, the name the user gave
(``--scenes synth_1``: scene ``synth_1``, data folder ``synth_000``); the scenes of a larger set are
called by the data's names for them (``waymo_023``, ``synth_001``). A prediction folder may still
carry the data folder's name (docs/design.md §3, "Scene names").

drivestudio names a processed scene folder by its index zero-padded to three digits (``023``,
``002``) and its configs select it by the plain index (``data.scene_idx=23``), which tools such as
WeatherCity carry into their run names; a set lists both spellings its data folder does not
already carry as aliases (``pandaset_002``: ``002`` and ``2``). Within a set, no name may stand for
two scenes (:func:`check_scene_names`).

The data root comes from ``--data-root`` or the ``WCBENCH_DATA`` environment variable. Built-in
sets with a ``generator`` need no data root: the generator writes them into the cache folder.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.registry import import_string
from wcbench.scenes.loaders import detect_format, load_scene
from wcbench.scenes.scene import Scene

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

DATA_ENV = "WCBENCH_DATA"
_LOADER_OPTIONS = ("camera", "start", "count")


@dataclass(frozen=True)
class SceneSet:
    """A named list of scene references (loaded on demand).

    Attributes
    ----------
    name : str
    description : str
    scenes : list[SceneRef]
    """

    name: str
    description: str
    scenes: Sequence[SceneRef]


@dataclass(frozen=True)
class SceneRef:
    """Where one scene of a set lives and how to read it.

    Attributes
    ----------
    id : str
        Scene id used in output folders and reports (e.g. ``"waymo_788"``; a one-scene set's:
        the set's name).
    format : str
        Loader name (``"drivestudio_waymo"``, ``"drivestudio_nuscenes"``, ``"builtin"``).
    path : Path
        Scene folder.
    options : dict
        Loader options (camera, first frame, frame count...).
    aliases : tuple of str
        Other names tools give the scene's folder (``"23"`` for ``waymo_023``); besides these, a
        prediction folder may carry the scene id or the name of the scene's data folder.
    """

    id: str
    format: str
    path: Path
    options: dict = field(default_factory=dict)
    aliases: tuple[str, ...] = ()

    def load(self) -> Scene:
        """Load the scene with its loader (see :mod:`wcbench.scenes.loaders`)."""
        return load_scene(self.path, format=self.format, scene_id=self.id, **self.options)



def _specs() -> dict[str, dict[str, Any]]:
    out = {}
    for entry in resources.files("wcbench.scenes").joinpath("specs").iterdir():
        if entry.name.endswith(".toml"):
            spec = tomllib.loads(entry.read_text(encoding="utf-8"))
            out[spec["name"]] = spec
    return out


def list_scene_sets() -> list[tuple[str, str]]:
    """(name, description) of every built-in scene set, sorted by name."""
    return sorted((name, spec.get("description", "")) for name, spec in _specs().items())


def data_root_from(value: str | os.PathLike[str] | None) -> Path | None:
    """The data root: ``value`` if given, else ``$WCBENCH_DATA``, else ``None``."""
    if value:
        return Path(value).expanduser()
    env = os.environ.get(DATA_ENV)
    return Path(env).expanduser() if env else None


def get_scene_set(name: str, *, data_root: str | os.PathLike[str] | None = None) -> SceneSet:
    """Resolve a named scene set to scene references and check that their folders exist.

    Raises
    ------
    UnknownNameError
        No such set.
    InputError
        The set needs a data root and none was given, or scene folders are missing under it
        (the message lists every expected folder).
    """
    specs = _specs()
    if name not in specs:
        raise UnknownNameError("scene set", name, specs)
    spec = specs[name]
    options = {k: spec[k] for k in _LOADER_OPTIONS if k in spec}
    if "generator" in spec:
        root = Path(import_string(spec["generator"])())
    else:
        root_opt = data_root_from(data_root)
        expected = "\n".join(f"  <data-root>/{s['path']}/images/..." for s in spec["scenes"])
        if root_opt is None:
            raise InputError(
                f"scene set {name!r} needs a data root: pass --data-root DIR or set {DATA_ENV}. "
                f"Expected under it:\n{expected}"
            )
        root = root_opt
        if not root.is_dir():
            raise InputError(f"data root {root} does not exist. Scene set {name!r} expects:\n{expected}")
        missing = [s["path"] for s in spec["scenes"] if not (root / s["path"]).is_dir()]
        if missing:
            listing = "\n".join(f"  {root / m}" for m in missing)
            raise InputError(f"scene set {name!r}: {len(missing)} scene folder(s) missing:\n{listing}")
    refs = [
        SceneRef(id=s["id"], format=spec["format"], path=root / s["path"], options=dict(options),
                 aliases=tuple(str(a) for a in s.get("aliases", ())))
        for s in spec["scenes"]
    ]
    check_scene_names(name, refs)
    return SceneSet(name=name, description=spec.get("description", ""), scenes=refs)


def check_scene_names(set_name: str, refs: Sequence[SceneRef]) -> None:
    """Check that no name a prediction folder may carry (a scene's id, its data folder's name, an
    alias) stands for two scenes of one set: such a folder would be claimed by both.

    Raises
    ------
    ValueError
        Naming the shared names and their scenes (a bug in the set's spec).
    """
    owners: dict[str, set[str]] = {}
    for ref in refs:
        for name in (ref.id, ref.path.name, *ref.aliases):
            owners.setdefault(name, set()).add(ref.id)
    shared = {name: sorted(ids) for name, ids in owners.items() if len(ids) > 1}
    if shared:
        listing = "; ".join(f"{name!r}: {', '.join(ids)}" for name, ids in sorted(shared.items()))
        raise ValueError(f"scene set {set_name!r}: names shared by several scenes ({listing})")


def resolve_scenes(
    name_or_path: str | os.PathLike[str], *, data_root: str | os.PathLike[str] | None = None
) -> list[SceneRef]:
    """Scenes of ``--scenes``: a set name, a path to one processed scene folder, or a comma-separated
    list of both (``demo,runs/demo_copy``).

    A path is recognised by containing a path separator or existing on disk.

    Raises
    ------
    InputError
        Two entries give scenes of the same id (their outputs would share folders), or one scene
        folder under two names (``synth_1,synth_3``: ``synth_1`` is ``synth_3``'s first scene).
    """
    text = str(name_or_path)
    if "," in text and not Path(text).expanduser().is_dir():
        refs = [r for part in text.split(",") if part.strip()
                for r in resolve_scenes(part.strip(), data_root=data_root)]
        ids = [r.id for r in refs]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            raise InputError(f"--scenes {text!r}: scene ids {twice} come up more than once "
                             "(a scene folder's id is its folder name)")
        names: dict[Path, list[str]] = {}
        for r in refs:
            names.setdefault(r.path.resolve(), []).append(r.id)
        again = {path: ids for path, ids in names.items() if len(ids) > 1}
        if again:
            listing = "; ".join(f"{path} as {', '.join(ids)}" for path, ids in again.items())
            raise InputError(f"--scenes {text!r}: one scene folder given twice ({listing}); give it once")
        return refs
    return _resolve_one(text, data_root=data_root)


def _is_path(text: str) -> bool:
    return os.sep in text or "/" in text or (Path(text).expanduser().is_dir() and text not in _specs())


def normalized_scenes(name_or_path: str | os.PathLike[str]) -> str:
    """``--scenes`` with every folder path made absolute, so the same scenes read the same
    whether given relative or absolute (set names are left as they are)."""
    text = str(name_or_path)
    parts = [text] if Path(text).expanduser().is_dir() else text.split(",")
    return ",".join(str(Path(p.strip()).expanduser().resolve()) if _is_path(p.strip()) else p.strip() for p in parts)


def _resolve_one(text: str, *, data_root: str | os.PathLike[str] | None) -> list[SceneRef]:
    path = Path(text).expanduser()
    if _is_path(text):
        if not path.is_dir():
            raise InputError(f"{path}: scene folder does not exist")
        return [SceneRef(id=path.resolve().name, format=detect_format(path), path=path)]
    return list(get_scene_set(text, data_root=data_root).scenes)
