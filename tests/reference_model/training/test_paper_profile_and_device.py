"""The `paper` profile (native resolution, 30,000 steps, progressive resolution, the paper's particles)
and the training's device: CPU by default, a one-line refusal of a device that cannot run."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from wcbench.core.progress import TimeLeft  # noqa: E402
from wcbench.reference_model.devices import check_device, device_problem, rasterizer_for  # noqa: E402
from wcbench.reference_model.raster.rasterizer import rasterize  # noqa: E402
from wcbench.reference_model.training.build import build_model  # noqa: E402
from wcbench.reference_model.training.config import PROFILE_PHYSICS, TrainConfig, make_config  # noqa: E402
from wcbench.reference_model.training.trainer import Trainer  # noqa: E402
from wcbench.reference_model.training.views import TrainingView, build_views, scaled_view  # noqa: E402

pytestmark = pytest.mark.model

SIZE = (96, 54)


@pytest.fixture(scope="module")
def sky_scene(demo_scene, tmp_path_factory):
    """The demo scene shipping sky masks (the top third), as the lent GPU machine's scene ships them:
    its OpenCV 5 has no cv2.ml, which the sky segmentation's forest needs (tools/export_sky_masks.py),
    and tools/workstation_check.sh runs this module there."""
    folder = tmp_path_factory.mktemp("sky")
    frames = []
    for f in demo_scene.frames:
        mask = np.zeros((f.camera.height, f.camera.width), np.uint8)
        mask[: f.camera.height // 3] = 255
        cv2.imwrite(str(folder / f"sky_{f.index}.png"), mask)
        frames.append(dataclasses.replace(f, sky_mask_path=folder / f"sky_{f.index}.png"))
    return dataclasses.replace(demo_scene, frames=frames)


@pytest.fixture(scope="module")
def demo_views(sky_scene):
    views, _ = build_views(sky_scene, size=SIZE, supervision={})
    assert all(v.sky is not None and v.sky.any() for v in views)
    return views


def test_the_paper_profile_resolves_to_the_papers_protocol():
    config = make_config("paper")
    assert config.iterations == 30_000
    assert config.size_for((1920, 1080)) == (1920, 1080)  # width 0: the scene's native size
    assert config.size_for((1920, 1280)) == (1920, 1280)
    # progressive: 1/4 for 3,000 steps, 1/2 for the next 3,000, then full
    assert [config.resolution_divisor(s) for s in (0, 2999, 3000, 5999, 6000, 29_999)] == [4, 4, 2, 2, 1, 1]
    assert PROFILE_PHYSICS["paper"] == {"rain": "paper", "snow": "paper"}
    from wcbench.reference_model.weather.conditions import load_presets

    presets = load_presets()
    assert presets["rain"]["presets"]["paper"]["count"] == 40_000
    assert presets["snow"]["presets"]["paper"]["count"] == 16_000


def test_progressive_settings_off_leave_the_cache_key_as_before():
    d = make_config("default").to_json()
    assert "resolution_levels" not in d and "resolution_interval" not in d
    assert TrainConfig.from_json(d) == make_config("default")
    p = make_config("paper").to_json()
    assert p["resolution_levels"] == 2 and TrainConfig.from_json(p) == make_config("paper")


def test_a_scaled_view_halves_the_size_and_scales_the_intrinsics():
    rng = np.random.default_rng(0)
    K = np.array([[80.0, 0.0, 48.0], [0.0, 80.0, 27.0], [0.0, 0.0, 1.0]])
    sky = np.zeros((54, 96), bool)
    sky[:10] = True
    v = TrainingView(frame=0, time=0.0, camera_to_world=np.eye(4), K=K, width=96, height=54,
                     images={"clear": rng.random((54, 96, 3), dtype=np.float32)},
                     depth=np.full((54, 96), 7.0, np.float32), sky=sky, dynamic=np.zeros((54, 96), bool))
    small = scaled_view(v, 2)
    assert (small.width, small.height) == (48, 27)
    np.testing.assert_allclose(small.K[0], v.K[0] * 0.5)
    np.testing.assert_allclose(small.K[1], v.K[1] * 27 / 54)
    assert small.images["clear"].shape == (27, 48, 3)
    # area averaging: each pixel the mean of the 2 x 2 it covers
    np.testing.assert_allclose(small.images["clear"][0, 0], v.images["clear"][:2, :2].mean((0, 1)), atol=1e-6)
    assert small.depth is not None and small.depth.shape == (27, 48) and (small.depth == 7.0).all()
    assert small.sky is not None and small.sky[:5].all() and not small.sky[5:].any()
    assert small.ignore.shape == (0, 0)  # an empty mask stays empty
    assert scaled_view(v, 1) is v
    with pytest.raises(ValueError, match="divisor"):
        scaled_view(v, 0)


@pytest.mark.slow  # a scene graph and three steps: 11 s on the shared 2-core machine
def test_the_paper_profiles_first_steps_run_on_cpu_at_its_progressive_resolution(sky_scene, demo_views):
    # the paper profile with the scene's size (96x54 here), 3 steps: each renders at 1/4 of it
    config = make_config("paper", iterations=3, voxel_m=0.4, far_points=False)
    model, _ = build_model(sky_scene, demo_views, config, weathers=("clear",))
    trainer = Trainer(model, demo_views, config)
    assert trainer.step_kinds(0, 3) == ["clear@1/4"] * 3
    assert trainer.kind_weights(0, 3) == {"clear@1/4": 1 / 16}
    logs = trainer.train()
    assert [log.step for log in logs] == [0, 1, 2]
    assert all(np.isfinite(log.loss) for log in logs)
    # the renders were at 1/4: the densification statistics' views are (24, 13)
    assert {k[1] for k in trainer._scaled} == {4}
    assert next(iter(trainer._scaled.values()))[0].width == 24


def test_the_default_rasterizer_of_the_cpu_is_the_numba_one():
    assert device_problem("cpu") is None
    assert rasterizer_for("cpu") is rasterize


def test_the_time_left_prices_a_later_larger_level_by_its_weight():
    kinds = ["a@1/4"] * 10 + ["a"] * 10
    left = TimeLeft(kinds, total=20, min_steady=3, weights={"a@1/4": 1 / 16, "a": 1.0})
    for _ in range(5):
        left.record(1.0)  # one second a quarter-resolution step
    # 5 more at 1 s, 10 at 16 s
    assert left.estimate() == pytest.approx(5 * 1.0 + 10 * 16.0)
    plain = TimeLeft(kinds, total=20, min_steady=3)
    for _ in range(5):
        plain.record(1.0)
    assert plain.estimate() == pytest.approx(15.0)  # without weights: unchanged, every kind at the mean


@pytest.mark.slow  # two scene graphs and two steps each: 8 s on the shared 2-core machine
def test_cpu_is_the_default_device_and_keeps_the_numba_rasterizer(sky_scene, demo_views):
    assert device_problem("cpu") is None
    assert rasterizer_for("cpu") is rasterize
    config = make_config("quick", width=SIZE[0], iterations=2, voxel_m=0.4, far_points=False)
    a = Trainer(build_model(sky_scene, demo_views, config, weathers=("clear",))[0], demo_views, config)
    b = Trainer(build_model(sky_scene, demo_views, config, weathers=("clear",))[0], demo_views, config,
                device="cpu")
    assert a.rasterizer is rasterize and b.rasterizer is rasterize
    assert [s.loss for s in a.train()] == [s.loss for s in b.train()]  # bit for bit


def test_an_unknown_or_unavailable_device_is_refused_in_one_line(monkeypatch):
    with pytest.raises(ValueError, match=r"unknown device 'tpu'"):
        check_device("tpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    problem = device_problem("cuda")
    assert problem is not None and "\n" not in problem
    assert "gsplat" in problem or "CUDA" in problem


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)])
def test_a_training_on_a_device_follows_the_cpu_resumes_and_comes_back_evaluable(sky_scene, device, tmp_path):
    # The whole step on the device (on a GPU: gsplat, the torch twins of SSIM and the sky) against the
    # CPU's numba step from the same model: the first losses agree to the rasterizers' float differences
    # (gsplat's images are within 1e-3 of ours, tests/reference_model/raster/test_gsplat_agreement.py),
    # later ones drift apart as the parameters do. Every tensor the step, the densification, a checkpoint
    # and its resumption meet must be on the model's device. tools/workstation_check.sh runs the cuda
    # case on a lent GPU machine; it is skipped without one.
    from wcbench.core.image_io import read_rgb8
    from wcbench.reference_model.training.checkpoint import load_checkpoint, save_checkpoint
    from wcbench.reference_model.training.trainer import evaluate_views

    problem = device_problem(device)
    if problem is not None:
        pytest.skip(problem)
    config = make_config("quick", width=SIZE[0], iterations=6, voxel_m=0.4, far_points=False, densify_from=2,
                         densify_interval=2, densify_until=4)

    # a second weather's decoder and targets: the frames darkened stand in for rain
    scene = sky_scene
    rain = [(0.6 * read_rgb8(f.image_path)).astype(np.uint8) for f in scene.frames]
    views, _ = build_views(scene, size=SIZE, supervision={"rain": rain})

    def trainer(model, on):
        return Trainer(model, views, config, device=on)

    def model():
        return build_model(scene, views, config, weathers=("clear", "rain"))[0]

    cpu, gpu = trainer(model(), "cpu"), trainer(model(), device)
    assert next(gpu.model.parameters()).device.type == device
    a, b = cpu.train(), gpu.train(until=3)
    save_checkpoint(gpu, tmp_path / "ckpt")
    gpu = load_checkpoint(tmp_path / "ckpt", model=model(), views=views, make_trainer=lambda m: trainer(m, device))
    assert gpu.step_index == 3 and next(gpu.model.parameters()).device.type == device
    b += gpu.train()
    assert len(b) == 6 and all(np.isfinite(log.loss) for log in b)
    assert [r["step"] for r in gpu.densify_log] == [2, 4]  # one densification before the checkpoint, one after
    np.testing.assert_allclose(b[0].loss, a[0].loss, rtol=1e-2)
    held = evaluate_views(gpu.model, views[:2])  # on the device: gsplat chosen by a GPU model's device
    assert np.isfinite(held["mean_psnr"])
    gpu.model.to("cpu")
    back = evaluate_views(gpu.model, views[:2])  # back on the CPU: numba, the same images to 1e-3
    assert abs(back["mean_psnr"] - held["mean_psnr"]) < 0.05
