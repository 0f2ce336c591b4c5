"""VGN as a benchmark method (sim_bridge.benchmark.methods.vgn): strict loading of the
published weights, the project's TSDF as VGN's get_grid builds it, VGN's post-processing,
the grasp frame the Panda executor takes, and the real network on a rendered box."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import open3d as o3d
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from gravgrasp_detector.execution.executor import plan_poses
from sim_bridge.benchmark.methods import vgn
from sim_bridge.physics.baseline_files import BaselineFileMissing, baselines_dir
from sim_bridge.physics.depth_rendering import render_depth
from sim_bridge.physics.panda_hand import FINGER_DEPTH_M, HAND_TO_TCP_M, MAX_OPENING_M
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import CameraSettings
from sim_bridge.world.camera import camera_intrinsics, camera_pose

MODEL = baselines_dir() / vgn.MODEL_FILE
needs_model = pytest.mark.skipif(not MODEL.is_file(), reason=f"VGN's published model is not at {MODEL}")
VS = vgn.VOXEL_SIZE_M


@pytest.fixture(scope="module")
def net():
    return vgn.load_vgn()


# loading


@needs_model
def test_published_weights_load_strictly(net):
    assert sum(1 for _ in net.state_dict()) == 18
    quality, quaternions, width = vgn.predict(net, np.zeros((40, 40, 40), np.float32))
    assert quality.shape == width.shape == (40, 40, 40) and quaternions.shape == (4, 40, 40, 40)
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=0), 1.0, atol=1e-5)


@needs_model
def test_a_doctored_file_names_every_wrong_tensor_in_one_error(tmp_path):
    state = torch.load(MODEL, map_location="cpu", weights_only=True)
    del state["conv_rot.bias"]
    state["conv_extra.weight"] = torch.zeros(3)
    state["conv_width.weight"] = torch.zeros(2, 16, 5, 5, 5)
    torch.save(state, tmp_path / "vgn_doctored.pth")
    with pytest.raises(vgn.VGNModelError) as e:
        vgn.load_vgn(tmp_path / "vgn_doctored.pth")
    message = str(e.value)
    assert "3 problems" in message
    assert "missing conv_rot.bias (4,)" in message and "unexpected conv_extra.weight" in message
    assert "conv_width.weight is (2, 16, 5, 5, 5), VGN's is (1, 16, 5, 5, 5)" in message


def test_not_a_state_dict_is_one_clear_error(tmp_path):
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(vgn.VGNModelError, match="is not a PyTorch state dict.*github.com/ethz-asl/vgn"):
        vgn.load_vgn(tmp_path / "junk.pth")
    torch.save([torch.zeros(1)], tmp_path / "list.pth")
    with pytest.raises(vgn.VGNModelError, match="holds a list, not a state dict"):
        vgn.load_vgn(tmp_path / "list.pth")


def test_a_missing_file_says_which_and_where_to_get_it(tmp_path):
    with pytest.raises(BaselineFileMissing, match=r"vgn/vgn_conv\.pth not found.*github\.com/ethz-asl/vgn.*--baselines"):
        vgn.load_vgn(baselines_dir=tmp_path)
    with pytest.raises(BaselineFileMissing, match=r"nope\.pth not found: get it from github\.com/ethz-asl/vgn"):
        vgn.load_vgn(tmp_path / "nope.pth")


# the input: the project's TSDF is VGN's grid


def box_on_table(size_m=(0.04, 0.05, 0.08), centre_xy=(0.15, 0.15)):
    """(meshes, box bounds) of a box standing on the benchmark's table."""
    table = trimesh.creation.box((1.0, 1.0, 0.05))
    table.apply_translation((0.15, 0.15, TABLE_HEIGHT_M - 0.025))
    box = trimesh.creation.box(size_m)
    box.apply_translation((*centre_xy, TABLE_HEIGHT_M + size_m[2] / 2))
    return [table, box], box.bounds


def benchmark_view(meshes):
    """(depth, intrinsics, T_task_camera) from the benchmark's fixed camera."""
    camera = CameraSettings()
    k, T = camera_intrinsics(camera), camera_pose(camera)
    return render_depth(meshes, k, T, camera.max_depth_m), k, T


