"""Ray-cast depth rendering: depths, conventions, and agreement with the TSDF."""
import numpy as np
import pytest
import trimesh

from gravgrasp_detector.perception.tsdf import CameraIntrinsics, TSDFVolume
from sim_bridge.physics.depth_rendering import DepthRenderer, look_at, random_view_on_hemisphere, render_depth

K = CameraIntrinsics(640, 480, 540.0, 540.0, 319.5, 239.5)


def table():
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.02))
    box.apply_translation((0.15, 0.15, 0.04))  # top at z = 0.05
    return box


def test_top_down_plane_depth_is_optical_z():
    T = look_at((0.15, 0.15, 0.65), (0.15, 0.15, 0.0), up=(0, 1, 0))
    depth = render_depth([table()], K, T)
    assert depth.dtype == np.float32 and depth.shape == (480, 640)
    np.testing.assert_allclose(depth, 0.60, atol=1e-5)  # z-depth, not ray length


def test_box_pose_pairs_and_misses():
    cube = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    T_mesh = np.eye(4)
    T_mesh[:3, 3] = (0.15, 0.15, 0.075)  # top at 0.10
    T_cam = look_at((0.15, 0.15, 0.60), (0.15, 0.15, 0.0), up=(0, 1, 0))
    depth = render_depth([(cube, T_mesh)], K, T_cam)
    assert depth[240, 320] == pytest.approx(0.50, abs=1e-5)
    assert depth[0, 0] == 0.0  # misses are "no return"
    assert (depth > 0).sum() == pytest.approx((540 * 0.05 / 0.5) ** 2, rel=0.1)  # 5 cm at 0.5 m
    assert DepthRenderer([(cube, T_mesh)]).render(K, T_cam, max_depth_m=0.4).max() == 0.0


def test_look_at_is_optical_and_right_handed():
    T = look_at((1.0, 0.0, 0.5), (0.0, 0.0, 0.0))
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 2], -np.array([1.0, 0, 0.5]) / np.linalg.norm([1.0, 0, 0.5]))
    assert R[2, 1] < 0  # image y (down) points down in the world
    down = look_at((0, 0, 1.0), (0, 0, 0))  # looking along -up: still defined
    assert np.isfinite(down).all()


def test_random_views_look_at_target_from_above():
    rng = np.random.default_rng(0)
    target = np.array([0.15, 0.15, 0.05])
    for _ in range(50):
        T = random_view_on_hemisphere(rng, target)
        to_target = target - T[:3, 3]
        assert 0.45 <= np.linalg.norm(to_target) <= 0.65
        np.testing.assert_allclose(T[:3, 2], to_target / np.linalg.norm(to_target), atol=1e-12)
        assert T[2, 3] > target[2]


def test_rendered_scene_fuses_to_its_surface():
    T = look_at((0.4, -0.2, 0.5), (0.15, 0.15, 0.05))
    vol = TSDFVolume()
    vol.integrate(render_depth([table()], K, T), K, T)
    grid, weights = vol.grid(), vol.weights()
    k = int(np.floor(0.05 / vol.voxel_size_m - 0.5))  # table top between k and k + 1
    seen = (weights[:, :, k] > 0) & (weights[:, :, k + 1] > 0)
    assert seen.sum() > 1000
    assert (grid[:, :, k][seen] < 0.5).all() and (grid[:, :, k + 1][seen] >= 0.5).all()
