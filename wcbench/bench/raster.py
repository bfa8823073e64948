"""``wcbench bench raster``: speed and accuracy of the CPU rasterizer, fast path against its twin.

Cases (docs/design.md §8 yardsticks):

a. 20k random Gaussians at 320x180;
b. the real workload: the lidar of ``pandaset_002`` (every sweep, voxelised at 0.15 m, voxel
   centroids), isotropic sigma = 0.075 m, opacity 0.8, colors sampled from frame 0's image,
   rendered from frame 0's camera at 480x270 (K scaled from 1920x1080); a generated scene with
   the same count and depth statistics when the data is absent;
b_..._15ch. case b with 15 channels, the training's weather step (four weathers' RGB and three
   hazes' transmittance), fast path only; ``fwd_vs_rgb`` and ``bwd_vs_rgb`` divide its times by
   case b's of the same run;
c. 40k rain streaks (scale [0.0025, 0.0025, 0.075] m, opacity 0.13) within 10 m, at 480x270;
d. 1M Gaussians at 1920x1080, forward only, fast path only, with peak memory;
profile_<case>_<size>: the per-phase profile of one rasterizer call (forward + backward of case b,
   at 480x270 and at 1920x1080) at each thread count of ``threads`` (numba, torch and BLAS set
   together, :func:`~wcbench.reference_model.raster.threads.set_threads`): the median time of
   each phase (projection, depth sort, tile binning, forward blend, backward blend, the
   per-Gaussian reduction of the backward, backward projection, and the torch glue: the rest of
   the call), its speed-up from the first to the second thread count, the serial fraction that
   speed-up implies (Amdahl) and, from that fraction, a *projected* speed-up at 16 threads. The
   rounds interleave the thread counts, so load drifts hit them alike; the notes print the table;
start_cold, start_warm: a new process that imports wcbench and runs every numba kernel once
   (:func:`~wcbench.reference_model.kernel_warmup.compile_kernels`, what ``wcbench compile`` does)
   with an empty numba cache, then again with the cache the first run wrote: what a fresh
   install's first render waits for, and what every later process pays.

Set ``WCBENCH_BENCH_RASTER_GROUPS`` to run some of the groups ``speed,profile,start`` (default all):
``speed`` the cases a to d, ``profile`` the per-phase profiles (case b's Gaussians, built without
timing its fast path against the twin), ``start`` the cold and warm starts; the workstation check
(docs/workstation.md) runs the profiles alone.

Per case: forward and backward wall time of the fast path (median over repeats after a warm-up)
and of the pure-torch twin (one run), the Gaussian-pixel pairs evaluated, ns per pair, the
speed-up over the twin, the fraction of the compiled-kernel floor of docs/design.md §8 reached, and the
largest error of the fast path against a float64 reference: the twin run in float64 on the very
pairs the float32 fast path composited (same skip and stop decisions).
"""

from __future__ import annotations

import math
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from wcbench.bench.phases import parse_threads, phase_table, run_interleaved
from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.core.errors import InputError
from wcbench.reference_model.raster.kernels import RenderJob
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.reference_model.raster.torch_twin import rasterize_torch
from wcbench.scenes.loaders import load_scene

#: docs/design.md §8: ~6M pairs cost a compiled tile kernel >= 4 ms forward and >= 10 ms backward on this
#: machine (~35 FLOP per pair forward, ~2.5x that backward): the floor per pair.
FLOOR_NS_PER_PAIR_FWD = 4e6 / 6e6
FLOOR_NS_PER_PAIR_BWD = 10e6 / 6e6
#: Pandaset frames are 1920x1080; the real case renders at a quarter of that.
REAL_SIZE = (480, 270)
#: Channels of the default training's weather step (four weathers' RGB and three hazes).
WEATHER_STEP_CHANNELS = 15
VOXEL_M = 0.15
#: The case groups of ``WCBENCH_BENCH_RASTER_GROUPS`` (default all).
GROUPS = ("speed", "profile", "start")


def _params(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, opac: np.ndarray,
            colors: np.ndarray) -> list[torch.Tensor]:
    return [torch.tensor(np.ascontiguousarray(a), dtype=torch.float32).requires_grad_(True)
            for a in (means, quats, scales, opac, colors)]


