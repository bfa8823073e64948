"""Arguments shared by several verbs: one spelling per concept on every command.

=================  ==========================================  ===================================
concept            spelling                                    deprecated aliases (one release)
=================  ==========================================  ===================================
output             ``--out``                                   report ``-o/--output``, bench ``--json``
weathers           ``--weathers W [W ...]`` (or ``a,b``)       render ``--weather``
scenes, data       ``--scenes``, ``--data-root``
method options     ``--method-option KEY=VALUE`` and the       train ``--setting KEY=VALUE``
                   shorthands ``--profile --supervision        (= ``--method-option settings.KEY=VALUE``)
                   --jitter --ablation --holdout`` (run,
                   render, train alike)
physics weather    ``--method-option physics=...``             ``--method-option weathers=...``
                   (lidar-init, physical-editor,               (``--weathers`` lists weather kinds)
                   weathercity)
metric options     ``--metric-option METRIC.KEY=VALUE``
progress, offline  ``--no-progress``, ``--offline``
frames, size       ``--frames``, ``--scale`` | ``--width/--height``
method names       hyphenated: ``lidar-init``                  ``lidar_init`` (any ``_`` spelling)
=================  ==========================================  ===================================

A deprecated spelling works as its replacement, says so in ``--help`` and prints one line on
stderr when used (``wcbench: --output is deprecated, use --out``; a method option's old name:
``wcbench: method option weathers is deprecated, use physics``, and ``wcbench methods show``
lists it as such). ``tests/cli/test_vocabulary.py`` checks every command against this table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.weathers import WEATHERS
from wcbench.core.working_size import METRIC_RESOLUTION, SizeRequest, parse_metric_resolution
from wcbench.methods import METHODS, validate_method_options

#: Namespace attribute listing the deprecated spellings a command line used.
DEPRECATED_USED = "_deprecated_used"


def warn_deprecated(old: str, new: str, namespace: argparse.Namespace | None = None) -> None:
    """Print ``wcbench: OLD is deprecated, use NEW`` on stderr (once per command line when
    ``namespace`` is given) and record ``old`` in it."""
    used: set[str] = set(getattr(namespace, DEPRECATED_USED, ())) if namespace is not None else set()
    if old not in used:
        print(f"wcbench: {old} is deprecated, use {new}", file=sys.stderr, flush=True)
    if namespace is not None:
        setattr(namespace, DEPRECATED_USED, used | {old})


def used_deprecated(args: argparse.Namespace, old: str) -> bool:
    """Whether the command line of ``args`` used the deprecated spelling ``old``."""
    return old in getattr(args, DEPRECATED_USED, ())


class DeprecatedAlias(argparse.Action):
    """An old spelling of an option: parses into the new one's ``dest`` and warns once on stderr.

    Parameters
    ----------
    use : str
        The spelling to use instead, as the warning and ``--help`` show it.
    convert : callable, optional
        Turns the parsed value into the new option's (e.g. one weather -> a list of one).
    append : bool
        Append to the new option's list (for repeatable options) instead of replacing it.
    """

    def __init__(self, option_strings: Sequence[str], dest: str, *, use: str,
                 convert: Callable[[Any], Any] | None = None, append: bool = False, **kwargs: Any):
        kwargs.setdefault("default", argparse.SUPPRESS)  # never overwrites the new option's default
        kwargs["help"] = f"deprecated alias of {use}" + (f" ({kwargs['help']})" if kwargs.get("help") else "")
        super().__init__(option_strings, dest, **kwargs)
        self.use, self.convert, self.append = use, convert, append

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        warn_deprecated(option_string or self.option_strings[0], self.use, namespace)
        value = self.convert(values) if self.convert is not None else values
        if self.append:
            value = [*(getattr(namespace, self.dest, None) or []), value]
        setattr(namespace, self.dest, value)


def add_deprecated_alias(parser: argparse.ArgumentParser | Any, *flags: str, use: str, dest: str,
                         **kwargs: Any) -> argparse.Action:
    """Add ``flags`` as deprecated spellings of the option ``use`` names (see :class:`DeprecatedAlias`)."""
    return parser.add_argument(*flags, dest=dest, action=DeprecatedAlias, use=use, **kwargs)  # type: ignore[no-any-return]


def method_name(text: str) -> str:
    """argparse type of ``--method``: a registered method name, returned as its current spelling (an
    old one, ``lidar_init``, says it is deprecated). Checked as it is parsed, so an unknown method is
    reported before any missing option (the registry lists names without importing them)."""
    if text not in METHODS:
        raise argparse.ArgumentTypeError(str(UnknownNameError("method", text, METHODS.names())))
    name = METHODS.canonical(text, warn=False)
    if name != text:
        warn_deprecated(f"method name {text!r}", repr(name))
    return name


def add_output_argument(parser: argparse.ArgumentParser, *, help: str, required: bool = False,
                        default: Path | None = None) -> argparse.Action:
    """``--out``: where a command writes (a folder, or the file ``help`` says), on every command."""
    return parser.add_argument("--out", type=Path, required=required, default=default, metavar="OUT",
                               help=help)


def add_weathers_argument(parser: argparse.ArgumentParser, *, help: str, required: bool = False) -> argparse.Action:
    """``--weathers W [W ...]`` (also ``a,b``), on every command that takes weathers (render reads it
    with :func:`weathers_from`; run and evaluate leave the check to the evaluation, which knows what
    the method supports)."""
    return parser.add_argument("--weathers", nargs="+", default=None, required=required, metavar="WEATHER",
                               help=f"{help}; one or more of {', '.join(WEATHERS)}, e.g. rain snow or rain,snow")


def weathers_from(values: list[str] | None, *, known: Sequence[str] = WEATHERS) -> list[str] | None:
    """The weathers of ``--weathers`` (``None`` when not given), each checked against ``known``.

    Raises
    ------
    UnknownNameError
        On a weather not in ``known`` (with close-name suggestions).
    """
    names = split_list(values)
    for name in names or []:
        if name not in known:
            raise UnknownNameError("weather", name, known)
    return names


def frame_rate(text: str) -> float:
    """argparse type of ``--fps``: a finite frame rate in (0, 1e6]."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0 < value <= 1e6):
        raise argparse.ArgumentTypeError(f"expected a frame rate in frames per second, > 0 and finite, got {text!r}")
    return value


