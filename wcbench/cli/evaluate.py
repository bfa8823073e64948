"""Score a method's rendered frames from files alone and write results.json + results.csv.

The predictions folder holds one sub-folder per scene (left out when one scene is scored), named
like the scene id, its data folder (788 for waymo_788) or an alias of the scene set; each method
reader knows its tool's file naming (`wcbench methods list -v`), or pass --pattern. Re-running with
the same inputs does no work; a killed run resumes; finished results of other inputs are kept
unless --overwrite.

Examples::

    wcbench evaluate --method folder --scenes pandaset_002 --data-root ../shared/data \\
        --predictions my_frames/ --out results/mine
    wcbench evaluate --method controlnet --scenes waymo_5 --predictions controlnet_out/ \\
        --out results/controlnet --weathers rain,snow --metrics temporal_flicker,fps --fps 0.4
    wcbench evaluate --method fresco --scenes pandaset_002 --data-root ../shared/data \\
        --predictions fresco_rain/ --weathers rain --out results/fresco    # FRESCO's save_path itself
    wcbench evaluate --method controlnet --scenes waymo_5 --predictions controlnet_out/ \\
        --out results/controlnet --executor dask --scheduler tcp://HOST:8786   # on a Dask cluster
    wcbench evaluate --method lidar-init --scenes pandaset_002 --data-root ../shared/data \\
        --predictions renders/lidar-init --out results/render    # a `wcbench render` output, as it is
    wcbench evaluate --method folder --scenes pandaset_002 --data-root ../shared/data \\
        --predictions my_frames/ --frames 0-9 --scale 0.5 --out results/part   # frames 0-9 at 960x540

Every method of a scene is scored at the scene's working size, its frames resized to it: the scene's
frame size, downscaled to 960 px on the longer side when larger (``--metric-resolution``; ``native``
for the exact protocol); ``--scale`` or ``--width/--height`` sets the size scored at.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wcbench.cli.common import (
    METRIC_RESOLUTION,
    METRIC_RESOLUTION_HELP,
    add_executor_arguments,
    add_frame_and_size_arguments,
    add_offline_argument,
    add_output_argument,
    add_progress_argument,
    add_scene_arguments,
    add_weathers_argument,
    executor_from,
    frame_rate,
    method_name,
    metric_resolution,
    parse_metric_options,
    size_request_from,
    split_list,
)
from wcbench.cli.report import write_report

HELP = "score a method's frames (results.json, results.csv)"


def add_evaluate_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``evaluate`` and ``run``."""
    add_output_argument(parser, required=True, help="output folder for results.json / results.csv")
    add_weathers_argument(parser, help="weathers to score (default: every weather found / supported)")
    parser.add_argument("--metrics", nargs="+", default=None, help="metrics (default: see `wcbench metrics list`)")
    parser.add_argument("--fps", type=frame_rate, default=None, help="frame rate to report if info.json has none")
    parser.add_argument("--metric-option", action="append", default=[], metavar="METRIC.KEY=VALUE",
                        help="option of one metric, repeatable, e.g. sem_cs.segmenter=segformer-b0-ade, "
                             "clip_s.backend=torch, flow_warping_error.flow=deepflow (VALUE is read as JSON "
                             "when it parses, else as text); each metric's options: `wcbench metrics show NAME`")
    parser.add_argument("--metric-resolution", type=metric_resolution, default=METRIC_RESOLUTION,
                        metavar="PX|native", help=METRIC_RESOLUTION_HELP)
    parser.add_argument("--overwrite", action="store_true", help="replace finished results of other inputs")
    parser.add_argument("--report", action="store_true", help="also write OUT/report.html (see `wcbench report`)")
    add_offline_argument(parser)
    add_progress_argument(parser)
    add_executor_arguments(parser)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``wcbench evaluate``."""
    parser.add_argument("--method", required=True, type=method_name, help="method adapter (see `wcbench methods list`)")
    add_scene_arguments(parser)
    parser.add_argument("--predictions", type=Path, required=True, help="folder with the method's frames")
    parser.add_argument("--pattern", default=None, help="file pattern, e.g. '{weather}/{frame}.png' or '{weather}.mp4'")
    parser.add_argument("--resize", action="store_true",
                        help="resize predictions of another size to the scene's (readers of tools that work at "
                             "their own size do it anyway)")
    parser.add_argument("--frame-offset", type=int, default=0, metavar="N",
                        help="the method's frame i is scene frame i + N (default 0)")
    add_frame_and_size_arguments(parser, size_help="size the frames are scored at, predictions and scene frames "
                                                   "resized to it (default: the scene's working size, the "
                                                   "scene's frame size within --metric-resolution, for every "
                                                   "method)")
    add_evaluate_options(parser)


def report(outcome: object) -> None:
    """Print where results went and a short table."""
    from wcbench.evaluation import EvaluateOutcome, skipped_causes, summarize
    from wcbench.results import frames_text

    assert isinstance(outcome, EvaluateOutcome)
    doc = outcome.results
    for scene, f in doc["config"].get("scene_folders", {}).items():
        if Path(f["folder"]).name != scene:  # said whenever the folder is not simply named like the scene
            print(f"scene {scene}: predictions from {f['folder']} ({f['rule']})")
    for w in doc.get("warnings", []):
        print(f"warning: {w['scene']} {w['weather']}: {w['message']}", file=sys.stderr)
    sys.stderr.flush()
    if outcome.status == "up-to-date":
        print(f"up to date: {outcome.results_path} (inputs unchanged, nothing recomputed)")
    else:
        print(f"wrote {outcome.results_path} and results.csv "
              f"({outcome.units_computed} computed, {outcome.units_reused} reused)")
    for p in doc.get("partial", []):
        print(f"partial: {p['scene']} {p['weather']}: scored frames {p['scored'][0]}-{p['scored'][1]} of "
              f"{p['n_scene_frames']}, missing {frames_text(p['missing'])} ({p['reason']})")
    for scene, weather, name, text in summarize(outcome.results):
        print(f"  {scene:16s} {weather:6s} {name:26s} {text}")
    for reason, names, count in skipped_causes(outcome.results):
        print(f"skipped {', '.join(names)} ({count} row{'' if count == 1 else 's'}): {reason}")
    sys.stdout.flush()


def run(args: argparse.Namespace) -> int:
    """Evaluate and print a summary."""
    from wcbench.evaluation import EvaluateConfig, check_metrics, evaluate

    cfg = EvaluateConfig(
        method=args.method, scenes=args.scenes, predictions=args.predictions, out=args.out,
        weathers=split_list(args.weathers), metrics=split_list(args.metrics), pattern=args.pattern,
        resize=args.resize, fps=args.fps, frame_offset=args.frame_offset, data_root=args.data_root,
        overwrite=args.overwrite, metric_resolution=args.metric_resolution, frames=args.frames,
        score_size=size_request_from(args),
        show_progress=not args.no_progress, metric_options=parse_metric_options(args.metric_option),
        offline=args.offline,
    )
    check_metrics(cfg)  # before an executor starts (a Dask cluster); evaluate checks again
    with executor_from(args) as executor:
        outcome = evaluate(cfg, executor=executor)
    report(outcome)
    if args.report:
        write_report([args.out], args.out / "report.html")
    return 0
