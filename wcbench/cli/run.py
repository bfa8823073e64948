"""Render with a runnable method, then evaluate: the whole benchmark in one command.

Frames go to OUT/<method>/<scene>/<weather>/{frame:03d}.png (+ info.json with timings), results
to OUT/results.json and OUT/results.csv. Both steps resume after a kill and skip finished work.

Examples::

    wcbench run --method filter2d --scenes demo --out runs/demo
    wcbench run --method identity --scenes pandaset_002 --data-root ../shared/data --out runs/id
    wcbench run --method weathercity --scenes pandaset_002 --data-root ../shared/data --out runs/wc
    wcbench run --method weathercity --scenes demo --profile quick --edit "remove class=Car" --out runs/edit
    wcbench run --method weathercity --scenes waymo_5 --out runs/wc --executor dask --workers 2
"""

from __future__ import annotations

import argparse
from contextlib import nullcontext

from wcbench.cli.common import (
    add_frame_and_size_arguments,
    add_method_options,
    add_scene_arguments,
    checked_method_options,
    executor_from,
    method_name,
    parse_metric_options,
    size_request_from,
    split_list,
)
from wcbench.cli.evaluate import add_evaluate_options, report
from wcbench.cli.report import write_report
from wcbench.core.errors import InputError

HELP = "render with a runnable method, then evaluate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``wcbench run``."""
    parser.add_argument("--method", required=True, type=method_name,
                        help="runnable method (see `wcbench methods list`)")
    add_scene_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="random seed of the method")
    add_frame_and_size_arguments(parser, size_help="size the method renders at (default: the method's own "
                                                   "size); frames are scored at the scene's working size, as "
                                                   "every method's are")
    add_evaluate_options(parser)
    add_method_options(parser)


def run(args: argparse.Namespace) -> int:
    """Render, then evaluate (one pass over the units of work)."""
    from wcbench.evaluation import EvaluateConfig, check_metrics, evaluate
    from wcbench.execution.background_compile import kernels_compiled_aside
    from wcbench.methods import get_method, is_runnable
    from wcbench.units import RenderSettings

    if args.frames and list(args.frames) != list(range(args.frames[0], args.frames[-1] + 1)):
        raise InputError(f"--frames {','.join(map(str, args.frames))}: run scores one contiguous run of frames "
                         "(temporal metrics compare neighbours), e.g. 0-9")
    method = get_method(args.method, **checked_method_options(args, args.method))
    size = size_request_from(args)
    if size is not None:
        if not is_runnable(method):
            raise InputError(f"method {args.method!r} is an output reader: --scale/--width/--height size what "
                             "wcbench renders")
        method.request_size(size)  # type: ignore[attr-defined]
    cfg = EvaluateConfig(
        method=args.method, scenes=args.scenes, predictions=args.out / method.info.name, out=args.out,
        weathers=split_list(args.weathers) or list(method.info.weathers), metrics=split_list(args.metrics),
        fps=args.fps, data_root=args.data_root, overwrite=args.overwrite, show_progress=not args.no_progress,
        metric_options=parse_metric_options(args.metric_option), metric_resolution=args.metric_resolution,
        frames=args.frames, offline=args.offline,
        render=RenderSettings(seed=args.seed, frames=args.frames, overwrite=args.overwrite,
                              show_progress=not args.no_progress),
    )
    check_metrics(cfg)  # before an executor starts (a Dask cluster); evaluate checks again
    # a method that renders with the reference model waits for its kernels on a fresh install: a second
    # process compiles them while this one fetches, generates and edits
    aside = kernels_compiled_aside() if is_runnable(method) and "torch" in method.info.requires \
        else nullcontext()
    with aside, executor_from(args) as executor:
        outcome = evaluate(cfg, method=method, executor=executor)
    report(outcome)
    if args.report:
        write_report([args.out], args.out / "report.html")
    return 0