def vgn_get_grid(depth, k, T_task_camera):
    """VGN's perception.py, restated: a UniformTSDFVolume of the 0.30 m cube (40^3,
    truncation 4 voxels) fed as VGN feeds it (colour+depth RGBD, depth_trunc 2 m,
    extrinsic T_camera_task), then each voxel of the voxel point cloud written at
    floor(point / voxel size) with its grey value, 0 elsewhere."""
    volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=0.30, resolution=40, sdf_trunc=4 * VS, color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor)
    rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.empty_like(depth)), o3d.geometry.Image(depth), depth_scale=1.0, depth_trunc=2.0,
        convert_rgb_to_intensity=False)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    volume.integrate(rgbd, intrinsic, np.linalg.inv(T_task_camera))
    cloud = volume.extract_voxel_point_cloud()
    grid = np.zeros((40, 40, 40), np.float32)
    i, j, k_ = np.floor(np.asarray(cloud.points) / VS).astype(int).T
    grid[i, j, k_] = np.asarray(cloud.colors)[:, 0]
    return grid


def test_the_projects_tsdf_of_a_rendered_scene_is_vgns_grid():
    """Voxel for voxel: the same Open3D integration, so the same voxels and values; the
    only room for a difference is float32 vs float64 in (d + 1) / 2 (1e-6)."""
    depth, k, T = benchmark_view(box_on_table()[0])
    volume = vgn.vgn_volume()
    volume.integrate(depth, k, T)
    ours, theirs = volume.grid(), vgn_get_grid(depth, k, T)
    assert (theirs > 0).sum() > 5000  # the table and the box are in it
    assert np.array_equal(ours != 0, theirs != 0)
    np.testing.assert_allclose(ours, theirs, atol=1e-6, rtol=0)
    grid, T_task_grid = vgn.vgn_input((ours, volume.voxel_size_m, volume.origin))
    assert np.array_equal(grid, ours) and np.array_equal(T_task_grid, np.eye(4))  # no resampling


def test_a_volume_vgn_was_not_trained_on_is_refused():
    with pytest.raises(ValueError, match="VGN reads a 40\\^3 TSDF of 7.5 mm voxels.*vgn_volume"):
        vgn.vgn_input((np.zeros((64, 64, 64)), 0.3 / 64, np.zeros(3)))


# the output: VGN's post-processing


def table_grid():
    """Observed inside (0.3) at k = 5, 6 under observed free space (0.7) at k = 7..9."""
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 5:7], grid[:, :, 7:10] = 0.3, 0.7
    return grid


def test_quality_is_kept_within_two_dilations_of_free_space_and_not_inside():
    width = np.full((40, 40, 40), 5.0, np.float32)
    width[:4], width[-4:] = 12.0, 1.0  # too wide, too narrow
    masked = vgn.mask_quality(table_grid(), np.ones((40, 40, 40), np.float32), width)
    kept_k = np.flatnonzero(masked[20, 20])
    assert kept_k.tolist() == [7, 8, 9, 10, 11]  # free space + 2 up; never into k = 5, 6
    assert not masked[:4].any() and not masked[-4:].any()
    np.testing.assert_allclose(masked[4:-4, :, 7:12], 1.0)  # smoothing a constant keeps it


def bump(centre, peak, radius=5):
    """Quality 0.95 within `radius` of `centre`, rising smoothly to `peak` at it."""
    r2 = ((np.indices((40, 40, 40)).T - np.asarray(centre)).T ** 2).sum(axis=0)
    return np.where(r2 <= radius ** 2, 0.95 + (peak - 0.95) * np.exp(-r2 / 8.0), 0.0).astype(np.float32)


# fingers close along task x, approach straight down: x = y cross z
R_GRASP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


class FixedOutputs(torch.nn.Module):
    """Stands in for the network: returns prepared output volumes."""

    def __init__(self, quality, quaternions, width):
        super().__init__()
        self.outputs = [torch.as_tensor(a)[None] for a in (quality[None], quaternions, width[None])]

    def forward(self, x):
        assert tuple(x.shape) == (1, 1, 40, 40, 40)
        return tuple(self.outputs)


def test_a_known_peak_gives_one_grasp_at_its_voxel_with_its_orientation_and_width():
    quality = np.maximum(bump((20, 20, 9), 0.99), bump((8, 30, 9), 0.97))
    quality = np.maximum(quality, bump((30, 8, 25), 0.99))  # far above the table: masked out
    quaternions = np.broadcast_to(Rotation.from_matrix(R_GRASP).as_quat()[:, None, None, None], (4, 40, 40, 40))
    width = np.full((40, 40, 40), 4.0, np.float32)
    width[0:14, 26:34] = 10.0  # the second peak's width is out of range
    origin = np.array([0.1, -0.2, 0.0])
    grasps = vgn.make_vgn_detector(FixedOutputs(quality, quaternions.astype(np.float32), width))(
        (table_grid(), VS, origin))
    assert len(grasps) == 1
    g = grasps[0]
    assert g.voxel_index == (20, 20, 9)
    np.testing.assert_allclose(g.pose[:3, 3], origin + np.array([20, 20, 9]) * VS)  # index x voxel, VGN's
    np.testing.assert_allclose(g.pose[:3, :3], R_GRASP, atol=1e-6)
    assert g.width_m == pytest.approx(4.0 * VS)
    assert g.rank_key == g.validness and 0.95 < g.validness <= 0.99
    assert math.isnan(g.score_n)  # a probability is never a score in N


