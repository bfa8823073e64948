"""How far the editor's frame time moves from run to run on this machine (issue 36's 150 ms goal;
docs/findings.md, "The editor's time is a draw").

Runs ``bench streets``' editor case (``editor_<scene>``: every frame of rain, snow and fog, one weather
after the other, each frame paying for its surface maps) ``--runs`` times, each in a fresh process
(the scene's analysis, the kernels' on-disk caches and the editor's memos as a first run has them),
and prints each run's median frame time over all weathers and per weather, with the 1-minute load
average and the CPU clock before it, then the spread of the runs. A goal judged to a few
milliseconds needs this spread first: one run's median is one draw of it. The frames themselves
are not compared here (``bench streets`` does that); every run edits the same frames with the same
code.

Usage::

    python tools/editor_time_spread.py --data-root ../shared/data --scene pandaset_002 --runs 5 [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from wcbench.core.environment import machine_info

#: What one run executes in its own process: the bench's editor case, its times as JSON on stdout.
_CHILD = """
import json, sys
from wcbench.bench.streets import _editor_case
from wcbench.scenes.loaders import load_scene
case, _ = _editor_case(sys.argv[1], load_scene(sys.argv[2]))
print(json.dumps({k: v for k, v in case.extra.items() if k.startswith("ms_per_frame")}))
"""


def _clock_mhz() -> float | None:
    """The mean clock of the CPUs (MHz) from ``/proc/cpuinfo``; ``None`` where it is not there."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return None
    mhz = [float(line.split(":")[1]) for line in lines if line.startswith("cpu MHz")]
    return round(statistics.fmean(mhz), 1) if mhz else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, required=True, help="folder of the scenes (../shared/data)")
    parser.add_argument("--scene", default="pandaset_002", help="scene folder name (default pandaset_002)")
    parser.add_argument("--runs", type=int, default=5, help="runs, each in a fresh process (default 5)")
    parser.add_argument("--out", type=Path, help="also write the runs and their spread as JSON here")
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error(f"--runs must be at least 2 to give a spread, got {args.runs}")
    folder = args.data_root / args.scene
    if not (folder / "images").is_dir():
        parser.error(f"{folder}: a scene folder with images/ was expected")
    runs = []
    for i in range(args.runs):
        load, mhz = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan"), _clock_mhz()
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", _CHILD, args.scene, str(folder)], capture_output=True, text=True,
                              env={**os.environ, "WCBENCH_PROGRESS": "0"})
        if done.returncode != 0:
            print(done.stderr, file=sys.stderr)
            raise SystemExit(f"run {i + 1} failed (exit {done.returncode}); its error is above")
        times = json.loads(done.stdout.strip().splitlines()[-1])
        runs.append({"load_1min_before": round(load, 2), "cpu_mhz_before": mhz,
                     "seconds": round(time.perf_counter() - start, 1), **times})
        print(f"run {i + 1}/{args.runs}: median {times['ms_per_frame_median']:.1f} ms (rain "
              f"{times['ms_per_frame_median_rain']:.1f}, snow {times['ms_per_frame_median_snow']:.1f}, fog "
              f"{times['ms_per_frame_median_fog']:.1f}); load {load:.2f} before, CPU {mhz} MHz", flush=True)
    medians = [r["ms_per_frame_median"] for r in runs]
    spread = {"runs": len(runs), "min_ms": min(medians), "median_ms": round(statistics.median(medians), 1),
              "max_ms": max(medians), "max_over_min": round(max(medians) / min(medians), 3)}
    print(f"{args.scene}: the median frame over {len(runs)} runs {spread['min_ms']:.1f} to {spread['max_ms']:.1f} ms "
          f"(median {spread['median_ms']:.1f}; slowest / fastest {spread['max_over_min']:.3f})")
    if args.out:
        args.out.write_text(json.dumps({"scene": args.scene, "machine": machine_info(), "spread": spread, "runs": runs},
                                   indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
