"""Weather Gaussians: decoders against their per-weather twin, one pass for every weather, edits."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import weather_models as wm  # noqa: E402

from wcbench.reference_model.editing.edits import parse_edits, placement_for  # noqa: E402
from wcbench.reference_model.model.decoders import WeatherDecoders, color_logits, mlp_colors  # noqa: E402
from wcbench.reference_model.model.scene_model import Placement  # noqa: E402
from wcbench.reference_model.raster.torch_twin import rasterize_torch  # noqa: E402

pytestmark = pytest.mark.model


def _decoder_twin(dec: WeatherDecoders, features: torch.Tensor, weathers: list[str]) -> torch.Tensor:
    """The paper's MLP written plainly, one weather at a time: [N, 3 len(weathers)]."""
    outs = []
    for i in dec.index(weathers):
        h = torch.relu(features @ dec.w1[i].T + dec.b1[i])
        outs.append(torch.sigmoid(h @ dec.w2[i].T + dec.b2[i]))
    return torch.cat(outs, 1)


@pytest.mark.parametrize("weathers", [["clear"], ["clear", "rain", "snow", "fog"], ["fog", "clear"]])
def test_batched_decoders_match_the_per_weather_twin(weathers):
    dec = WeatherDecoders(("clear", "rain", "snow", "fog"), feature_dim=32, hidden=64, seed=4)
    with torch.no_grad():
        for p in dec.parameters():  # leave the identity initialisation: every weight matters here
            p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())) * 0.3)
    f = torch.randn(500, 32, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(dec(f, weathers), _decoder_twin(dec, f, weathers), atol=1e-6, rtol=1e-5)


def _mlp_inputs(dtype: torch.dtype, n: int = 53) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    shapes = [(n, 6), (10, 6), (10,), (4, 10), (4,)]
    return [torch.randn(s, generator=g, dtype=dtype).requires_grad_(True) for s in shapes]


def test_chunked_mlp_gradients_pass_gradcheck_in_float64():
    # chunks of 7 rows leave a short last chunk; every input gets a gradient
    assert torch.autograd.gradcheck(lambda *a: mlp_colors(*a, chunk_rows=7), _mlp_inputs(torch.float64))


@pytest.mark.parametrize("chunk_rows", [1, 16, 53, 1000])
def test_chunked_mlp_matches_the_plain_expression(chunk_rows):
    """Values and every gradient against autograd through the whole-array expression (float32)."""
    inputs = _mlp_inputs(torch.float32, n=300)
    f, w1, b1, w2, b2 = inputs
    grad = torch.rand(300, 4, generator=torch.Generator().manual_seed(5))
    plain = torch.sigmoid(torch.relu(f @ w1.T + b1) @ w2.T + b2)
    ref = torch.autograd.grad(plain, inputs, grad)
    out = mlp_colors(*inputs, chunk_rows=chunk_rows)
    got = torch.autograd.grad(out, inputs, grad)
    torch.testing.assert_close(out, plain, atol=1e-6, rtol=1e-6)
    for a, b in zip(got, ref):  # the weight gradients sum over 300 rows (float64 in the chunked path)
        torch.testing.assert_close(a, b, atol=1e-5 * float(b.abs().max()), rtol=0)
    with pytest.raises(ValueError, match="chunk_rows"):
        mlp_colors(*inputs, chunk_rows=0)


def test_decoders_start_as_the_identity_on_the_color_channels():
    dec = WeatherDecoders(("clear", "snow"), feature_dim=32, hidden=64)
    colors = torch.rand(100, 3, generator=torch.Generator().manual_seed(1)) * 0.9 + 0.05
    f = torch.cat([color_logits(colors), torch.randn(100, 29)], 1)
    out = dec(f, ["clear", "snow"])
    # six hidden units pass the color logits through exactly; the others start small (second-layer
    # weights ~0.01/sqrt(hidden)) and move the colors by well under 1e-3
    torch.testing.assert_close(out[:, :3], colors, atol=1e-3, rtol=0)
    torch.testing.assert_close(out[:, 3:], colors, atol=1e-3, rtol=0)


def test_shared_decoder_gives_every_weather_the_same_colors_and_unknown_weathers_are_refused():
    dec = WeatherDecoders(("clear", "rain"), feature_dim=8, hidden=16, shared=True)
    f = torch.randn(1000, 8, generator=torch.Generator().manual_seed(0))
    out = dec(f, ["clear", "rain"])
    assert torch.equal(out[:, :3], out[:, 3:])
    with pytest.raises(KeyError, match="snow"):
        dec(f, ["snow"])


def _render(model, weathers, placement=None, frame=1):
    return model.render(frame, wm.WORLD_TO_CAMERA, wm.K, wm.WIDTH, wm.HEIGHT, weathers,
                        sky_grid=wm.sky_grid(model), depth=True, placement=placement)


def test_depth_and_alpha_are_identical_across_weathers_and_one_pass_equals_separate_passes():
    model = wm.make_model()
    with torch.no_grad():  # make the weathers' decoders differ
        model.decoders.b2[1] += 0.7
        model.decoders.b2[2] -= 0.5
        together = _render(model, ("clear", "rain", "fog"))
        for w in ("clear", "rain", "fog"):
            alone = _render(model, (w,))
            assert torch.equal(alone.alpha, together.alpha)
            assert torch.equal(alone.depth, together.depth)
            torch.testing.assert_close(together.image(w), alone.images, atol=1e-5, rtol=0)
            assert together.image(w).shape == (wm.HEIGHT, wm.WIDTH, 3)
        assert (together.image("rain") - together.image("clear")).abs().max() > 0.05


def test_the_model_renders_the_same_through_the_torch_twin():
    model = wm.make_model()
    with torch.no_grad():
        fast = _render(model, ("clear", "rain"))
        twin = model.render(1, wm.WORLD_TO_CAMERA, wm.K, wm.WIDTH, wm.HEIGHT, ("clear", "rain"),
                            sky_grid=wm.sky_grid(model), depth=True, rasterizer=rasterize_torch)
    torch.testing.assert_close(fast.images, twin.images, atol=2e-5, rtol=0)
    torch.testing.assert_close(fast.alpha, twin.alpha, atol=2e-5, rtol=0)


def _car_mask(model, placement=None, frame=1) -> np.ndarray:
    """Pixels the car covers (alpha > 0.5 with everything else hidden)."""
    hidden = Placement(hidden={"background"} | (placement.hidden if placement else set()),
                       offsets=placement.offsets if placement else {},
                       copies=placement.copies if placement else [])
    with torch.no_grad():
        return (_render(model, ("clear",), hidden, frame).alpha > 0.5).numpy()


def test_removing_the_car_changes_its_pixels_only():
    model = wm.make_model()
    placement = placement_for(parse_edits("remove class=car"), model.objects())
    with torch.no_grad():
        before = _render(model, ("clear",)).images.numpy()
        after = _render(model, ("clear",), placement).images.numpy()
    car = _car_mask(model)
    assert car.sum() > 50
    changed = np.abs(after - before).max(-1) > 1e-3
    assert changed[car].mean() > 0.9
    # far from the car (its mask grown by 8 px) nothing changes at all
    ys, xs = np.nonzero(car)
    far = np.ones_like(car)
    far[max(ys.min() - 8, 0):ys.max() + 9, max(xs.min() - 8, 0):xs.max() + 9] = False
    assert np.array_equal(after[far], before[far])


def test_translating_the_car_moves_its_projected_center_by_focal_times_shift_over_depth():
    model = wm.make_model()
    placement = placement_for(parse_edits("translate id=5 by=0.5,0,0"), model.objects())
    a, b = _car_mask(model), _car_mask(model, placement)
    shift = np.nonzero(b)[1].mean() - np.nonzero(a)[1].mean()
    assert shift == pytest.approx(wm.FOCAL * 0.5 / wm.CAR_DEPTH, abs=0.5)
    assert np.nonzero(b)[0].mean() == pytest.approx(np.nonzero(a)[0].mean(), abs=0.2)


def test_inserting_a_copy_doubles_the_cars_pixels():
    model = wm.make_model()
    # at frame 0 the car is 1 m left of the axis; the copy 2.8 m to its right does not overlap it
    placement = placement_for(parse_edits("insert id=5 by=2.8,0,0"), model.objects())
    one, two = _car_mask(model, frame=0).sum(), _car_mask(model, placement, frame=0).sum()
    assert two == pytest.approx(2 * one, rel=0.05)


def test_keep_only_and_except_select_by_id_and_class():
    model = wm.make_model()
    assert placement_for(parse_edits("keep-only ids=5"), model.objects()).hidden == set()
    assert placement_for(parse_edits('[{"op": "remove", "ids": ["5"]}]'), model.objects()).hidden == {"rigid:5"}
    for spec in ("remove class=Truck", "remove class=Car except ids=5"):  # a selection of nothing is a typo
        with pytest.raises(ValueError, match="selects no object"):
            placement_for(parse_edits(spec), model.objects())


def test_an_object_absent_at_a_frame_is_not_rendered():
    model = wm.make_model()
    model.rigid[0].present[2] = False
    model.rigid[0].refresh_poses()  # the host copy that at() reads
    g = model.frame_gaussians(2)
    assert [s[0] for s in g.segments] == ["background"]
    assert len(g) == len(model.background)


@pytest.mark.parametrize("placement", [None, Placement(hidden={"background"}),
                                       Placement(copies=[("rigid:5", np.array([0.0, 2.0, 0.0]))])])
def test_precomputed_scales_and_opacities_place_the_same_gaussians(placement):
    # rendering a trained model takes each node's activations once; the frame must not change
    model = wm.make_model()
    with torch.no_grad():
        model.background.opacity_logits += torch.linspace(-1, 1, len(model.background))
        direct = model.frame_gaussians(1, placement)
        cached = model.frame_gaussians(1, placement, activated=model.activated())
    for name in ("means", "quats", "scales", "opacities"):
        assert torch.equal(getattr(direct, name), getattr(cached, name)), name
    assert direct.segments == cached.segments


def test_the_sky_grid_from_cached_camera_rays_equals_the_grid_of_each_frames_rays():
    from wcbench.reference_model.model.sky import camera_rays, view_directions
    from wcbench.reference_model.transforms import quat_to_matrix

    model = wm.make_model()
    rays = camera_rays(wm.K, wm.WIDTH, wm.HEIGHT)
    for q in ([1.0, 0.0, 0.0, 0.0], [0.9, 0.1, -0.3, 0.2], [0.2, 0.7, 0.1, -0.6]):
        c2w = np.eye(4)
        c2w[:3, :3] = quat_to_matrix(np.asarray(q) / np.linalg.norm(q))
        c2w[:3, 3] = [3.0, -1.0, 2.0]
        want = model.sky.grid(torch.from_numpy(view_directions(c2w, wm.K, wm.WIDTH, wm.HEIGHT)))
        got = model.sky.grid_from_rays(rays, c2w)
        # float32 rays turned in float32 against rays built in float64: rounding only (grid units)
        torch.testing.assert_close(got, want, atol=2e-6, rtol=0)


def test_a_sky_window_covers_the_cameras_rays_with_a_margin_and_goes_round_when_they_do():
    from wcbench.reference_model.model.sky import SkyModel, sky_window, view_directions

    frame = {"up": np.array([0.0, -1.0, 0.0]), "heading": np.array([0.0, 0.0, 1.0])}
    rays = torch.from_numpy(view_directions(np.linalg.inv(wm.WORLD_TO_CAMERA), wm.K, wm.WIDTH, wm.HEIGHT))
    window = sky_window(SkyModel(["clear"], **frame), [rays])
    sky = SkyModel(["clear"], **frame, rows=8, cols=16, window=window)
    grid = sky.grid(rays)
    # every ray inside the map, none at its border (10 % margin), and the map mostly used
    assert float(grid.abs().max()) < 0.95 and float(grid[..., 0].max() - grid[..., 0].min()) > 1.5
    # a camera turned all the way round sees every azimuth: the window is the whole circle
    turned = [rays @ torch.tensor([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]],
                                  dtype=torch.float32).T for a in np.linspace(0, 2 * np.pi, 9)]
    a0, a1, _, _ = sky_window(SkyModel(["clear"], **frame), turned)
    assert (a0, a1) == (-np.pi, np.pi)
    with pytest.raises(ValueError, match="window"):
        SkyModel(["clear"], **frame, window=(1.0, 0.0, 0.0, 1.0))


