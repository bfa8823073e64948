"""HTML reports built from results files alone (``wcbench report``).

The report reads ``results.json`` / ``results.csv`` (and the frames and ``info.json`` files they
record), never scenes or metrics, so methods scored separately, elsewhere or months apart can be
put side by side. Entry point: :func:`build_report`.
"""

from .builder import ReportOutcome, build_report
from .loading import ResultsFolder, load_results_folder

__all__ = ["ReportOutcome", "ResultsFolder", "build_report", "load_results_folder"]
