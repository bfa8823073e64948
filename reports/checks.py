"""What a report must not mix silently: mismatched inputs across folders, and unpublished weights.

Every finding is a :class:`Flag` with a scope (methods, scenes, outputs); table cells inside its
scope carry a marker whose hover text is the flag's message, and the report lists all flags at
the top.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from .loading import ResultsFolder

#: Flag kinds and their markers (HTML and LaTeX). ``weights``: numbers produced with weights that
#: are not the published ones; the rest: inputs or definitions that differ across folders.
MARKERS = {"weights": ("\u2020", r"\dag"), "mismatch": ("\u2021", r"\ddag")}

#: Config keys that name where a file was, not what it holds (their sha256 sits beside them).
_LOCATION_SUFFIXES = ("_file", "_dir", "_path", "path")
_HASH_KEYS = ("weights_sha256", "onnx_sha256")
#: The end of an output's variant when it was scored at another size than its scene's frames
#: (wcbench/units.py writes it; results.json ``working_size`` gives the details).
_SCORED_AT = re.compile(r"; scored at (\d+x\d+)$")


@dataclass(frozen=True)
class Flag:
    """One finding.

    Attributes
    ----------
    kind : str
        ``"weights"`` or ``"mismatch"`` (see :data:`MARKERS`).
    topic : str
        What differs: ``weights``, ``scenes``, ``frames``, ``source``, ``resolution``, ``size`` (the
        size numbers were scored at), ``variant``, ``settings``, ``duplicate``.
    message : str
        One sentence for the reader.
    methods, scenes, outputs : frozenset of str or None
        Scope; ``None`` means all.
    means_only : bool
        Applies to mean-over-scenes cells only (a method scored on other scenes).
    units : frozenset of (method, scene, output) or None
        Finer scope: the numbers concerned.
    """

    kind: str
    topic: str
    message: str
    methods: frozenset[str] | None = None
    scenes: frozenset[str] | None = None
    outputs: frozenset[str] | None = None
    means_only: bool = False
    units: frozenset[tuple[str, str, str]] | None = None

    def applies(self, *, method: str, scenes: Iterable[str], output: str, is_mean: bool) -> bool:
        """Whether a cell of ``method`` and ``output`` over ``scenes`` lies in this flag's scope."""
        if self.means_only and not is_mean:
            return False
        if self.methods is not None and method not in self.methods:
            return False
        if self.outputs is not None and output not in self.outputs:
            return False
        if self.units is not None and not any((method, s, output) in self.units for s in scenes):
            return False
        return self.scenes is None or bool(self.scenes & set(scenes))


def _model_records(obj: Any, name: str = "") -> list[tuple[str, dict[str, Any]]]:
    """(model name, dict) for every dict of a metric config that records weights."""
    out: list[tuple[str, dict[str, Any]]] = []
    if isinstance(obj, dict):
        named = [obj.get(k) for k in ("model", "segmenter", "net") if isinstance(obj.get(k), str)]
        here = str(named[0]) if named else name
        if "weights_verified" in obj or any(isinstance(obj.get(k), str) for k in _HASH_KEYS):
            out.append((here or "?", obj))
        for value in obj.values():
            out += _model_records(value, here)
    elif isinstance(obj, list):
        for value in obj:
            out += _model_records(value, name)
    return out


def weights_status(metric_config: dict[str, Any]) -> list[dict[str, Any]]:
    """The weights one metric used, from its recorded config.

    Returns
    -------
    list of dict
        ``{"model", "sha256", "verified"}`` per model record; ``verified`` is ``True`` (source
        file matched the pinned published hash), ``False`` (it did not: e.g. a random-weight test
        model or an unpinned checkpoint) or ``None`` (not recorded: results of an older wcbench).
    """
    out = []
    for model, rec in _model_records(metric_config.get("config", {})):
        sha = next((rec[k] for k in _HASH_KEYS if isinstance(rec.get(k), str)), None)
        if sha is None and isinstance(rec.get("files"), dict):
            sha = next(iter(sorted(rec["files"].items())), (None, None))[1]
        verified = rec.get("weights_verified")
        out.append({"model": model, "sha256": sha, "verified": verified if isinstance(verified, bool) else None})
    return out


