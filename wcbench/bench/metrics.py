"""``wcbench bench metrics``: speed vs error of the metric implementations, measured in one run.

Cases
-----
ssim_<WxH>      our SSIM (OpenCV separable float64 filter) vs scikit-image's, same definition:
                time of both, abs difference.
flow_<method>   optical flow for the flow warping error (DIS, Farneback, DeepFlow) on the demo
                scene's frames: ms per frame pair and the relative deviation of the resulting
                warping error (of the filter2d rain baseline) from the DeepFlow value.
resolution_<px>, identity_run, two_weathers
                the metric working resolution against the native size, and the scoring path
                before and after its speed-ups, in one run (:mod:`wcbench.bench.scoring`; uses
                the models installed in the user's store, read only).
clip_<backend>, segformer_b0_<backend>, evaluate_scene, evaluate_scene_warm
                CLIP and SegFormer backends (torch, ONNX, ONNX int8) and scoring one method on a
                whole scene; see :mod:`wcbench.bench.metric_models`. Need the ``[model]`` extra.

The suite runs with ``WCBENCH_CACHE`` and (but for the scoring cases, which read the installed
models) ``WCBENCH_MODELS`` pointed into a temporary folder, so it leaves nothing in the user's
cache or model store.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.bench.metric_models import private_caches, run_model_cases
from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.bench.scoring import scoring_cases
from wcbench.core.models.store import ModelStore
from wcbench.methods.filter2d import Filter2DMethod
from wcbench.metrics.clip.tokenizer import VOCAB_ENTRY
from wcbench.metrics.pixel.ssim import ssim_map_mean
from wcbench.metrics.temporal.flicker import FLOW_METHODS, FlowWarpingError
from wcbench.scenes.demo import N_FRAMES, render_frame
from wcbench.scenes.sets import resolve_scenes


def _best_ms(fn: Callable[..., Any], repeats: int, *args: Any) -> tuple[float, Any]:
    best, out = float("inf"), None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn(*args)
        best = min(best, (time.perf_counter() - t) * 1e3)
    return best, out


def _ssim_cases(quick: bool) -> list[BenchCase]:
    from skimage.metrics import structural_similarity


    cases = []
    sizes = [(320, 180)] if quick else [(480, 270), (1920, 1080)]
    rng = np.random.default_rng(0)
    for w, h in sizes:
        a = rng.random((h, w, 3))
        b = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1)
        ours_ms, ours = _best_ms(ssim_map_mean, 3, a, b)
        ref_ms, ref = _best_ms(partial(structural_similarity, gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False, data_range=1, channel_axis=-1), 3, a, b)
        cases.append(BenchCase(
            name=f"ssim_{w}x{h}", knob="pixels", value=w * h, time_ms=ours_ms, error=abs(ours - ref),
            error_unit="abs", extra={"reference": "skimage.metrics.structural_similarity", "ref_ms": ref_ms,
                                     "speedup": ref_ms / ours_ms},
        ))
    return cases


def _flow_cases(quick: bool) -> list[BenchCase]:
    scene = resolve_scenes("demo")[0].load()
    n = 3 if quick else N_FRAMES
    src = np.stack([render_frame(t)[0] for t in range(n)]).astype(np.float32) / 255.0
    rain = Filter2DMethod()
    edit = np.stack([rain.render_frame(scene, "rain", t, seed=0) for t in range(n)]).astype(np.float32) / 255.0
    values: dict[str, tuple[float, float]] = {}
    for name in ("deepflow", "dis", "farneback"):
        flow = FLOW_METHODS[name]
        ms, _ = _best_ms(flow, 2, src[0], src[1])
        m = FlowWarpingError(flow=name)
        m.update(edit, source=src)
        values[name] = (ms, m.compute()["flow_warping_error"].value or float("nan"))
    ref = values["deepflow"][1]
    return [
        BenchCase(name=f"flow_{k}", knob="flow", value=k, time_ms=ms, error=abs(v - ref) / ref,
                  error_unit="rel", extra={"warp_error": v, "reference": "deepflow", "default": k == "dis"})
        for k, (ms, v) in values.items()
    ]


def _user_vocab() -> Path | None:
    """CLIP's vocabulary from the user's model store if installed there (read, never written)."""
    store = ModelStore()
    return store.path(VOCAB_ENTRY) if store.available(VOCAB_ENTRY) else None


def run(*, data_root: Path | None = None, quick: bool = False) -> BenchReport:
    """Run the suite; ``quick`` shrinks it to a smoke test.

    Parameters
    ----------
    data_root : Path, optional
        Folder holding ``pandaset_002`` for the model cases (else they use the demo scene).
    quick : bool
        Small sizes, tiny models and the demo scene: a smoke test, not a measurement.
    """
    report = BenchReport("metrics")
    vocab = _user_vocab()  # looked up before the cache and store are redirected
    with private_caches(store=False):  # the scoring cases read the user's installed models (LPIPS...)
        cases, notes, stand_ins = scoring_cases(data_root=data_root, quick=quick)
    report.cases += cases
    report.notes += notes
    report.stand_ins += stand_ins
    with private_caches() as work:
        report.cases += _ssim_cases(quick)
        try:
            import onnx  # noqa: F401  (the int8 quantiser needs it)
            import onnxruntime  # noqa: F401
            import torch  # noqa: F401
        except ImportError as exc:
            report.notes.append(f"model cases skipped: they need the [model] extra (torch, onnx): {exc}")
        else:
            # Before the flow cases: their flows of the demo scene would warm evaluate_scene's cache.
            cases, notes = run_model_cases(data_root=data_root, quick=quick, work=work / "models_bench",
                                           user_vocab=vocab)
            report.cases += cases
            report.notes += notes
        report.cases += _flow_cases(quick)
    report.notes.append("flow cases use the built-in demo scene (320x180); ms per frame pair")
    return report
