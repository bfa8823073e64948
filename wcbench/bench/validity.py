"""``wcbench bench validity``: do the proxy metrics agree with the truth?

The ``synth_*`` scenes ship true rain, snow and fog frames (docs/design.md §3), so every method can
be scored against the truth (PSNR, SSIM, LPIPS) next to the proxies the paper has to use without
it (CLIP-S, CLIP-DS, Sem-CS) and the temporal ones (flicker, flow warping error, their ratios).

Cases
-----
``<entry>``
    One method (``identity``, ``filter2d``, ``physical-editor``, ``lidar-init`` outside ``--quick``),
    one severity of
    the simulated editor (``sim-editor_<s>``) or the truth itself (``truth``: severity 0),
    rendered and scored on every scene of the set and every edited weather: the mean of each
    output over those units (``null`` where a metric skipped, the reason in the notes),
    ``time_ms`` of rendering and scoring, ``error`` the mean LPIPS against the truth; per weather
    PSNR, LPIPS and flicker ratio, and ``frames``: the median whole-frame time of the renders.
``agree_<proxy>_<truth>``
    Spearman's rank correlation between a proxy and a truth metric over every unit (entry x scene
    x weather), oriented so that +1 means the proxy ranks units as the truth does (a lower-is-better
    proxy against PSNR counts its negative), with a 95 % percentile bootstrap interval over units
    (2,000 resamples, seeded). The notes give one line per proxy: it tracks the truth when, against
    PSNR, SSIM and LPIPS alike, its correlation is at least 0.5 and its interval lies above 0;
    otherwise the line says plainly that it does not.
``supervised_<label>``
    (outside ``--quick``) WeatherCity (``default`` profile) trained on each supervision: its default
    ``physical-editor``, ``filter2d`` and ``sim-editor`` at severities 0.5 and 1, against the
    supervision's frames themselves: PSNR against the truth (``closer_psnr``: WeatherCity's is
    higher), and temporal flicker next to the truth's own (``closer_flicker``: WeatherCity's is
    nearer it), in the mean and per weather; ``psnr_clear_vs_raw``, the same run's clear
    reconstruction. WeatherCity renders the weather the truth requested (``physics="truth"``:
    rate, visibility, wind) with the run's particle seed, never the truth's (docs/design.md §4):
    the editor's frames start from the truth's own particles, WeatherCity draws its own, and
    another draw of heavy snow alone is about 34 dB from the truth (heavy rain 47 dB), a cap near
    the scores compared that favours the editor and says nothing about the scene.
``first_run_<set>``
    (outside ``--quick``) The README's main job, ``wcbench run --method weathercity --scenes <set>
    --profile quick --report``, in a new process as on a fresh install: empty scene cache (the scenes are
    generated), empty model store (the weights it needs are fetched on first use, as the README's
    first command does), empty numba cache (the kernels compile). ``limit_s`` is the time it must
    stay under (4 min for ``synth_1``, 15 min for ``synth_3``); ``psnr_<weather>``: against the
    truth (clear: against the raw frames).

``--quick`` runs ``synth_1`` with two severities; the full suite runs ``synth_3``. Set
``WCBENCH_BENCH_VALIDITY_GROUPS`` to run some of the groups ``scores,first_run`` (default both):
``scores`` is every case but the first runs (over an hour on 2 cores), ``first_run`` the first runs
alone (minutes; ``docs/bench/first-run.json``).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from wcbench.bench.metric_models import private_caches
from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.core.errors import InputError
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.methods import get_method
from wcbench.units import RenderSettings

__all__ = ["agreement", "run"]

EDITED = ("rain", "snow", "fog")
TRUTH = ("psnr", "ssim", "lpips")
PROXY_METRICS = ("clip_s", "clip_ds", "sem_cs", "temporal_flicker", "flow_warping_error")
#: outputs compared with the truth (a metric may give two: the value and its ratio to the source)
PROXIES = ("clip_s", "clip_ds", "sem_cs", "temporal_flicker", "temporal_flicker_ratio", "flow_warping_error",
           "flow_warping_error_ratio")
WEAK = 0.5
BOOTSTRAP = 2000
#: The issues' limits on the README main job from a fresh install (s): 4 minutes for synth_1 (issue 36).
FIRST_RUN_LIMIT_S = {"synth_1": 240.0, "synth_3": 900.0}
#: The case groups of ``WCBENCH_BENCH_VALIDITY_GROUPS`` (default all).
GROUPS = ("scores", "first_run")
#: The supervisions WeatherCity is trained on (outside --quick): its default (the physical editor),
#: the 2D grade, and the simulated editor at two severities (label, --supervision, the entry whose
#: frames it is compared with).
SUPERVISIONS = (("physical-editor", "physical-editor", "physical-editor"), ("filter2d", "filter2d", "filter2d"),
                ("sim-editor_0.5", "sim-editor:0.5", "sim-editor_0.5"),
                ("sim-editor_1", "sim-editor:1", "sim-editor_1"))


def agreement(proxy: np.ndarray, truth: np.ndarray, *, sign: float = 1.0, resamples: int = BOOTSTRAP,
              seed: int = 0) -> tuple[float, float, float]:
    """Spearman's rho of ``proxy`` against ``truth`` [N] times ``sign``, with a 95 % percentile
    bootstrap interval over the N points.

    Returns
    -------
    (rho, low, high) : floats
        NaN when fewer than 3 points or when either series is constant; resamples in which one is
        constant are left out of the interval.
    """
    x, y = np.asarray(proxy, np.float64), np.asarray(truth, np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"proxy and truth must be two series of one length, got {x.shape} and {y.shape}")
    nan = float("nan")
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return nan, nan, nan
    rho = sign * float(spearmanr(x, y).statistic)
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(resamples):
        idx = rng.integers(0, len(x), len(x))
        if np.ptp(x[idx]) > 0 and np.ptp(y[idx]) > 0:
            draws.append(sign * float(spearmanr(x[idx], y[idx]).statistic))
    if not draws:
        return rho, nan, nan
    low, high = np.percentile(draws, [2.5, 97.5])
    return rho, float(low), float(high)


def _entries(quick: bool) -> list[tuple[str, str, dict[str, Any]]]:
    severities = (0.25, 1.0) if quick else (0.25, 0.5, 0.75, 1.0)
    # the truth itself (sim-editor at severity 0) is a unit too: the perfect method
    out: list[tuple[str, str, dict[str, Any]]] = [("truth", "sim-editor", {"severity": 0.0}),
                                                  ("identity", "identity", {}), ("filter2d", "filter2d", {}),
                                                  ("physical-editor", "physical-editor", {})]
    if not quick:
        out.append(("lidar-init", "lidar-init", {}))
    out += [(f"sim-editor_{s:g}", "sim-editor", {"severity": s}) for s in severities]
    return out


def _run_entry(label: str, name: str, options: dict[str, Any], scenes: str, root: Path,
               metrics: tuple[str, ...], weathers: tuple[str, ...] = EDITED) -> tuple[float, dict[str, Any]]:
    """Seconds to render and score one entry, and its results document."""
    method = get_method(name, **options)
    cfg = EvaluateConfig(method=name, scenes=scenes, predictions=root / "predictions" / label,
                         out=root / "results" / label, weathers=list(weathers), metrics=list(metrics),
                         render=RenderSettings(seed=0, show_progress=False), show_progress=False)
    start = time.perf_counter()
    doc = evaluate(cfg, method=method).results
    return time.perf_counter() - start, doc


def _frame_ms(root: Path, label: str) -> dict[str, Any] | None:
    """Median whole-frame time (ms) of an entry's renders and their size, from their ``info.json``."""
    medians, size = [], None
    for info_path in sorted((root / "predictions" / label).rglob("info.json")):
        timings = json.loads(info_path.read_text(encoding="utf-8")).get("timings", {})
        if isinstance(timings.get("median_frame_ms"), (int, float)):
            medians.append(float(timings["median_frame_ms"]))
            size = timings.get("resolution")
    return {"median_frame_ms": float(np.median(medians)), "size": size} if medians else None