def metric_resolution(text: str) -> int | None:
    """argparse type of ``--metric-resolution``: ``native`` (``None``) or the longer side in pixels."""
    try:
        return parse_metric_resolution(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: Help of ``--metric-resolution`` (run, evaluate).
METRIC_RESOLUTION_HELP = (f"score every method of a scene at the scene's frame size, area-downscaled to PX pixels "
                          f"on the longer side when larger (default {METRIC_RESOLUTION}, from the time-versus-error "
                          "table of `wcbench bench metrics`); native: the exact protocol at the scene's frame size")


#: Help of ``--frames`` (run, render, evaluate).
FRAMES_HELP = "frames: 17, 0-9, 0,5,10 (ranges inclusive; default: all; run and evaluate score one contiguous run)"


def parse_frame_spec(spec: str, *, option: str = "--frames") -> list[int]:
    """Frame indices of ``--frames`` (``17``, ``0-9``, ``0,5,10``; ranges inclusive), sorted, unchecked
    against any scene; ``option`` names the option in errors.

    Raises
    ------
    InputError
        On a malformed spec or one that selects no frame.
    """
    out: set[int] = set()
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part[1:]:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
            else:
                lo = hi = int(part)
        except ValueError:
            raise InputError(f"{option}: cannot parse {part!r}; use e.g. 17, 0-9 or 0,5,10") from None
        if hi < lo:
            raise InputError(f"{option}: the range {part} is reversed; write {hi}-{lo}")
        out.update(range(lo, hi + 1))
    if not out:
        raise InputError(f"{option}: {spec!r} selects no frame")
    return sorted(out)


def frames_option(text: str) -> tuple[int, ...]:
    """argparse type of ``--frames`` on run and evaluate."""
    try:
        return tuple(parse_frame_spec(text))
    except InputError as exc:  # argparse names the option itself
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--frames: ")) from None


def add_frame_and_size_arguments(parser: argparse.ArgumentParser, *, size_help: str) -> None:
    """``--frames`` and ``--scale`` | ``--width/--height``: one vocabulary for run, render and evaluate.

    ``size_help`` says what the size is of (rendered frames, scored frames) and its default.
    """
    parser.add_argument("--frames", type=frames_option, default=None, help=FRAMES_HELP)
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--scale", type=float, default=None, help=f"{size_help} as a fraction of the scene's size")
    group.add_argument("--width", type=int, default=None, help="width in px (with --height)")
    parser.add_argument("--height", type=int, default=None, help="height in px (with --width)")


def size_request_from(args: argparse.Namespace) -> SizeRequest | None:
    """The size ``--scale`` or ``--width/--height`` ask for; ``None`` when neither is given.

    Raises
    ------
    InputError
        ``--width`` without ``--height`` (or the reverse), or sizes that are not positive.
    """
    if args.width is not None or args.height is not None:
        if args.width is None or args.height is None:
            raise InputError("--width and --height go together")
        return SizeRequest(size=(int(args.width), int(args.height)))
    return None if args.scale is None else SizeRequest(scale=float(args.scale))


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """``--scenes`` and ``--data-root``."""
    parser.add_argument("--scenes", required=True,
                        help="scene set name (see `wcbench scenes list`), path to one processed scene folder, "
                             "or a comma-separated list of both")
    add_data_root_argument(parser)


def add_data_root_argument(parser: argparse.ArgumentParser, *, what: str = "") -> argparse.Action:
    """``--data-root``: the folder holding the datasets (``what`` says what it is for)."""
    return parser.add_argument("--data-root", type=Path, default=None, metavar="DIR",
                               help=f"folder holding the datasets{what} (default: $WCBENCH_DATA)")


def add_offline_argument(parser: argparse.ArgumentParser) -> None:
    """``--offline``: fetch no missing weights (also ``WCBENCH_OFFLINE=1``)."""
    parser.add_argument("--offline", action="store_true",
                        help="fetch no missing weights (also WCBENCH_OFFLINE=1); by default the weights the "
                             "metrics and the method need are fetched into the model store first, when their "
                             "source is pinned (LPIPS, VGG16, the CLIP vocabulary); what stays missing is "
                             "skipped with the command that installs it")


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def parse_metric_options(items: list[str]) -> dict[str, dict[str, Any]]:
    """``["sem_cs.segmenter=segformer-b0-ade", "clip_s.batch_size=8"]`` -> ``{metric: {key: value}}``.

    Values are read as JSON when they parse (numbers, booleans), else kept as text; whether a metric
    takes them is :func:`~wcbench.evaluation.check_metrics`'s to say (before any work).

    Raises
    ------
    InputError
        On an item not of the form ``METRIC.KEY=VALUE``.
    """
    out: dict[str, dict[str, Any]] = {}
    form, example = "METRIC.KEY=VALUE", "sem_cs.segmenter=segformer-b0-ade"
    for item in items:
        [(key, value)] = parse_key_values([item], option="--metric-option", example=example, form=form).items()
        metric, dot, option = key.partition(".")
        if not (dot and metric and option):
            raise InputError(f"--metric-option {item!r}: expected {form}, e.g. {example}")
        out.setdefault(metric, {})[option] = value
    return out


def split_list(values: list[str] | None) -> list[str] | None:
    """Accept both ``--x a b`` and ``--x a,b``."""
    if not values:
        return None
    return [v for item in values for v in item.split(",") if v]


#: The method options every command that builds a method (run, render, train) takes as flags of their
#: own; each is the same as ``--method-option KEY=VALUE`` (shorthand -> key).
METHOD_OPTION_FLAGS = {"profile": "profile", "supervision": "supervision", "jitter": "jitter",
                       "ablation": "ablation", "holdout": "holdout", "edit": "edits", "device": "device"}


def add_method_options(parser: argparse.ArgumentParser, *, edit: bool = True) -> argparse._ArgumentGroup:
    """Options handed to the method: ``--method-option KEY=VALUE`` and its shorthands ``--profile``,
    ``--supervision``, ``--jitter``, ``--ablation``, ``--holdout``, ``--device`` (and ``--edit`` unless
    ``edit`` is false), spelled and read alike on run, render and train (:func:`method_options_from`).

    A method that does not take one of them refuses it by name (``wcbench methods list -v``
    shows what each takes). Returns the group, for a command's own deprecated spellings.
    """
    group = parser.add_argument_group(
        "method options",
        "  passed to the method, spelled alike on run, render and train; each flag below is a\n"
        "  shorthand of --method-option KEY=VALUE (--holdout 5,15 is holdout=[5,15]); a method\n"
        "  refuses an option it does not take (see `wcbench methods list -v`)")
    group.add_argument("--method-option", action="append", default=[], metavar="KEY=VALUE",
                       help="any option of the method, repeatable; VALUE is read as JSON when it parses, and "
                            "KEY.SUB=VALUE sets one entry of a dict option, e.g. settings.iterations=500, "
                            "physics.rain.preset=heavy (weathercity)")
    group.add_argument("--profile", default=None, help="training profile of a trained method: default, quick, paper")
    group.add_argument("--supervision", default=None,
                       help="edited frames a trained method learns from: physical-editor (built in, the "
                            "default), filter2d (built in), sim-editor[:SEVERITY] (needs ground-truth scenes, "
                            "e.g. synth_1) or READER:DIR, e.g. qwen-image:edits/")
    group.add_argument("--jitter", type=float, default=None, metavar="J",
                       help="per-frame perturbation of the filter2d supervision (or of filter2d itself), 0..1")
    group.add_argument("--ablation", default=None, help="named ablation of a trained method: no-wgs, no-content-loss")
    group.add_argument("--holdout", nargs="+", default=None, metavar="FRAME",
                       help="frames a trained method leaves out of training and scores, e.g. 5,15,25")
    group.add_argument("--device", default=None, choices=("cpu", "cuda"),
                       help="where a trained method trains and rasterizes: cpu (the default) or cuda (needs "
                            "the [cuda] extra, gsplat, and a CUDA device; docs/workstation.md)")
    if edit:
        group.add_argument("--edit", action="append", default=None, metavar="EDIT",
                           help="object edit, repeatable: 'remove class=Car except ids=3,7', "
                                "'translate id=5 by=0,2,0', 'insert id=5 by=0,4,0' (a copy), "
                                "'insert scene=OTHER id=5 at=X,Y,YAW' (an object of another trained scene "
                                "standing on this one's ground, world metres and degrees), or a JSON list")
    return group


def _set_nested(out: dict[str, Any], key: str, value: Any, *, item: str) -> None:
    """``out[a][b] = value`` for ``key`` ``a.b`` (any depth), merging with dicts already there."""
    *parents, last = key.split(".")
    node = out
    for i, part in enumerate(parents):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise InputError(f"--method-option {item!r}: {'.'.join(parents[:i + 1])} is already set to "
                             f"{json.dumps(child)}, not a dict")
        node = child
    if isinstance(node.get(last), dict) and isinstance(value, dict):
        node[last] = {**node[last], **value}
    else:
        node[last] = value


def method_options_from(args: argparse.Namespace) -> dict[str, Any]:
    """The method options given on the command line (only those given): ``--method-option`` items,
    the shorthand flags, and a deprecated ``--setting KEY=VALUE`` as ``settings.KEY=VALUE``.

    Raises
    ------
    InputError
        On a ``--method-option`` not of the form ``KEY=VALUE``, a bad ``--holdout``, or one option
        given twice (a flag and a ``--method-option`` of the same key).
    """
    out: dict[str, Any] = {}
    for item in getattr(args, "method_option", []) or []:
        [(key, value)] = parse_key_values([item], option="--method-option", example="jitter=0.5").items()
        if any(not part for part in key.split(".")):
            raise InputError(f"--method-option {item!r}: expected KEY=VALUE or KEY.SUB=VALUE, e.g. "
                             "settings.iterations=500")
        _set_nested(out, key, value, item=item)
    settings = parse_key_values(getattr(args, "setting", None) or [], option="--setting", example="iterations=500")
    for key, value in settings.items():
        _set_nested(out, f"settings.{key}", value, item=f"settings.{key}={json.dumps(value)}")
    flags: dict[str, Any] = {}
    for flag, key in METHOD_OPTION_FLAGS.items():
        value = getattr(args, flag, None)
        if value is not None:
            flags[key] = value
    if "holdout" in flags:
        flags["holdout"] = parse_frame_spec(",".join(flags["holdout"]), option="--holdout")
    if isinstance(out.get("holdout"), str):  # holdout=5,15,25 reads as --holdout 5,15,25
        out["holdout"] = parse_frame_spec(out["holdout"], option="--method-option holdout")
    if "edits" in flags:
        flags["edits"] = list(flags["edits"])
    twice = sorted(set(flags) & set(out))
    if twice:
        shown = {v: k for k, v in METHOD_OPTION_FLAGS.items()}
        raise InputError(f"method option {', '.join(twice)} given twice: as "
                         f"{', '.join('--' + shown[k] for k in twice)} and as --method-option; give it once")
    return {**out, **flags}


def checked_method_options(args: argparse.Namespace, method: str,
                           options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The method options of ``args`` (or ``options``) checked against method ``method``'s declared
    options, as its constructor takes them: an option given by its old name (``weathers``) is
    passed on under its new one (``physics``) and said once on stderr
    (``wcbench: method option weathers is deprecated, use physics``), after its value is checked.

    Raises
    ------
    InputError
        As :func:`method_options_from`; ``OptionError`` as
        :func:`wcbench.methods.validate_method_options` (an option given by both names: both named).
    """
    given = method_options_from(args) if options is None else options
    return validate_method_options(method, given,
                                   deprecated=lambda old, new: warn_deprecated(f"method option {old}", new, args))


def parse_key_values(items: list[str], *, option: str, example: str, form: str = "KEY=VALUE") -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}``: values read as JSON when they parse, else text.

    Raises
    ------
    InputError
        On an item not of the form ``KEY=VALUE`` (naming ``option``, ``form`` and ``example``).
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not (sep and key):
            raise InputError(f"{option} {item!r}: expected {form}, e.g. {example}")
        try:
            out[key] = json.loads(raw)
        except json.JSONDecodeError:
            out[key] = raw
    return out


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor``, ``--scheduler`` and ``--workers`` (where the units of work run)."""
    group = parser.add_argument_group("where units run")
    group.add_argument("--executor", choices=("local", "dask"), default=None,
                       help="local (default: this process) or dask (needs the [dask] extra; OUT, the "
                            "predictions and the cache folder on a filesystem every worker shares)")
    group.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="with --executor dask: a running scheduler, e.g. tcp://HOST:8786")
    group.add_argument("--workers", type=int, default=None, metavar="N",
                       help="with --executor dask: start a local cluster of N worker processes "
                            "(default: one per core)")


def executor_from(args: argparse.Namespace) -> Any:
    """The executor ``args`` ask for (a context manager that closes what it started).

    Raises
    ------
    InputError
        ``--scheduler`` or ``--workers`` without ``--executor dask``.
    """
    from wcbench.execution import make_executor

    name = args.executor or "local"
    if name != "dask" and (args.scheduler or args.workers is not None):
        raise InputError("--scheduler and --workers go with --executor dask")
    if name == "dask":
        return make_executor("dask", scheduler=args.scheduler, workers=args.workers,
                             show_progress=not args.no_progress)
    return make_executor(name)