def _identity_quats(n: int) -> np.ndarray:
    q = np.zeros((n, 4), np.float32)
    q[:, 0] = 1.0
    return q


def _pinhole(width: int, height: int, fx: float) -> np.ndarray:
    return np.array([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])


def _voxel_centroids(points: np.ndarray, voxel: float) -> np.ndarray:
    """[M, 3] centroid of the points in each occupied voxel."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    counts = np.bincount(inv).astype(np.float64)
    out = np.stack([np.bincount(inv, weights=points[:, k]) for k in range(3)], -1) / counts[:, None]
    return out.astype(np.float32)


def _real_scene(data_root: pathlib.Path | None, n_cap: int | None) -> tuple[dict[str, Any] | None, str]:
    """Case (b) from pandaset_002, or (None, reason) when the data is absent."""
    if data_root is None:
        return None, "no data root given"
    root = pathlib.Path(data_root) / "pandaset_002"
    if not (root / "images").is_dir():
        return None, f"{root} not found"
    from PIL import Image


    scene = load_scene(root)
    frame = scene.frames[0]
    cam = frame.camera
    centroids = _voxel_centroids(scene.all_lidar_points(), VOXEL_M)
    if n_cap is not None and len(centroids) > n_cap:
        centroids = centroids[np.random.default_rng(0).choice(len(centroids), n_cap, replace=False)]
    image = np.asarray(Image.open(frame.image_path).convert("RGB"), np.float32) / 255.0  # sRGB in [0, 1]
    uv, _ = cam.project(centroids)
    ij = np.clip(np.floor(np.nan_to_num(uv)).astype(np.int64), 0, [cam.width - 1, cam.height - 1])
    colors = image[ij[:, 1], ij[:, 0]]
    n = len(centroids)
    K = np.array(cam.K, np.float64)
    scale = REAL_SIZE[0] / cam.width
    K[:2] *= scale  # pixel-edge convention: u' = s u maps the image onto itself exactly
    return {"params": _params(centroids, _identity_quats(n), np.full((n, 3), VOXEL_M / 2), np.full(n, 0.8),
                              colors),
            "viewmat": cam.world_to_camera, "K": K, "size": REAL_SIZE}, ""


def _synthetic_street(n: int, width: int, height: int, seed: int) -> dict[str, Any]:
    """Stand-in for case (b): same count, sigma, opacity; depths log-normal like pandaset's lidar.

    The real voxels have camera depth percentiles 5/50/95 % of about 10/24/86 m; uniform image
    positions then back-projection give the same footprint distribution on screen.
    """
    rng = np.random.default_rng(seed)
    fx = 1970.0 * width / 1920.0
    K = _pinhole(width, height, fx)
    z = np.exp(rng.normal(math.log(24.0), 0.65, n)).clip(2.0, 250.0)
    u = rng.uniform(0, width, n)
    v = rng.uniform(0, height, n)
    means = np.stack([(u - K[0, 2]) / fx * z, (v - K[1, 2]) / fx * z, z], -1)
    return {"params": _params(means, _identity_quats(n), np.full((n, 3), VOXEL_M / 2), np.full(n, 0.8),
                              rng.uniform(0, 1, (n, 3))),
            "viewmat": np.eye(4), "K": K, "size": (width, height)}


def _random_cloud(n: int, width: int, height: int, seed: int) -> dict[str, Any]:
    """Case (a): anisotropic random Gaussians filling the view between 2 and 12 m."""
    rng = np.random.default_rng(seed)
    K = _pinhole(width, height, 0.8 * width)
    z = rng.uniform(2.0, 12.0, n)
    means = np.stack([rng.uniform(-0.7, 0.7, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], -1)
    return {"params": _params(means, rng.normal(size=(n, 4)), rng.uniform(0.005, 0.08, (n, 3)),
                              rng.uniform(0.05, 0.95, n), rng.uniform(0, 1, (n, 3))),
            "viewmat": np.eye(4), "K": K, "size": (width, height)}


def _rain(n: int, width: int, height: int, seed: int) -> dict[str, Any]:
    """Case (c): thin streaks falling along camera +y (down), 15 degrees of wind tilt, within 10 m."""
    rng = np.random.default_rng(seed)
    K = _pinhole(width, height, 1970.0 * width / 1920.0)
    z = rng.uniform(0.5, 10.0, n)
    means = np.stack([rng.uniform(-0.55, 0.55, n) * z, rng.uniform(-0.3, 0.3, n) * z, z], -1)
    # Rotate the local z axis (the 0.075 m one) onto the fall direction: about x by -(90 - 15) deg.
    half = -math.radians(75.0) / 2
    quats = np.tile([math.cos(half), math.sin(half), 0.0, 0.0], (n, 1))
    return {"params": _params(means, quats, np.tile([0.0025, 0.0025, 0.075], (n, 1)), np.full(n, 0.13),
                              np.tile([0.7, 0.7, 0.8], (n, 1))),
            "viewmat": np.eye(4), "K": K, "size": (width, height)}


def _timed(fn: Callable[[], Any], repeats: int) -> tuple[list[float], Any]:
    """Wall times (ms) of ``repeats`` calls after one warm-up, and the last result."""
    result = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return times, result


def _loss_weights(width: int, height: int, channels: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(0)
    return (torch.rand(height, width, channels, generator=g), torch.rand(height, width, generator=g),
            torch.rand(height, width, generator=g) * 0.01)


def _forward_backward(render: Callable[[], Any], weights: tuple[torch.Tensor, ...], repeats: int
                      ) -> tuple[list[float], list[float], Any]:
    """Forward and backward wall times (ms); the backward of a fixed random linear loss."""
    fwd, bwd = [], []
    out = None
    for i in range(repeats + 1):  # the first round warms up (numba compile / cache load)
        t0 = time.perf_counter()
        out = render()
        t1 = time.perf_counter()
        loss = (out.color * weights[0]).sum() + (out.alpha * weights[1]).sum() + (out.depth * weights[2]).sum()
        loss.backward()
        t2 = time.perf_counter()
        if i:
            fwd.append((t1 - t0) * 1e3)
            bwd.append((t2 - t1) * 1e3)
    return fwd, bwd, out


def _reference_error(spec: dict[str, Any], out: Any) -> dict[str, float]:
    """Max errors of a fast-path render against the float64 twin on the same composited pairs."""
    width, height = spec["size"]
    m, q, s, o, c = (p.detach() for p in spec["params"])
    vm = torch.as_tensor(spec["viewmat"], dtype=torch.float32)
    K = torch.as_tensor(spec["K"], dtype=torch.float32)
    job = RenderJob(m, q, s, o, c, vm, K, width, height, near=0.01, far=1e10, render_depth=True)
    job.forward()
    gid, pix = job.composited_pairs()
    ref = rasterize_torch(m.double(), q.double(), s.double(), o.double(), c.double(), vm.double(), K.double(),
                          width, height, pairs=(torch.from_numpy(gid), torch.from_numpy(pix)))
    color_err = float((out.color.detach().double() - ref.color).abs().max())
    alpha_err = float((out.alpha.detach().double() - ref.alpha).abs().max())
    assert ref.depth is not None
    drawn = ref.alpha > 0
    depth_rel = (out.depth.detach().double() - ref.depth).abs()[drawn] / ref.depth[drawn].abs().clamp_min(1e-12)
    return {"color_max_abs_err": color_err, "alpha_max_abs_err": alpha_err,
            "depth_max_rel_err": float(depth_rel.max()) if depth_rel.numel() else 0.0}


def _case(name: str, spec: dict[str, Any], *, repeats: int, with_twin: bool,
          extra_notes: dict[str, Any] | None = None) -> BenchCase:
    width, height = spec["size"]
    params = spec["params"]
    weights = _loss_weights(width, height, params[4].shape[1])

    m, q, s, o, c = params

    def render(backend: str) -> Callable[[], Any]:
        return lambda: rasterize(m, q, s, o, c, spec["viewmat"], spec["K"], width, height, backend=backend)

    for p in params:
        p.grad = None
    cpu0 = time.process_time()
    fwd, bwd, out = _forward_backward(render("numba"), weights, repeats)
    cpu_per_round = (time.process_time() - cpu0) * 1e3 / (repeats + 1)
    pairs = int(out.meta["n_pairs"])
    errors = _reference_error(spec, out)
    fwd_ms, bwd_ms = statistics.median(fwd), statistics.median(bwd)
    ref_fwd = ref_bwd = None
    if with_twin:
        rf, rb, _ = _forward_backward(render("torch"), weights, 1)
        ref_fwd, ref_bwd = rf[0], rb[0]
    extra: dict[str, Any] = {
        "gaussians": len(params[0]), "width": width, "height": height, "pairs": pairs,
        "visible": int(out.meta["n_visible"]), "tile_entries": int(out.meta["n_tile_entries"]),
        "fwd_ms": round(fwd_ms, 3), "bwd_ms": round(bwd_ms, 3),
        "fwd_ms_min": round(min(fwd), 3), "bwd_ms_min": round(min(bwd), 3),
        "cpu_ms_per_fwd_bwd": round(cpu_per_round, 3),
        "ref_fwd_ms": None if ref_fwd is None else round(ref_fwd, 3),
        "ref_bwd_ms": None if ref_bwd is None else round(ref_bwd, 3),
        "speedup_fwd": None if ref_fwd is None else round(ref_fwd / fwd_ms, 2),
        "speedup_bwd": None if ref_bwd is None else round(ref_bwd / bwd_ms, 2),
        "ns_per_pair_fwd": round(fwd_ms * 1e6 / max(pairs, 1), 3),
        "ns_per_pair_bwd": round(bwd_ms * 1e6 / max(pairs, 1), 3),
        "floor_fraction_fwd": round(pairs * FLOOR_NS_PER_PAIR_FWD * 1e-6 / fwd_ms, 4),
        "floor_fraction_bwd": round(pairs * FLOOR_NS_PER_PAIR_BWD * 1e-6 / bwd_ms, 4),
        **errors,
        "max_abs_err": max(errors["color_max_abs_err"], errors["alpha_max_abs_err"]),
        "peak_mb": None,
    }
    extra.update(extra_notes or {})
    return BenchCase(name=name, knob="gaussians", value=len(params[0]), time_ms=round(fwd_ms, 3),
                     error=extra["max_abs_err"], error_unit="abs", extra=extra)


def _case_memory(name: str, spec: dict[str, Any], *, repeats: int) -> BenchCase:
    """Forward only, fast path only; peak memory as the growth of the process's max RSS."""
    width, height = spec["size"]
    m, q, s, o, c = (p.detach() for p in spec["params"])
    vm, K = spec["viewmat"], spec["K"]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    tracemalloc.start()
    times, out = _timed(lambda: rasterize(m, q, s, o, c, vm, K, width, height, backend="numba"), repeats)
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    fwd_ms = statistics.median(times)
    pairs = int(out.meta["n_pairs"])
    extra = {
        "gaussians": len(m), "width": width, "height": height, "pairs": pairs,
        "visible": int(out.meta["n_visible"]), "tile_entries": int(out.meta["n_tile_entries"]),
        "fwd_ms": round(fwd_ms, 3), "fwd_ms_min": round(min(times), 3), "bwd_ms": None,
        "ref_fwd_ms": None, "ref_bwd_ms": None,
        "ns_per_pair_fwd": round(fwd_ms * 1e6 / max(pairs, 1), 3),
        "floor_fraction_fwd": round(pairs * FLOOR_NS_PER_PAIR_FWD * 1e-6 / fwd_ms, 4),
        "max_abs_err": None,
        "peak_mb": round(rss1 - rss0, 1), "peak_rss_mb": round(rss1, 1),
        "peak_mb_tracemalloc": round(traced_peak / 2**20, 1),
    }
    return BenchCase(name=name, knob="gaussians", value=len(m), time_ms=round(fwd_ms, 3), error=None,
                     error_unit="abs", extra=extra)


