"""Build one self-contained HTML report from results folders (results.json + results.csv).

Tables like the paper's (methods x weather x metric, best bold, second underlined), per-scene
breakdowns, runtime, frame strips and animations, per-frame curves, benchmark charts and
provenance; numbers computed with unpublished weights and inputs that differ across folders are
flagged. The report reads result files only: methods scored separately, on another machine or
months apart go into one report. It opens from a file:// URL and makes no network request.

Examples::

    wcbench report runs/identity runs/filter2d --out report.html
    wcbench report runs/* --out paper/report.html --csv --latex
    wcbench report runs/a --bench bench/raster.json bench/metrics.json --out report.html

``-o`` and ``--output`` are deprecated spellings of ``--out``. Results written under a method's
old name (``lidar_init``) are read as they are.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wcbench.cli.common import add_deprecated_alias, add_output_argument

HELP = "build an HTML report (tables, frames, provenance) from results folders"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``RESULTS_DIR... [--out FILE] [--csv] [--latex] [--bench FILE...] [--title T] [--animation-frames N]``."""
    parser.add_argument("results", nargs="+", type=Path, metavar="RESULTS_DIR",
                        help="--out folder of `wcbench run` or `wcbench evaluate` (several are merged)")
    add_output_argument(parser, default=Path("report.html"), help="HTML file to write (default: report.html)")
    add_deprecated_alias(parser, "-o", "--output", use="--out", dest="out", type=Path, metavar="OUT")
    add_report_options(parser)


def add_report_options(parser: argparse.ArgumentParser) -> None:
    """Options of ``wcbench report`` besides the folders and the output file."""
    parser.add_argument("--csv", action="store_true",
                        help="also write the tables as CSV beside the HTML (same text as shown)")
    parser.add_argument("--latex", action="store_true",
                        help="also write the tables as LaTeX (booktabs) beside the HTML")
    parser.add_argument("--bench", nargs="+", type=Path, default=[], metavar="FILE",
                        help="benchmark JSON files (`wcbench bench SUITE --out FILE`) to chart as time vs error")
    parser.add_argument("--title", default=None, help="report heading (default: methods and scenes)")
    parser.add_argument("--animation-frames", type=int, default=12, metavar="N",
                        help="frames per animated sequence, 0-12 (0: none; default 12)")
    parser.add_argument("--no-frames", action="store_true",
                        help="leave out frame strips and animations (tables, curves, provenance only)")


def write_report(results: list[Path], output: Path, *, title: str | None = None, bench: list[Path] | None = None,
                 csv: bool = False, latex: bool = False, animation_frames: int = 12, frames: bool = True) -> int:
    """Build the report (:func:`wcbench.reports.build_report`) and print what was written; returns 0."""
    from wcbench.core.storage import check_writable_folder
    from wcbench.reports import build_report

    check_writable_folder(output.parent, what="folder of the report")
    outcome = build_report(results, output, title=title, bench=bench or [], csv=csv, latex=latex,
                           animation_frames=animation_frames, frames=frames)
    extra = [str(p) for p in (outcome.csv, outcome.latex) if p is not None]
    print(f"wrote {outcome.html} ({outcome.size_bytes / 1e6:.1f} MB, {outcome.n_images} images, "
          f"{outcome.seconds:.1f} s)" + (f" and {', '.join(extra)}" if extra else ""))
    for flag in outcome.flags:
        print(f"  flagged ({flag.topic}): {flag.message}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Build the report."""
    return write_report(list(args.results), args.out, title=args.title, bench=args.bench, csv=args.csv,
                        latex=args.latex, animation_frames=args.animation_frames, frames=not args.no_frames)