def test_selection_thresholds_suppresses_neighbours_and_ranks_best_first():
    quality = np.zeros((40, 40, 40), np.float32)
    quality[10, 10, 9], quality[10, 11, 9] = 0.95, 0.94  # neighbours: the lower one is suppressed
    quality[30, 30, 9], quality[20, 5, 9] = 0.98, 0.89  # the best; one below the threshold
    quaternions = np.zeros((4, 40, 40, 40), np.float32)
    quaternions[3] = 1.0
    grasps = vgn.select_grasps(quality, quaternions, np.full((40, 40, 40), 3.0, np.float32))
    assert [g.voxel_index for g in grasps] == [(30, 30, 9), (10, 10, 9)]
    assert [g.rank_key for g in grasps] == [g.validness for g in grasps] == pytest.approx([0.98, 0.95])


# the grasp frame the Panda executor takes


def test_vgns_grasp_frame_is_the_panda_hands_tcp_frame():
    """VGN's grasp pose is its hand's TCP: 0.022 m past PyBullet's body frame (the hand
    link's centre of mass) along the approach z, fingers closing along y and reaching
    finger_depth 0.05 m past it. Read from the hand's URDF and finger mesh, that is the
    Panda model's TCP (physics.panda_hand), so the pose passes unchanged."""
    hand_dir = baselines_dir() / "panda_hand"
    if not (hand_dir / "hand.urdf").is_file():
        pytest.skip(f"the Panda hand is not at {hand_dir}")
    robot = ET.parse(hand_dir / "hand.urdf").getroot()
    com_z = float(robot.find("link[@name='panda_hand']/inertial/origin").get("xyz").split()[2])
    assert com_z + 0.022 == pytest.approx(HAND_TO_TCP_M)
    joints = robot.findall("joint[@type='prismatic']")
    assert sorted(j.find("axis").get("xyz") for j in joints) == ["0 -1 0", "0 1 0"]  # closing along y
    finger = trimesh.load(hand_dir / "meshes/collision/finger.obj", force="mesh")
    tip_z = float(joints[0].find("origin").get("xyz").split()[2]) + finger.bounds[1, 2]  # fingers point along +z
    assert tip_z - HAND_TO_TCP_M == pytest.approx(0.05, abs=1e-3)  # VGN's finger_depth
    assert FINGER_DEPTH_M == pytest.approx(0.05, abs=1e-3)


def test_the_executor_backs_a_vgn_grasp_off_against_its_approach():
    quality = bump((20, 20, 9), 0.99)
    quaternions = np.broadcast_to(Rotation.from_matrix(R_GRASP).as_quat()[:, None, None, None], (4, 40, 40, 40))
    grasp = vgn.select_grasps(vgn.mask_quality(table_grid(), quality, np.full((40, 40, 40), 4.0, np.float32)),
                              quaternions, np.full((40, 40, 40), 4.0, np.float32))[0]
    poses = plan_poses(grasp.pose, 0.05, 0.1)
    np.testing.assert_allclose(poses["pregrasp"][:3, 3] - grasp.pose[:3, 3], [0.0, 0.0, 0.05])  # up, away


# the real network on a rendered scene


@needs_model
def test_the_published_network_grasps_a_rendered_box(net):
    meshes, (lo, hi) = box_on_table()
    depth, k, T = benchmark_view(meshes)
    volume = vgn.vgn_volume()
    volume.integrate(depth, k, T)
    grasps = vgn.make_vgn_detector(net)((volume.grid(), volume.voxel_size_m, volume.origin))
    assert grasps, "VGN found no grasp on a 4 x 5 x 8 cm box"
    best = grasps[0]
    tips = best.pose[:3, 3] + FINGER_DEPTH_M * best.pose[:3, 2]
    assert np.all(tips > lo - 0.01) and np.all(tips < hi + 0.01), "the finger tips do not reach the box"
    assert 0.02 < best.width_m < MAX_OPENING_M