def weight_flags(folders: list[ResultsFolder], outputs_of: dict[str, set[str]]) -> list[Flag]:
    """One ``weights`` flag per model whose weights are not verified as the published ones, on every
    number a metric computed with it (in any folder). A metric with no number (every row skipped,
    e.g. its weights are not installed) flags nothing: there is nothing to compare."""
    groups: dict[tuple[str, str, bool | None], dict[str, Any]] = {}
    for f in folders:
        for metric, cfg in sorted(f.doc["config"].get("metric_config", {}).items()):
            outputs = outputs_of.get(metric, {metric})
            units = {(f.label, scene, output) for scene, weathers in f.doc["results"].items()
                     for outs in weathers.values() for output in outputs
                     if isinstance(outs.get(output), dict) and outs[output].get("value") is not None}
            if not units:
                continue
            for w in weights_status(cfg):
                if w["verified"] is True:
                    continue
                g = groups.setdefault((w["model"], str(w["sha256"]), w["verified"]),
                                      {"metrics": set(), "methods": set(), "units": set()})
                g["metrics"].add(metric)
                g["methods"].add(f.label)
                g["units"].update(units)
    flags = []
    for (model, sha, verified), g in sorted(groups.items(), key=lambda kv: str(kv[0])):
        why = ("its source file did not match the pinned sha256 of the published file (e.g. a random-weight "
               "test model or another checkpoint)" if verified is False
               else "the results do not record whether it came from the published file")
        flags.append(Flag(
            "weights", "weights",
            f"{model} (sha256 {sha[:12]}...) is not verified as the published weights: {why}. Used for "
            f"{', '.join(sorted(g['metrics']))} of {', '.join(sorted(g['methods']))}; those numbers are not "
            "comparable with published ones.",
            units=frozenset(g["units"]),
        ))
    return flags


def _settings(cfg: dict[str, Any]) -> str:
    """A metric's settings without file locations (they differ across machines for the same file)."""
    def strip(obj: Any) -> Any:
        if isinstance(obj, dict):
            return {k: strip(v) for k, v in obj.items() if not str(k).endswith(_LOCATION_SUFFIXES)}
        if isinstance(obj, list):
            return [strip(v) for v in obj]
        return obj

    return json.dumps(strip(cfg), sort_keys=True)


def _differs(values: dict[str, Any]) -> bool:
    return len({json.dumps(v, sort_keys=True) for v in values.values()}) > 1


def _listing(values: dict[str, Any]) -> str:
    return "; ".join(f"{k}: {v}" for k, v in values.items())


def _split_variant(variant: str) -> tuple[str, str | None]:
    """(definition, size scored at or ``None`` for the scene's own size) of an output's variant."""
    m = _SCORED_AT.search(variant)
    return (variant[: m.start()], m.group(1)) if m else (variant, None)


def _grouped(by_label: dict[str, str]) -> list[tuple[list[str], str]]:
    """(labels, value) with the labels that share a value together, in order of first label."""
    groups: dict[str, list[str]] = {}
    for label, value in sorted(by_label.items()):
        groups.setdefault(value, []).append(label)
    return [(labels, value) for value, labels in groups.items()]


def _fps_flags(folders: list[ResultsFolder]) -> list[Flag]:
    """A flag for a method whose FPS on one scene were measured at several resolutions (say another
    tool's ``info.json`` per weather): its means mix them.

    Methods that render at different sizes are not flagged: FPS is a method's speed at the size it
    renders at, which the report's runtime table gives beside it, as the paper's runtime table gives
    each method's own inference or rendering speed (docs/design.md §8, "Scoring").
    """
    res: dict[tuple[str, str], set[str]] = {}
    for f in folders:
        for scene, weathers in sorted(f.doc["results"].items()):
            for outputs in weathers.values():
                r = outputs.get("fps")
                size = ((r or {}).get("extra") or {}).get("resolution") if isinstance(r, dict) else None
                if size:
                    res.setdefault((f.label, scene), set()).add("x".join(str(v) for v in size))
    mixed = {k: v for k, v in sorted(res.items()) if len(v) > 1}
    if not mixed:
        return []
    listing = "; ".join(f"{label} on {scene}: {', '.join(sorted(v))}" for (label, scene), v in mixed.items())
    return [Flag("mismatch", "resolution", f"FPS of one method measured at different resolutions ({listing})",
                 outputs=frozenset({"fps"}),
                 units=frozenset((label, scene, "fps") for label, scene in mixed))]