def test_left_multiplication_matrices_equal_the_hamilton_product_and_follow_a_loaded_state():
    from wcbench.reference_model.model.objects import quat_left_matrix, quat_multiply_torch

    gen = torch.Generator().manual_seed(3)
    q, r = torch.randn(50, 4, generator=gen, dtype=torch.float64), torch.randn(50, 4, generator=gen,
                                                                               dtype=torch.float64)
    got = (r[:, None, :] @ quat_left_matrix(q).transpose(-1, -2))[:, 0]
    torch.testing.assert_close(got, quat_multiply_torch(q, r), rtol=0, atol=1e-14)
    # a node placed from a loaded state uses the loaded poses
    model, other = wm.make_model(), wm.make_model()
    with torch.no_grad():
        other.rigid[0].quat[1] = torch.tensor([0.0, 0.0, 1.0, 0.0])
    model.load_state_dict(other.state_dict())
    model = pickle.loads(pickle.dumps(model))  # the model still pickles (workers receive methods)
    _, quats = model.rigid[0].world(1)
    torch.testing.assert_close(quats, quat_multiply_torch(model.rigid[0].quat[1].expand_as(quats),
                                                          model.rigid[0].gaussians.quats))


#: Largest difference of a pixel (RGB in [0, 1], alpha) between the fixed rows' render and the
#: twin's: their centres differ by float32 rounding only.
IMAGE_TOL = 1e-5