def _units(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """One record per (scene, weather) of a results document: output -> value (None if skipped)."""
    return [{"scene": scene, "weather": w, **{name: rec.get("value") for name, rec in outs.items()}}
            for scene, ws in doc["results"].items() for w, outs in ws.items()]


def _mean(values: list[Any]) -> float | None:
    nums = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return float(np.mean(nums)) if nums else None


def run(*, data_root: Path | None = None, quick: bool = False) -> BenchReport:
    """Run the suite (``data_root`` is not used: the scenes are built in).

    Parameters
    ----------
    data_root : Path, optional
        Unused (the ``synth_*`` sets generate themselves).
    quick : bool
        ``synth_1``, two severities and no WeatherCity training: a smoke run.
    """
    groups = set(os.environ.get("WCBENCH_BENCH_VALIDITY_GROUPS", ",".join(GROUPS)).split(","))
    if groups - set(GROUPS):
        raise InputError(f"WCBENCH_BENCH_VALIDITY_GROUPS: unknown groups {sorted(groups - set(GROUPS))}; "
                         f"known: {', '.join(GROUPS)}")
    report = BenchReport("validity")
    scenes = "synth_1" if quick else "synth_3"
    metrics = (*TRUTH, *PROXY_METRICS)
    points: list[dict[str, Any]] = []
    directions: dict[str, bool] = {}
    skipped: dict[str, str] = {}
    per_entry: dict[str, list[dict[str, Any]]] = {}
    # first: a new process with every cache empty, before this one has generated or compiled anything
    first_runs = [] if quick or "first_run" not in groups else [_first_run_case(name) for name in FIRST_RUN_LIMIT_S]
    with private_caches(store=False), tempfile.TemporaryDirectory(prefix="wcbench-bench-validity-") as tmp:
        root = Path(tmp)
        for label, name, options in _entries(quick) if "scores" in groups else ():
            seconds, doc = _run_entry(label, name, options, scenes, root, metrics)
            units = _units(doc)
            per_entry[label] = units
            points += [{"entry": label, **u} for u in units]
            for ws in doc["results"].values():
                for outs in ws.values():
                    for out_name, rec in outs.items():
                        directions[out_name] = bool(rec.get("higher_is_better"))
            for s in doc.get("skipped", []):
                skipped.setdefault(s["metric"], s["reason"])
            means = {k: _mean([u.get(k) for u in units]) for k in (*TRUTH, *PROXIES)}
            per_weather = {f"{k}_{w}": _mean([u.get(k) for u in units if u["weather"] == w])
                           for k in ("psnr", "lpips", "temporal_flicker_ratio") for w in EDITED}
            report.cases.append(BenchCase(
                name=label, knob="method", value=label, time_ms=1e3 * seconds, error=means["lpips"],
                error_unit="lpips vs truth", extra={**{k: v for k, v in means.items() if k != "lpips"},
                                                    **per_weather, "units": len(units),
                                                    "frames": _frame_ms(root, label)}))
        if not quick and "scores" in groups:
            report.cases += _supervision_cases(scenes, root, per_entry, metrics)
    report.cases += first_runs
    for proxy in PROXIES:
        if proxy not in directions:
            continue
        found: dict[str, tuple[float, float, float, int]] = {}
        for truth in TRUTH:
            pairs = [(p.get(proxy), p.get(truth)) for p in points]
            pairs = [(a, b) for a, b in pairs if isinstance(a, (int, float)) and isinstance(b, (int, float))
                     and math.isfinite(a) and math.isfinite(b)]
            if len(pairs) < 3:
                continue
            sign = 1.0 if directions[proxy] == directions.get(truth, True) else -1.0
            x, y = (np.array(v) for v in zip(*pairs))
            rho, low, high = agreement(x, y, sign=sign)
            found[truth] = (rho, low, high, len(pairs))
            report.cases.append(BenchCase(
                name=f"agree_{proxy}_{truth}", knob="agreement",
                value=f"{proxy} vs {truth}: rho {rho:+.2f} [{low:+.2f}, {high:+.2f}], n {len(pairs)}", time_ms=None,
                error=None, error_unit="n/a", extra={"rho": rho, "low": low, "high": high, "n": len(pairs)}))
        if found:
            tracks = all(rho >= WEAK and low > 0 for rho, low, _, _ in found.values())
            verdict = "tracks the truth" if tracks else "does NOT track the truth here"
            detail = "; ".join(f"{t} {r:+.2f} [{lo:+.2f}, {hi:+.2f}]" for t, (r, lo, hi, _) in found.items())
            n = max(v[3] for v in found.values())
            report.notes.append(f"{proxy} {verdict} (rho against the truth over {n} units: {detail})")
    for metric, reason in sorted(skipped.items()):
        if metric in PROXY_METRICS or metric in TRUTH:
            report.notes.append(f"{metric} skipped: {reason}")
    if "scores" in groups:
        report.notes.append(f"scenes {scenes}; weathers {', '.join(EDITED)}; agreement = Spearman rho oriented so "
                            f"that +1 ranks units as the truth does, 95 % bootstrap interval over units "
                            f"({BOOTSTRAP} resamples); 'tracks' needs rho >= {WEAK} and an interval above 0")
    return report


def _supervision_cases(scenes: str, root: Path, per_entry: dict[str, list[dict[str, Any]]],
                       metrics: tuple[str, ...]) -> list[BenchCase]:
    """WeatherCity trained on the simulated editor's frames against those frames (see the module docstring)."""
    cases = []
    truth_units = per_entry.get("truth", [])
    for label, supervision, entry in SUPERVISIONS:
        editor = per_entry.get(entry)
        if editor is None:
            continue
        seconds, doc = _run_entry(f"weathercity_{label}", "weathercity",
                                  {"supervision": supervision, "profile": "default", "physics": "truth"},
                                  scenes, root, metrics, weathers=("clear", *EDITED))
        units = _units(doc)
        clear = [u for u in units if u["weather"] == "clear"]
        extra: dict[str, Any] = {"psnr_clear_vs_raw": _mean([u.get("psnr") for u in clear])}
        for subset in ("all", *EDITED):
            def pick(us: list[dict[str, Any]], key: str, subset: str = subset) -> float | None:
                return _mean([u.get(key) for u in us if u["weather"] == subset
                              or (subset == "all" and u["weather"] != "clear")])

            suffix = "" if subset == "all" else f"_{subset}"
            psnr_wc, psnr_ed = pick(units, "psnr"), pick(editor, "psnr")
            fl_wc, fl_ed = pick(units, "temporal_flicker"), pick(editor, "temporal_flicker")
            fl_truth = pick(truth_units, "temporal_flicker")
            extra.update({
                f"psnr_weathercity{suffix}": psnr_wc, f"psnr_editor{suffix}": psnr_ed,
                f"flicker_weathercity{suffix}": fl_wc, f"flicker_editor{suffix}": fl_ed,
                f"flicker_truth{suffix}": fl_truth,
                f"closer_psnr{suffix}": None if psnr_wc is None or psnr_ed is None else psnr_wc > psnr_ed,
                f"closer_flicker{suffix}": None if fl_wc is None or fl_ed is None or fl_truth is None else (
                    abs(fl_wc - fl_truth) < abs(fl_ed - fl_truth)),
            })
        cases.append(BenchCase(
            name=f"supervised_{label}", knob="supervision", value=supervision,
            time_ms=1e3 * seconds, error=_mean([u.get("lpips") for u in units if u["weather"] != "clear"]),
            error_unit="lpips vs truth",
            extra=extra))
    return cases


def _first_run_case(scenes: str) -> BenchCase:
    """The README main job on ``scenes`` in a new process with every cache empty (see the module docstring)."""
    with tempfile.TemporaryDirectory(prefix="wcbench-first-run-") as tmp:
        root = Path(tmp)
        env = {**os.environ, "WCBENCH_CACHE": str(root / "cache"), "WCBENCH_MODELS": str(root / "models"),
               "NUMBA_CACHE_DIR": str(root / "numba"), "WCBENCH_PROGRESS": "0"}
        cmd = [sys.executable, "-m", "wcbench", "run", "--method", "weathercity", "--scenes", scenes,
               "--profile", "quick", "--out", str(root / "run"), "--report", "--no-progress"]
        start = time.perf_counter()
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        seconds = time.perf_counter() - start
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
        doc = json.loads((root / "run" / "results.json").read_text(encoding="utf-8"))
        if not (root / "run" / "report.html").is_file():
            raise RuntimeError(f"{' '.join(cmd)} wrote no report.html")
    units = _units(doc)
    truth = {k: _mean([u.get(k) for u in units if u["weather"] != "clear"]) for k in TRUTH}
    per_weather = {f"psnr_{w}": _mean([u.get("psnr") for u in units if u["weather"] == w])
                   for w in ("clear", *EDITED)}
    limit = FIRST_RUN_LIMIT_S[scenes]
    return BenchCase(
        name=f"first_run_{scenes}", knob="first_run", value=scenes, time_ms=1e3 * seconds, error=None,
        error_unit="-", extra={"limit_s": limit, "within_limit": seconds <= limit, "units": len(units),
                               **{f"{k}_vs_truth": v for k, v in truth.items()}, **per_weather,
                               "command": f"wcbench run --method weathercity --scenes {scenes} --profile quick "
                                          "--out OUT --report"})