def _definition_flags(folders: list[ResultsFolder], outputs_of: dict[str, set[str]]) -> list[Flag]:
    """Flags for outputs whose variants differ across methods, grouped by cause: one flag for the
    sizes numbers were scored at (every output that reads frames differs by that alone), one per
    metric whose definitions differ otherwise, each definition said once with its methods.

    A number depends on the size it was scored at (LPIPS features, flicker and flows in pixels;
    docs/design.md §8, "Scoring"), so methods of one scene scored at different sizes do not compare.
    Scenes of different sizes are not a mismatch: each is compared within itself.
    """
    metric_of = {o: m for m, outs in outputs_of.items() for o in outs}
    # (scene, output) -> label -> variants (a label merged from folders may hold several)
    seen: dict[tuple[str, str], dict[str, set[str]]] = {}
    for f in folders:
        for scene, weathers in sorted(f.doc["results"].items()):
            for outputs in weathers.values():
                for output, r in outputs.items():
                    if isinstance(r, dict):
                        seen.setdefault((scene, output), {}).setdefault(f.label, set()).add(str(r.get("variant", "")))
    scene_size: dict[str, str] = {}  # scene -> its frame size
    for f in folders:
        for scene in f.doc["results"]:
            size = f.frame_size(scene)
            if size is not None:
                scene_size.setdefault(scene, f"{size[0]}x{size[1]}")
    sizes: dict[str, dict[str, set[str]]] = {}  # scene -> label -> sizes scored at
    size_outputs: dict[str, set[str]] = {}  # scene -> outputs whose sizes differ
    definitions: dict[str, dict[str, set[str]]] = {}  # output -> label -> definitions
    for (scene, output), by_label in sorted(seen.items()):
        split = {label: [_split_variant(v) for v in sorted(vs)] for label, vs in by_label.items()}
        at = {label: {size or scene_size.get(scene, "the scene's size") for _, size in parts}
              for label, parts in split.items()}
        if len({tuple(sorted(v)) for v in at.values()}) > 1:
            size_outputs.setdefault(scene, set()).add(output)
            for label, v in at.items():
                sizes.setdefault(scene, {}).setdefault(label, set()).update(v)
        for label, parts in split.items():
            definitions.setdefault(output, {}).setdefault(label, set()).update(d for d, _ in parts)
    flags: list[Flag] = []
    if sizes:
        texts: dict[str, list[str]] = {}  # one text per pattern, with the scenes that show it
        for scene, by_label in sizes.items():
            text = "; ".join(f"{', '.join(labels)} {value}" for labels, value in
                             _grouped({label: "/".join(sorted(v)) for label, v in by_label.items()}))
            texts.setdefault(text, []).append(scene)
        several = len({s for f in folders for s in f.doc["results"]}) > 1
        where = "; ".join(text + (f" (on {', '.join(scenes)})" if several else "") for text, scenes in texts.items())
        units = frozenset((label, scene, output) for scene, outs in size_outputs.items()
                          for label in sizes[scene] for output in outs)
        flags.append(Flag("mismatch", "size",
                          f"scored at different sizes: {where} (what the metrics that read frames give depends "
                          "on the size: score them at one size, the default, to compare)",
                          units=units))
    by_metric: dict[tuple[str, str], list[str]] = {}  # (metric, definitions text) -> outputs
    for output, by_label in sorted(definitions.items()):
        if len({tuple(sorted(v)) for v in by_label.values()}) > 1:
            text = "; ".join(f"{{{', '.join(labels)}}}: {value}" for labels, value in
                             _grouped({label: " / ".join(sorted(v)) for label, v in by_label.items()}))
            by_metric.setdefault((metric_of.get(output, output), text), []).append(output)
    for (_metric, text), outputs in sorted(by_metric.items()):
        flags.append(Flag("mismatch", "variant", f"{', '.join(outputs)}: different definitions ({text})",
                          outputs=frozenset(outputs)))
    return flags