@pytest.mark.parametrize("placement", [None, Placement(hidden={"background"}),
                                       Placement(offsets={"rigid:5": np.array([0.5, 0.0, 0.0])},
                                                 copies=[("rigid:5", np.array([0.0, 2.0, 0.0]))])])
def test_fixed_rows_hold_each_frames_gaussians_and_render_the_same_image(placement):
    # FrameRows is the render fast path; frame_gaussians (concatenated afresh) is its twin
    from wcbench.reference_model.model.scene_model import FrameRows
    from wcbench.reference_model.raster.rasterizer import rasterize

    model = wm.make_model()
    model.rigid[0].present[2] = False
    model.rigid[0].refresh_poses()  # the host copy that at() reads
    with torch.no_grad():
        model.background.opacity_logits += torch.linspace(-1, 1, len(model.background))
        colors = {key: model.decoders(p.features, ["rain"]) for key, p in model.nodes().items()}
    rows = FrameRows(model, colors, placement=placement)
    for frame in (0, 2, 1, 1):  # the car leaves and comes back
        written = rows.place(frame)
        with torch.no_grad():
            g = model.frame_gaussians(frame, placement)
            ref = {"means": g.means, "quats": g.quats, "scales": g.scales, "opacities": g.opacities,
                   "colors": torch.cat([colors[key] for key, _, _ in g.segments]) if g.segments else
                   torch.zeros(len(g), 3)}  # nothing placed (the background hidden, the car absent)
        shown = rows.arrays["opacities"] > 0
        assert shown.sum() == len(g)
        for name, value in ref.items():
            # centres and rotations: the same products summed in another order (float32 rounding,
            # 1e-6 relative); the rest copied (tolerance 0)
            tol = 1e-6 if name in ("means", "quats") else 0.0
            np.testing.assert_allclose(rows.arrays[name][shown], value.numpy(), rtol=tol, atol=tol, err_msg=name)
        assert all(s.stop - s.start == len(model.rigid[0].gaussians) for s in written)
        fast = rasterize(*(torch.from_numpy(rows.arrays[k]) for k in ref), torch.from_numpy(wm.WORLD_TO_CAMERA),
                         torch.from_numpy(wm.K), wm.WIDTH, wm.HEIGHT, render_depth=False, absgrad=False)
        slow = rasterize(*ref.values(), torch.from_numpy(wm.WORLD_TO_CAMERA), torch.from_numpy(wm.K), wm.WIDTH,
                         wm.HEIGHT, render_depth=False, absgrad=False)
        # an ulp of a centre moves a pixel's alpha by ~1e-7 (a threshold it flips, by up to 1/255)
        torch.testing.assert_close(fast.color, slow.color, rtol=0, atol=IMAGE_TOL)
        torch.testing.assert_close(fast.alpha, slow.alpha, rtol=0, atol=IMAGE_TOL)
    with pytest.raises(ValueError, match="missing"):
        FrameRows(model, {"background": colors["background"]}, placement=placement)


