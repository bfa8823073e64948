"""Arguments shared by several verbs."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.working_size import METRIC_RESOLUTION, SizeRequest, parse_metric_resolution
from wcbench.methods import METHODS


def method_name(text: str) -> str:
    """argparse type of ``--method``: a registered method name. Checked as it is parsed, so an unknown
    method is reported before any missing option (the registry lists names without importing them)."""
    if text not in METHODS:
        raise argparse.ArgumentTypeError(str(UnknownNameError("method", text, METHODS.names())))
    return text


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


def parse_frame_spec(spec: str) -> list[int]:
    """Frame indices of ``--frames`` (``17``, ``0-9``, ``0,5,10``; ranges inclusive), sorted, unchecked
    against any scene.

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
                if hi < lo:
                    raise ValueError
                out.update(range(lo, hi + 1))
            else:
                out.add(int(part))
        except ValueError:
            raise InputError(f"--frames: cannot parse {part!r}; use e.g. 17, 0-9 or 0,5,10") from None
    if not out:
        raise InputError(f"--frames: {spec!r} selects no frame")
    return sorted(out)


def frames_option(text: str) -> tuple[int, ...]:
    """argparse type of ``--frames`` on run and evaluate."""
    try:
        return tuple(parse_frame_spec(text))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder holding the datasets (default: $WCBENCH_DATA)")


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

    Values are read as JSON when they parse (numbers, booleans), else kept as text.

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


def add_method_options(parser: argparse.ArgumentParser) -> None:
    """Options handed to a runnable method (``--profile``, ``--supervision``, ``--edit``, ``--method-option``).

    A method that does not take one of them refuses it by name (``wcbench methods list -v``
    shows what each takes).
    """
    group = parser.add_argument_group("method options (passed to the method; see `wcbench methods list -v`)")
    group.add_argument("--profile", default=None, help="training profile of a trained method: default, quick")
    group.add_argument("--supervision", default=None,
                       help="edited frames a trained method learns from: physical-editor (built in, the "
                            "default), filter2d (built in), sim-editor[:SEVERITY] (needs ground-truth scenes, "
                            "e.g. synth_1) or READER:DIR, e.g. qwen-image:edits/")
    group.add_argument("--edit", action="append", default=None, metavar="EDIT",
                       help="object edit, repeatable: 'remove class=Car except ids=3,7', "
                            "'translate id=5 by=0,2,0', or a JSON list")
    group.add_argument("--method-option", action="append", default=[], metavar="KEY=VALUE",
                       help="any option of the method, repeatable (VALUE read as JSON when it parses), "
                            "e.g. jitter=0.5, ablation=no-wgs, holdout=[5,15,25]")


def method_options_from(args: argparse.Namespace) -> dict[str, Any]:
    """The method options given on the command line (only those given).

    Raises
    ------
    InputError
        On a ``--method-option`` not of the form ``KEY=VALUE``.
    """
    out: dict[str, Any] = {}
    for name in ("profile", "supervision"):
        if getattr(args, name, None) is not None:
            out[name] = getattr(args, name)
    if getattr(args, "edit", None):
        out["edits"] = list(args.edit)
    out.update(parse_key_values(getattr(args, "method_option", []) or [], option="--method-option",
                                example="jitter=0.5"))
    return out


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
