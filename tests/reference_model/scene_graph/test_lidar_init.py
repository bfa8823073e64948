"""Gaussians initialised from lidar: coloring, voxels, scales, moving objects, sky color."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from paths import PANDASET

from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.scene_graph.lidar_init import (
    LidarInitOptions,
    estimate_sky_color,
    init_from_lidar,
    init_scene_from_lidar,
    node_tracks,
    sample_image,
    voxel_downsample,
)
from wcbench.scenes.scene import Camera, Frame, LidarSweep, ObjectTrack, Scene

RED, BLUE, SKY = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.6, 0.7, 0.9)
W, H, F = 80, 60, 50.0


def _grid(x0: float, x1: float, y0: float, y1: float, z: float, step: float) -> np.ndarray:
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)


#: Centre of the parked cube of ``make_scene(parked=True)`` (world, m).
PARKED = np.array([2.0, 0.0, 6.0])


def make_scene(tmp_path: Path, *, noise_point: bool = False, parked: bool = False) -> Scene:
    """Three frames of a camera driving along +z towards a wall (left red, right blue) at z = 8,
    with a 1 m cube moving 1 m/frame along +x, and optional lone noise point near the camera.
    ``parked``: a second 1 m cube standing at :data:`PARKED` in every sweep, its box (track
    ``"parked"``, class Car) annotated in every frame, 8 cm off in frame 1 (annotation jitter)."""
    img = np.zeros((H, W, 3), np.uint8)
    img[:, : W // 2] = (0, 0, 255)  # BGR red on the left
    img[:, W // 2 :] = (255, 0, 0)  # blue on the right
    img[: H // 4] = (np.array(SKY[::-1]) * 255).astype(np.uint8)  # sky band at the top
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])
    frames, poses = [], []
    for k in range(3):
        path = tmp_path / f"{k:03d}.png"
        cv2.imwrite(str(path), img)
        c2w = np.eye(4)
        c2w[2, 3] = 0.5 * k
        frames.append(
            Frame(
                index=k,
                timestamp=0.1 * k,
                camera=Camera(K=K, width=W, height=H, camera_to_world=c2w),
                image_path=path,
                lidar_path=tmp_path / f"{k:03d}.bin",
            )
        )
        T = np.eye(4)
        T[:3, 3] = [-2.0 + 1.0 * k, 0.5, 5.0]
        poses.append(T)
    wall = _grid(-4, 4, -0.9, 2, 8.0, 0.05)  # below the sky band (y down: the band is y < -1.2 at z=8)

    def loader(frame: Frame) -> LidarSweep:
        cube = _grid(-0.45, 0.45, -0.45, 0.45, -0.45, 0.1) + poses[frame.index][:3, 3]
        pts = [wall, cube]
        if noise_point and frame.index == 0:
            pts.append(np.array([[0.3, 0.2, 2.0]]))
        if parked:
            pts.append(_grid(-0.45, 0.45, -0.45, 0.45, -0.45, 0.1) + PARKED)
        return LidarSweep(points=np.concatenate(pts).astype(np.float32))

    track = ObjectTrack(
        id="car",
        class_name="Car",
        frames=np.arange(3),
        object_to_world=np.stack(poses),
        box_size=np.tile([1.0, 1.0, 1.0], (3, 1)),
    )
    tracks = [track]
    if parked:
        T = np.tile(np.eye(4), (3, 1, 1))
        T[:, :3, 3] = PARKED
        T[1, 0, 3] += 0.08
        tracks.append(ObjectTrack(id="parked", class_name="Car", frames=np.arange(3), object_to_world=T,
                                  box_size=np.ones((3, 3))))
    return Scene(
        id="synthetic",
        frames=frames,
        tracks=tracks,
        up=np.array([0.0, -1.0, 0.0]),
        world_offset=np.zeros(3),
        source_format="test",
        root=tmp_path,
        lidar_loader=loader,
    )


def test_voxel_downsample_averages_per_voxel() -> None:
    pts = np.array([[0.01, 0.01, 0.01], [0.09, 0.05, 0.02], [0.5, 0.5, 0.5]])
    vals = np.array([[1.0], [3.0], [7.0]])
    centers, means, counts = voxel_downsample(pts, vals, 0.1)
    order = np.argsort(counts)[::-1]
    np.testing.assert_array_equal(counts[order], [2, 1])
    np.testing.assert_allclose(centers[order[0]], [0.05, 0.03, 0.015], rtol=1e-6)
    np.testing.assert_allclose(means[order].ravel(), [2.0, 7.0])
    with pytest.raises(ValueError, match="voxel_m"):
        voxel_downsample(pts, vals, 0.0)


def test_sample_image_is_exact_at_pixel_centers_and_bilinear_between() -> None:
    img = np.random.default_rng(0).random((5, 6, 3)).astype(np.float32)
    uv = np.array([[2.5, 3.5], [0.5, 0.5]])
    np.testing.assert_allclose(sample_image(img, uv), img[[3, 0], [2, 0]], rtol=1e-6)
    mid = sample_image(img, np.array([[3.0, 1.5]]))
    np.testing.assert_allclose(mid[0], (img[1, 2] + img[1, 3]) / 2, rtol=1e-6)


def test_gaussian_cloud_checks_shapes_and_round_trips(tmp_path: Path) -> None:
    n = 4
    cloud = GaussianCloud(
        np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), np.ones((n, 3)), np.ones(n), np.zeros((n, 3))
    )
    assert cloud.means.dtype == np.float32 and len(cloud) == n
    cloud.save_npz(tmp_path / "c.npz")
    back = GaussianCloud.load_npz(tmp_path / "c.npz")
    np.testing.assert_array_equal(back.quats, cloud.quats)
    with pytest.raises(ValueError, match="colors"):
        GaussianCloud(np.zeros((n, 3)), np.zeros((n, 4)), np.ones((n, 3)), np.ones(n), np.zeros((n, 4)))


def test_isotropic_clouds_are_unrotated_spheres_with_clipped_colours() -> None:
    means = np.arange(9.0).reshape(3, 3)
    cloud = GaussianCloud.isotropic(means, np.array([0.1, 0.2, 0.3]), np.array([[1.5, 0.5, -0.2]] * 3), 0.7)
    np.testing.assert_array_equal(cloud.quats, np.tile(np.float32([1, 0, 0, 0]), (3, 1)))
    np.testing.assert_array_equal(cloud.scales, np.float32([[0.1] * 3, [0.2] * 3, [0.3] * 3]))
    np.testing.assert_array_equal(cloud.colors, np.tile(np.float32([1.0, 0.5, 0.0]), (3, 1)))
    np.testing.assert_array_equal(cloud.opacities, np.float32([0.7] * 3))
    one = GaussianCloud.isotropic(means, 0.25, np.zeros((3, 3)), np.array([0.1, 0.2, 0.3]))
    assert one.scales.shape == (3, 3) and np.all(one.scales == np.float32(0.25))
    np.testing.assert_array_equal(one.opacities, np.float32([0.1, 0.2, 0.3]))
    assert len(GaussianCloud.isotropic(np.zeros((0, 3)), 0.1, np.zeros((0, 3)), 0.5)) == 0


def test_static_gaussians_take_the_image_colors_and_drop_moving_objects(tmp_path: Path) -> None:
    scene = make_scene(tmp_path)
    cloud = init_from_lidar(scene, LidarInitOptions(voxel_m=0.1))
    assert len(cloud) > 100
    on_wall = np.abs(cloud.means[:, 2] - 8.0) < 0.05
    assert on_wall.all()  # the moving cube is cut out
    left, right = cloud.means[:, 0] < -0.2, cloud.means[:, 0] > 0.2
    np.testing.assert_allclose(cloud.colors[left], np.tile(RED, (left.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(cloud.colors[right], np.tile(BLUE, (right.sum(), 1)), atol=1e-6)
    np.testing.assert_array_equal(cloud.quats, np.tile([1.0, 0, 0, 0], (len(cloud), 1)))
    # 3DGS scale: half the spacing (0.1 m voxels), clipped by 0.02 rad times the range (>= 8 m here).
    assert np.median(cloud.scales) == pytest.approx(0.5 * 0.1, rel=0.25)
    kept = init_from_lidar(scene, LidarInitOptions(voxel_m=0.1), moving_objects="keep")
    assert len(kept) > len(cloud)  # the cube's three positions smear in as a trail


def test_moving_objects_become_rigid_nodes_posed_per_frame(tmp_path: Path) -> None:
    scene = make_scene(tmp_path)
    sg = init_scene_from_lidar(scene, LidarInitOptions(voxel_m=0.1, node_voxel_m=0.1))
    assert len(sg.nodes) == 1 and sg.nodes[0].track_id == "car"
    local = sg.nodes[0].cloud.means
    assert np.abs(local).max() < 0.55  # in the box frame, around its center
    for k in range(3):
        node = sg.nodes[0].at_frame(k)
        assert node is not None
        # The lidar saw the cube's front face (z = -0.45 in the box frame) wherever the box was.
        face = _grid(-0.45, 0.45, -0.45, 0.45, -0.45, 0.1).mean(0)
        np.testing.assert_allclose(
            node.means.mean(0), scene.tracks[0].object_to_world[k][:3, 3] + face, atol=0.02
        )
        assert len(sg.at_frame(k)) == len(sg.static) + len(node)
    assert sg.nodes[0].at_frame(7) is None


def _in_parked_box(means: np.ndarray, margin: float) -> np.ndarray:
    return np.all(np.abs(means - PARKED) <= 0.5 + margin, axis=1)


def test_a_parked_track_becomes_a_node_held_still_and_leaves_the_static_cloud(tmp_path: Path) -> None:
    scene = make_scene(tmp_path, parked=True)
    old = init_scene_from_lidar(scene, LidarInitOptions(voxel_m=0.1, node_voxel_m=0.1))
    assert [n.track_id for n in old.nodes] == ["car"]  # off: the parked cube stays in the static cloud
    assert _in_parked_box(old.static.means, 0.0).sum() > 10
    sg = init_scene_from_lidar(scene, LidarInitOptions(voxel_m=0.1, node_voxel_m=0.1, static_nodes=True))
    assert [n.track_id for n in sg.nodes] == ["car", "parked"]
    assert not _in_parked_box(sg.static.means, 0.2).any()
    parked = sg.nodes[1]
    assert parked.class_name == "Car" and len(parked.cloud) > 10
    face = _grid(-0.45, 0.45, -0.45, 0.45, -0.45, 0.1).mean(0)
    np.testing.assert_array_equal(parked.object_to_world[:, :3, 3], np.tile(PARKED, (3, 1)))  # the median box
    for k in range(3):
        placed = parked.at_frame(k)
        assert placed is not None
        np.testing.assert_allclose(placed.means.mean(0), PARKED + face, atol=0.02)
        assert len(sg.at_frame(k)) == len(sg.static) + len(sg.nodes[0].at_frame(k)) + len(placed)


def test_node_tracks_hold_still_tracks_and_keep_a_part_time_mover_whole() -> None:
    still = np.tile(np.eye(4), (4, 1, 1))
    still[:, :3, 3] = [5.0, 1.0, 0.0]
    still[1, :3, 3] += 0.02  # annotation jitter, below the threshold
    stop_go = np.tile(np.eye(4), (4, 1, 1))
    stop_go[3, :3, 3] = [3.0, 0.0, 0.0]  # parked for three frames, then drives off
    tracks = [SimpleNamespace(id="7", class_name="Car", frames=np.array([0, 1, 2]), object_to_world=still[:3],
                              box_size=np.ones((3, 3))),
              SimpleNamespace(id="8", class_name="Car", frames=np.arange(4), object_to_world=stop_go,
                              box_size=np.ones((4, 3)))]
    scene = SimpleNamespace(tracks=tracks)
    assert node_tracks(scene) == [tracks[1]]
    held = node_tracks(scene, static_nodes=True)
    assert held[0] is tracks[1] and len(held) == 2  # the mover: one node, posed per annotated frame
    np.testing.assert_array_equal(held[1].frames, [0, 1, 2])
    np.testing.assert_array_equal(held[1].object_to_world, np.tile(still[0], (3, 1, 1)))  # the median box
    assert held[1].id == "7" and held[1].box_size.shape == (3, 3)


def test_isolated_noise_returns_are_dropped(tmp_path: Path) -> None:
    scene = make_scene(tmp_path, noise_point=True)
    cloud = init_from_lidar(scene, LidarInitOptions(voxel_m=0.1))
    assert np.linalg.norm(cloud.means - [0.3, 0.2, 2.0], axis=1).min() > 1.0


def test_sky_color_comes_from_pixels_without_lidar(tmp_path: Path) -> None:
    scene = make_scene(tmp_path)
    np.testing.assert_allclose(estimate_sky_color(scene, radius_px=1), SKY, atol=1 / 255)


def test_real_scene_initialisation(tmp_path: Path) -> None:
    if not (PANDASET / "images").is_dir():
        pytest.skip(f"real scene not present at {PANDASET}")
    from wcbench.scenes.loaders import load_scene

    scene = load_scene(PANDASET)
    cloud = init_from_lidar(scene, LidarInitOptions(voxel_m=0.3), frames=[15, 16])  # 16 has no sweep: skipped
    assert len(cloud) > 10_000
    for name in ("means", "scales", "colors", "opacities"):
        assert np.all(np.isfinite(getattr(cloud, name)))
    assert cloud.colors.min() >= 0 and cloud.colors.max() <= 1
    assert np.all((cloud.scales > 0) & (cloud.scales <= 0.5))


def test_edits_reach_a_parked_node_of_the_trained_model(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from wcbench.reference_model.editing.edits import parse_edits, placement_for
    from wcbench.reference_model.model.scene_model import BACKGROUND
    from wcbench.reference_model.training.build import build_model
    from wcbench.reference_model.training.config import make_config
    from wcbench.reference_model.training.views import build_views

    scene = make_scene(tmp_path, parked=True)
    views, _ = build_views(scene, size=(W, H), derive_sky=False)
    config = make_config("quick", width=W, voxel_m=0.1, node_voxel_m=0.1, far_points=False,
                         completion_points=False, static_nodes=True)  # opt-in: it costs training time
    model, facts = build_model(scene, views, config, weathers=("clear",))
    assert sorted(model.objects()) == ["rigid:car", "rigid:parked"] and facts["skipped"]["tracks_in_background"] == 0
    assert not _in_parked_box(model.background.means.detach().numpy(), 0.2).any()

    def rows(frame: int, spec: str | None) -> dict[str, np.ndarray]:
        place = None if spec is None else placement_for(parse_edits(spec), model.objects())
        g = model.frame_gaussians(frame, place)
        means = g.means.detach().numpy()
        return {key: means[a:b] for key, a, b in g.segments}

    for frame in (1, 2):
        plain = rows(frame, None)
        assert _in_parked_box(plain["rigid:parked"], 0.0).all()
        removed = rows(frame, "remove class=car")
        assert list(removed) == [BACKGROUND]
        assert not _in_parked_box(np.concatenate(list(removed.values())), 0.2).any()  # no car left there
        kept = rows(frame, "keep-only ids=parked")
        assert list(kept) == [BACKGROUND, "rigid:parked"]
        moved = rows(frame, "translate id=parked by=0,0,1.5")
        np.testing.assert_allclose(moved["rigid:parked"], plain["rigid:parked"] + [0.0, 0.0, 1.5], atol=1e-5)
        place = placement_for(parse_edits("insert id=parked by=-3,0,0"), model.objects())
        g = model.frame_gaussians(frame, place)
        copies = [g.means[a:b].detach().numpy() for key, a, b in g.segments if key == "rigid:parked"]
        assert len(copies) == 2
        np.testing.assert_allclose(copies[1], copies[0] + [-3.0, 0.0, 0.0], atol=1e-5)


def _parked_on_a_road(tmp_path: Path) -> tuple[Scene, np.ndarray]:
    """Three frames of a camera 10 m above a grey road (z up) looking steeply down along +x at a red
    4 x 2 x 1.5 m box parked at the origin: no sweep sees the road under it. Returns the scene and
    the road's colour (RGB in [0, 1])."""
    road_rgb = np.array([0.35, 0.35, 0.40])
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])
    forward = np.array([0.2, 0.0, -1.0]) / np.linalg.norm([0.2, 0.0, -1.0])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(forward, right), forward], 1)  # OpenCV camera axes in the world
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, 2, 3] = 0.75
    size = np.array([4.0, 2.0, 1.5])
    frames, poses = [], []
    for k in range(3):
        c2w = np.eye(4)
        c2w[:3, :3] = R
        c2w[:3, 3] = [0.3 * k - 2.3, 0.0, 10.0]
        cam = Camera(K=K, width=W, height=H, camera_to_world=c2w)
        img = np.empty((H, W, 3), np.uint8)
        img[:] = (road_rgb[::-1] * 255).round().astype(np.uint8)
        corners = np.array([[sx * 2.0, sy * 1.0, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (0.0, 1.5)])
        uv, _ = cam.project(corners)
        cv2.fillConvexPoly(img, cv2.convexHull(np.round(uv).astype(np.int32)), (0, 0, 255))  # BGR red
        path = tmp_path / f"{k:03d}.png"
        cv2.imwrite(str(path), img)
        frames.append(Frame(index=k, timestamp=0.1 * k, camera=cam, image_path=path,
                            lidar_path=tmp_path / f"{k:03d}.bin"))
        poses.append(c2w)
    x, y = np.meshgrid(np.arange(-7, 7, 0.1), np.arange(-5, 5, 0.1))
    road = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    road = road[(np.abs(road[:, 0]) > 2.2) | (np.abs(road[:, 1]) > 1.2)]  # hidden under the box and its margin
    top = _grid(-1.95, 1.95, -0.95, 0.95, 1.5, 0.1)

    def loader(frame: Frame) -> LidarSweep:
        return LidarSweep(points=np.concatenate([road, top]).astype(np.float32))

    track = ObjectTrack(id="parked", class_name="Car", frames=np.arange(3), object_to_world=T,
                        box_size=np.tile(size, (3, 1)))
    scene = Scene(id="parked_on_road", frames=frames, tracks=[track], up=np.array([0.0, 0.0, 1.0]),
                  world_offset=np.zeros(3), source_format="test", root=tmp_path, lidar_loader=loader)
    return scene, road_rgb


def test_removing_a_parked_car_leaves_the_road_under_it_not_a_hole(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    import torch

    from wcbench.reference_model.editing.edits import parse_edits, placement_for
    from wcbench.reference_model.model.sky import view_directions
    from wcbench.reference_model.training.build import build_model
    from wcbench.reference_model.training.config import make_config
    from wcbench.reference_model.training.views import build_views

    scene, road_rgb = _parked_on_a_road(tmp_path)
    views, _ = build_views(scene, size=(W, H), derive_sky=False)
    config = make_config("quick", width=W, voxel_m=0.1, node_voxel_m=0.1, far_points=False,
                         completion_points=False, static_nodes=True, init_opacity=0.9)
    model, facts = build_model(scene, views, config, weathers=("clear",))
    assert facts["footprint_fill_gaussians"] > 50
    model.eval()
    cam = scene.frames[1].camera
    c2w = np.asarray(cam.camera_to_world, np.float64)
    w2c = np.linalg.inv(c2w)
    grid = model.sky.grid(torch.from_numpy(view_directions(c2w, cam.K, W, H)))
    place = placement_for(parse_edits("remove class=car"), model.objects())
    with torch.no_grad():
        out = model.render(1, w2c, cam.K, W, H, ("clear",), sky_grid=grid, placement=place)
    image = out.images.numpy().reshape(H, W, 3)
    uv, _ = cam.project(np.array([[x, y, 0.0] for x in (-1.5, 0.0, 1.5) for y in (-0.6, 0.0, 0.6)]))
    under = image[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]
    np.testing.assert_allclose(under, np.tile(road_rgb, (len(under), 1)), atol=0.06)  # road, not red, not sky
