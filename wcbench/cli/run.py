"""Render with a runnable method, then evaluate: the whole benchmark in one command.

Frames go to OUT/<method>/<scene>/<weather>/{frame:03d}.png (+ info.json with timings), results
to OUT/results.json and OUT/results.csv. Both steps resume after a kill and skip finished work.

Examples::

    wcbench run --method filter2d --scenes demo --out runs/demo
    wcbench run --method identity --scenes pandaset_002 --data-root ../shared/data --out runs/id
"""

from __future__ import annotations

import argparse

from wcbench.cli.common import add_scene_arguments, parse_metric_options, split_list
from wcbench.cli.evaluate import add_evaluate_options, report

HELP = "render with a runnable method, then evaluate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``wcbench run``."""
    parser.add_argument("--method", required=True, help="runnable method (see `wcbench methods list`)")
    add_scene_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="random seed of the method")
    add_evaluate_options(parser)


def run(args: argparse.Namespace) -> int:
    """Render, then evaluate."""
    from wcbench.evaluation import EvaluateConfig, check_out_folder, evaluate
    from wcbench.methods import get_method
    from wcbench.rendering import render_predictions
    from wcbench.scene_sets import resolve_scenes

    method = get_method(args.method)
    weathers = split_list(args.weathers) or list(method.info.weathers)
    cfg = EvaluateConfig(
        method=args.method, scenes=args.scenes, predictions=args.out / method.info.name, out=args.out,
        weathers=weathers, metrics=split_list(args.metrics), fps=args.fps, data_root=args.data_root,
        overwrite=args.overwrite, show_progress=not args.no_progress,
        metric_options=parse_metric_options(args.metric_option),
    )
    check_out_folder(cfg)
    scenes = resolve_scenes(args.scenes, data_root=args.data_root)
    render_predictions(method, scenes, weathers, cfg.predictions, seed=args.seed, overwrite=args.overwrite,
                       show_progress=not args.no_progress)
    report(evaluate(cfg))
    if args.report:
        from wcbench.cli.report import write_report

        write_report([args.out], args.out / "report.html")
    return 0