#: Phases of :attr:`RenderJob.phase_ms`, in pipeline order; ``glue`` is the rest of the call.
RASTER_PHASES = ("project", "sort", "bin", "fwd_blend", "bwd_blend", "bwd_reduce", "bwd_project", "glue")


def _profile_case(name: str, spec: dict[str, Any], counts: list[int], rounds: int) -> tuple[BenchCase, list[str]]:
    """Per-phase profile of forward + backward of ``spec`` at each thread count (see the module docstring)."""
    width, height = spec["size"]
    m, q, s, o, c = spec["params"]
    weights = _loss_weights(width, height, c.shape[1])

    def once() -> dict[str, float]:
        for p in spec["params"]:
            p.grad = None
        t0 = time.perf_counter()
        out = rasterize(m, q, s, o, c, spec["viewmat"], spec["K"], width, height, backend="numba")
        assert out.depth is not None  # render_depth is on
        loss = (out.color * weights[0]).sum() + (out.alpha * weights[1]).sum() + (out.depth * weights[2]).sum()
        loss.backward()
        total = 1e3 * (time.perf_counter() - t0)
        phases = dict(out.meta["phase_ms"])
        return {**phases, "glue": total - sum(phases.values()), "total": total}

    samples, effective = run_interleaved(once, counts, rounds)
    fields, lines = phase_table(f"{name}: {len(m)} Gaussians at {width}x{height}, forward + backward",
                                samples, effective, RASTER_PHASES, "total")
    whole = fields["phases"]["total"]
    case = BenchCase(name=name, knob="threads", value=",".join(map(str, counts)), time_ms=whole["ms"][str(counts[0])],
                     error=None, error_unit="-",
                     extra={"gaussians": len(m), "width": width, "height": height, "speedup": whole["speedup"],
                            "serial": whole["serial"], "projected_16t": whole["projected_16t"], **fields})
    return case, lines