def _placed_objects(seed: int) -> list:
    """Three rigid objects and a deformed one of different sizes, random poses, one moved by an edit."""
    from scipy.spatial.transform import Rotation

    from wcbench.reference_model.model.gaussians import GaussianParams
    from wcbench.reference_model.model.objects import NonRigidObject, RigidObject

    rng = np.random.default_rng(seed)
    out = []
    for k, n in enumerate((7, 64, 1, 30)):
        poses = np.tile(np.eye(4), (3, 1, 1))
        poses[:, :3, :3] = Rotation.random(3, random_state=seed + k).as_matrix()
        poses[:, :3, 3] = rng.normal(0, 20, (3, 3))
        params = GaussianParams(*(torch.tensor(rng.normal(size=shape), dtype=torch.float32)
                                  for shape in ((n, 3), (n, 3), (n, 4), (n,), (n, 8))))
        cls = NonRigidObject if k == 3 else RigidObject
        obj = cls(params, track_id=str(k), class_name="Car", frames=np.arange(3), object_to_world=poses,
                  box_size=np.ones(3), n_frames=3)
        if k == 3:
            with torch.no_grad():
                obj.offsets.normal_(0, 0.1, generator=torch.Generator().manual_seed(seed))
        out.append((obj, torch.tensor([1.5, -2.0, 0.25]) if k == 1 else None))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_the_batched_placement_of_objects_equals_the_per_object_one(seed):
    # place_objects(batched=True), the GPU's path (a few kernels for any number of objects), against
    # RigidObject.world per object, the CPU's: the same centres, rotations and gradients to float32
    # rounding (the products' sums run in another order; 1e-5 of coordinates of tens of metres)
    from wcbench.reference_model.model.objects import place_objects

    objects = _placed_objects(seed)
    leaves = [t for obj, _ in objects for t in (obj.gaussians.means, obj.gaussians.quats)]
    leaves.append(objects[3][0].offsets)
    weights = None
    results = []
    for batched in (False, True):
        means, quats = place_objects(objects, 2, batched=batched)
        if weights is None:
            g = torch.Generator().manual_seed(seed)
            weights = (torch.randn(means.shape, generator=g), torch.randn(quats.shape, generator=g))
        grads = torch.autograd.grad((means * weights[0]).sum() + (quats * weights[1]).sum(), leaves)
        results.append((means.detach(), quats.detach(), grads))
    (m0, q0, g0), (m1, q1, g1) = results
    assert m0.shape == (102, 3) and q0.shape == (102, 4)
    torch.testing.assert_close(m1, m0, rtol=0, atol=1e-4)  # |means| ~ 40 m: ~2 float32 ulps
    torch.testing.assert_close(q1, q0, rtol=0, atol=1e-5)
    for a, b in zip(g1, g0):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="no objects"):
        place_objects([], 0, batched=True)