def mismatch_flags(folders: list[ResultsFolder], outputs_of: dict[str, set[str]]) -> list[Flag]:
    """Flags for inputs and definitions that differ across folders (none for a single folder),
    one per cause.

    Checks scene sets (per method), frame counts, source frames (sha256) and frame sizes (per
    scene), the resolutions one method's FPS were measured at, the sizes each scene was scored at,
    and each metric's definitions (variants) and settings.
    """
    flags: list[Flag] = []
    labels = sorted({f.label for f in folders})
    if len({f.label for f in folders}) != len(folders):
        merged = sorted({f.label for f in folders if sum(g.label == f.label for g in folders) > 1})
        flags.append(Flag("mismatch", "duplicate",
                          f"methods merged from several folders (disjoint scenes or weathers): {', '.join(merged)}",
                          methods=frozenset(merged)))
    for f in folders:
        if f.label != f.method:
            flags.append(Flag("mismatch", "duplicate",
                              f"{f.method} was scored in several folders on the same scenes; {f.path} is shown as "
                              f"its own row {f.label!r} (never averaged together)", methods=frozenset({f.label})))
    if len(folders) < 2:
        return flags
    scene_sets: dict[str, set[str]] = {}
    for f in folders:
        scene_sets.setdefault(f.label, set()).update(f.doc["results"])
    union = set().union(*scene_sets.values())
    for label in labels:
        if scene_sets[label] != union:
            flags.append(Flag(
                "mismatch", "scenes",
                f"{label} was scored on {', '.join(sorted(scene_sets[label]))} only, not on "
                f"{', '.join(sorted(union - scene_sets[label]))}: its means are over other scenes than the rest",
                methods=frozenset({label}), means_only=True))
    for scene in sorted(union):
        counts, sources, sizes = {}, {}, {}
        for f in folders:
            for weather in sorted(f.doc["results"].get(scene, {})):
                counts[f"{f.label}/{weather}"] = f.n_frames(scene, weather)
                sources[f.label] = f.hashes(scene, weather, "source")
            if scene in f.doc["results"]:
                size = f.frame_size(scene)
                if size is not None:
                    sizes[f.label] = f"{size[0]}x{size[1]}"
        if _differs(counts):
            flags.append(Flag("mismatch", "frames", f"{scene}: frame counts differ ({_listing(counts)})",
                              scenes=frozenset({scene})))
        if _differs({k: v for k, v in sources.items() if v is not None}):
            flags.append(Flag("mismatch", "source",
                              f"{scene}: the source frames differ across folders (sha256): "
                              f"{', '.join(sorted(sources))} scored different raw frames", scenes=frozenset({scene})))
        if _differs(sizes):
            flags.append(Flag("mismatch", "resolution", f"{scene}: frame sizes differ ({_listing(sizes)})",
                              scenes=frozenset({scene})))
    flags += _fps_flags(folders)
    flags += _definition_flags(folders, outputs_of)
    settings: dict[str, dict[str, str]] = {}
    for f in folders:
        for metric, cfg in f.doc["config"].get("metric_config", {}).items():
            settings.setdefault(metric, {})[f.label] = _settings(cfg)
    for metric, by_label in sorted(settings.items()):
        if len(by_label) > 1 and len(set(by_label.values())) > 1:
            groups: dict[str, list[str]] = {}
            for label, s in sorted(by_label.items()):
                groups.setdefault(s, []).append(label)
            flags.append(Flag(
                "mismatch", "settings",
                f"{metric}: computed with different settings or weights in "
                + " vs ".join("{" + ", ".join(g) + "}" for g in groups.values())
                + " (see Provenance)", outputs=frozenset(outputs_of.get(metric, {metric}))))
    return flags