def _profile_cases(spec: dict[str, Any], label: str, counts: list[int], *, quick: bool) -> tuple[list[BenchCase],
                                                                                                  list[str]]:
    """The profile of case b at its size and, outside ``quick``, at 1920x1080 (K scaled by 4)."""
    sizes = [spec["size"]] if quick else [REAL_SIZE, (1920, 1080)]
    cases, lines = [], []
    for width, height in sizes:
        k = np.array(spec["K"], np.float64) * np.array([[width / spec["size"][0]], [height / spec["size"][1]], [1.0]])
        sized = {**spec, "size": (width, height), "K": k}
        case, text = _profile_case(f"profile_{label}_{width}x{height}", sized, counts, 1 if quick else 9)
        cases.append(case)
        lines += text
    return cases, lines


def _start_cases() -> list[BenchCase]:
    """A cold and a warm process start of the kernels (the numba cache in a fresh temporary folder)."""
    code = "from wcbench.reference_model.kernel_warmup import compile_kernels; compile_kernels()"
    times = []
    with tempfile.TemporaryDirectory(prefix="wcbench-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for _ in range(2):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True)
            times.append(1e3 * (time.perf_counter() - t))
    cold, warm = times
    return [BenchCase("start_cold", "numba_cache", "empty", cold, None, "none", {"default": False}),
            BenchCase("start_warm", "numba_cache", "filled", warm, None, "none",
                      {"default": True, "cold_over_warm": round(cold / warm, 2)})]


def run(*, data_root: pathlib.Path | None, quick: bool = False, threads: str | list[int] | None = None) -> BenchReport:
    """Run the rasterizer benchmark.

    Parameters
    ----------
    data_root : Path or None
        Folder holding ``pandaset_002``; when ``None`` or absent, case (b) uses a generated scene
        with the same count and depth statistics (said in the notes).
    quick : bool
        Shrink every case (a smoke test of the schema, not a measurement).
    threads : str or list of int, optional
        Thread counts of the per-phase profile, e.g. ``"1,2,4,8,16"`` (default ``1,2``): the first
        is the baseline, the speed-up and serial fraction compare it with the second, and every
        count gets its own time column. Counts above the machine's run at its count (said in the
        table).

    Returns
    -------
    BenchReport
        Suite ``"raster"``; one case per workload with the fields listed in the module docstring.
    """
    groups = set(os.environ.get("WCBENCH_BENCH_RASTER_GROUPS", ",".join(GROUPS)).split(","))
    if groups - set(GROUPS):
        raise InputError(f"WCBENCH_BENCH_RASTER_GROUPS: unknown groups {sorted(groups - set(GROUPS))}; "
                         f"known: {', '.join(GROUPS)}")
    counts = parse_threads(threads)
    report = BenchReport(suite="raster")
    repeats = 1 if quick else 5
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    report.notes.append(
        f"times are wall-clock medians of {repeats} runs after a warm-up (fwd_ms_min: the fastest run); "
        f"torch threads {torch.get_num_threads()}; 1-minute load average at start {load:.2f} "
        "(other processes on the machine slow every number down)")
    report.notes.append(
        "max_abs_err: largest |fast - reference| over color and alpha, the reference being the torch twin in "
        "float64 on the pairs the float32 fast path composited; depth_max_rel_err over drawn pixels")
    report.notes.append(
        "floor_fraction: docs/design.md §8 floor (4 ms fwd / 10 ms bwd per 6M pairs) divided by the measured time")

    if "speed" in groups:
        # (d) first, so that the growth of the process's max RSS is the case's own peak.
        n_d, size_d = (30_000, (320, 180)) if quick else (1_000_000, (1920, 1080))
        report.cases.append(_case_memory(f"d_random_{n_d // 1000}k_{size_d[0]}x{size_d[1]}",
                                         _random_cloud(n_d, *size_d, seed=3), repeats=repeats))
        report.notes.append("case d: peak_mb = growth of the process's max RSS (resource.ru_maxrss) over the "
                            "forward calls; peak_mb_tracemalloc = numpy allocations traced by tracemalloc")
        n_a, size_a = (2_000, (160, 90)) if quick else (20_000, (320, 180))
        report.cases.append(_case(f"a_random_{n_a // 1000}k", _random_cloud(n_a, *size_a, seed=0),
                                  repeats=repeats, with_twin=True))

    spec, why = _real_scene(data_root, 20_000 if quick else None)
    if spec is None:
        n_b = 20_000 if quick else 186_431
        spec = _synthetic_street(n_b, *REAL_SIZE, seed=1)
        name = f"b_synthetic_street_{n_b // 1000}k"
        report.notes.append(f"case b: pandaset_002 unavailable ({why}); a generated street-like scene with the same "
                            "Gaussian count, sigma, opacity and log-normal depth distribution stands in")
        report.stand_ins.append(f"case b: pandaset_002 unavailable ({why}); a generated street stood in")
    else:
        n_b = len(spec["params"][0])
        name = f"b_pandaset_{n_b // 1000}k"
        report.notes.append(f"case b: pandaset_002, all lidar sweeps voxelised at {VOXEL_M} m -> {n_b} Gaussians"
                            + (" (subsampled for --quick)" if quick else ""))
    if quick:
        spec["size"] = (240, 135)
        spec["K"] = np.array(spec["K"]) * np.array([[0.5], [0.5], [1.0]])
    if "speed" in groups:
        report.cases.append(_case(name, spec, repeats=repeats, with_twin=True))
        rgb = report.cases[-1]
        # The training's weather step: four weathers' RGB and three hazes' transmittance in one pass.
        m, q, s, o, c = spec["params"]
        extra = torch.rand((len(c), WEATHER_STEP_CHANNELS - 3), generator=torch.Generator().manual_seed(4))
        wide = {**spec, "params": [p.detach().clone().requires_grad_(True) for p in (m, q, s, o)]
                + [torch.cat([c.detach(), extra], 1).requires_grad_(True)]}
        case = _case(f"{name}_{WEATHER_STEP_CHANNELS}ch", wide, repeats=repeats, with_twin=False)
        case.extra.update(fwd_vs_rgb=round(case.extra["fwd_ms"] / rgb.extra["fwd_ms"], 3),
                          bwd_vs_rgb=round(case.extra["bwd_ms"] / rgb.extra["bwd_ms"], 3))
        report.cases.append(case)
        report.notes.append(f"case {case.name}: case b's Gaussians with {WEATHER_STEP_CHANNELS} channels (a training "
                            "weather step: four weathers' RGB and three hazes); fwd_vs_rgb / bwd_vs_rgb: its times "
                            "over case b's, measured in this run")
    if "profile" in groups:
        profiles, table = _profile_cases(spec, name.split("_")[0], counts, quick=quick)
        report.cases += profiles
        report.notes += table

    if "speed" in groups:
        n_c, size_c = (4_000, (240, 135)) if quick else (40_000, REAL_SIZE)
        report.cases.append(_case(f"c_rain_{n_c // 1000}k", _rain(n_c, *size_c, seed=2), repeats=repeats,
                                  with_twin=True))
    if "start" not in groups:
        return report
    if quick:
        report.notes.append("start_cold / start_warm: not run by --quick (a cold start compiles for over a minute)")
        return report
    report.cases += _start_cases()
    report.notes.append("start_cold / start_warm: wall time of a new Python process importing wcbench and running "
                        "every numba kernel once, with an empty numba cache and then with the one it wrote")
    return report
