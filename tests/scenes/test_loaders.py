"""Scene loaders on the real PandaSet scene and on Waymo-layout fixtures written here."""

from __future__ import annotations

import numpy as np
import pytest
from scene_fixtures import OPENCV_TO_WAYMO, make_waymo_scene, write_matrix

from wcbench.core.errors import InputError
from wcbench.scenes.loaders import detect_format, load_scene


def test_pandaset_loads_rebased_with_missing_lidar(pandaset_root):
    scene = load_scene(pandaset_root)
    assert scene.source_format == "drivestudio_nuscenes"
    assert len(scene) == 30 and scene.image_size == (1920, 1080)
    np.testing.assert_allclose(scene.frames[0].camera.center, 0.0, atol=1e-12)
    np.testing.assert_allclose(scene.up, [0, 0, 1])
    assert [f.index for f in scene.frames if f.lidar_path is None] == [16, 17, 18]
    assert scene.lidar(16) is None
    sweep = scene.lidar(0)
    assert sweep.points.dtype == np.float32 and sweep.labels is not None
    assert len(sweep.labels) == len(sweep.points)
    # the camera drives ~12 m; after re-basing, everything is within a few hundred metres
    assert np.abs(scene.all_lidar_points()).max() < 500
    # cameras are mounted level: their -y axes agree with the recorded up vector
    minus_y = np.mean([-f.camera.camera_to_world[:3, 1] for f in scene.frames], axis=0)
    assert np.dot(minus_y / np.linalg.norm(minus_y), scene.up) > 0.99


def test_pandaset_car_lidar_lands_in_projected_car_boxes(pandaset_root):
    """Poses, intrinsics, lidar and boxes agree: Car points project inside projected car boxes."""
    scene = load_scene(pandaset_root)
    car_ids = [k for k, v in scene.class_names.items() if v == "Car"]
    checked = 0
    for frame in scene.frames:
        sweep = scene.lidar(frame)
        if sweep is None:
            continue
        cam = frame.camera
        uv, z = cam.project(sweep.points[np.isin(sweep.labels, car_ids)])
        vis = (z > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        uv = uv[vis]
        inside = np.zeros(len(uv), bool)
        for track in scene.tracks:
            k = np.nonzero(track.frames == frame.index)[0]
            if track.class_name != "vehicle" or len(k) == 0:
                continue
            cuv, cz = cam.project(track.corners(int(k[0])))
            if (cz <= 0.1).any():
                continue
            inside |= np.all((uv >= cuv.min(0)) & (uv <= cuv.max(0)), axis=1)
        assert len(uv) > 1000
        assert inside.mean() > 0.95, f"frame {frame.index}: only {inside.mean():.3f} of car points in boxes"
        checked += 1
    assert checked == 27


def test_pandaset_lidar_depth_is_sparse_and_positive(pandaset_root):
    scene = load_scene(pandaset_root)
    depth = scene.lidar_depth(0)
    assert depth.shape == (1080, 1920)
    hit = depth > 0
    assert 0.001 < hit.mean() < 0.2
    assert depth[hit].min() > 0.5 and depth[hit].max() < 300


def test_waymo_layout_converts_axes_and_rebases(tmp_path):
    root = tmp_path / "waymo" / "023"
    truth = make_waymo_scene(root)
    assert detect_format(root) == "drivestudio_waymo"
    scene = load_scene(root)
    assert len(scene) == 4 and scene.source_format == "drivestudio_waymo"
    cam0 = scene.frames[0].camera
    np.testing.assert_allclose(cam0.center, 0.0, atol=1e-9)
    np.testing.assert_allclose(scene.world_offset, np.array([1000.0, -2000.0, 51.5]))
    # OpenCV z (forward) is the vehicle's +x; OpenCV y (down) is world -z
    np.testing.assert_allclose(cam0.camera_to_world[:3, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cam0.camera_to_world[:3, 1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(cam0.camera_to_world[:3, 0], [0, -1, 0], atol=1e-12)
    for k, frame in enumerate(scene.frames):
        expect = truth["egos"][k] @ truth["cam_to_ego"] @ OPENCV_TO_WAYMO
        np.testing.assert_allclose(frame.camera.camera_to_world[:3, :3], expect[:3, :3], atol=1e-12)
        # the lidar point 10 m ahead at camera height projects to the principal point at depth 10
        uv, z = frame.camera.project(scene.lidar(frame).points)
        np.testing.assert_allclose(z, [10.0], atol=1e-4)
        np.testing.assert_allclose(uv[0], truth["K"][:2, 2], atol=1e-3)


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_non_finite_pose_names_the_file(tmp_path, bad):
    root = tmp_path / "scene"
    make_waymo_scene(root)
    m = np.eye(4)
    m[0, 3] = float(bad)
    write_matrix(root / "ego_pose" / "002.txt", m)
    with pytest.raises(InputError, match=r"ego_pose/002\.txt.*non-finite"):
        load_scene(root)


def test_non_finite_intrinsics_names_the_file(tmp_path):
    root = tmp_path / "scene"
    make_waymo_scene(root)
    write_matrix(root / "intrinsics" / "0.txt", np.array([[np.nan, 50, 32, 24, 0, 0, 0, 0, 0]]))
    with pytest.raises(InputError, match=r"intrinsics/0\.txt.*non-finite"):
        load_scene(root)


def test_missing_requested_frames_are_listed(tmp_path):
    root = tmp_path / "scene"
    make_waymo_scene(root, n_frames=3)
    with pytest.raises(InputError, match=r"frames \[3, 4\] are missing"):
        load_scene(root, count=5)


def test_not_a_scene_folder(tmp_path):
    with pytest.raises(InputError, match="not a processed scene folder"):
        load_scene(tmp_path)
    with pytest.raises(InputError, match="does not exist"):
        load_scene(tmp_path / "nope")
