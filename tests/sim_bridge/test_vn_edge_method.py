"""VN-EdgeGraspNet as a benchmark method (sim_bridge.benchmark.methods.vn_edge*): strict
loading of the four published checkpoints, the project's TSDF -> the authors' point cloud,
the edges' grasp geometry and frame, the network's SE(3) invariance, its output pinned
on a fixed cloud, and the whole detector on a rendered box."""

import copy
import pathlib
import xml.etree.ElementTree as ET

import numpy as np
import open3d as o3d
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from sim_bridge.benchmark import methods, protocol
from sim_bridge.benchmark import rounds as bench_rounds
from sim_bridge.benchmark.methods import vn_edge, vn_edge_cloud, vn_edge_net
from sim_bridge.physics.baseline_files import BaselineFileMissing, baselines_dir
from sim_bridge.physics.panda_hand import FINGER_DEPTH_M, FINGER_TIP_Z_M, HAND_TO_TCP_M
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from baselines import VN_EDGE_FILES, needs_panda, needs_vn_edge  # tests/support
from test_vgn_method import benchmark_view, box_on_table

CHECKPOINTS = baselines_dir() / vn_edge_net.CHECKPOINT_DIR


@pytest.fixture(scope="module")
def net():
    return vn_edge_net.load_vn_edge()


def box_cloud(size_m=(0.02, 0.025, 0.03), centre_xy=(0.15, 0.15), spacing_m=0.0045, jitter_m=0.0008, seed=0):
    """(points, normals) float32 of a box's five faces above the table on a 4.5 mm grid
    (the authors' down-sampling), jittered as their 0.8 mm noise (which also breaks the
    grid's distance ties), with the faces' outward normals."""
    lo = np.array([*centre_xy, TABLE_HEIGHT_M]) - [size_m[0] / 2, size_m[1] / 2, 0.0]
    hi = lo + size_m
    points, normals = [], []
    for axis in range(3):
        for sign, face in ((-1.0, lo[axis]), (1.0, hi[axis])):
            if axis == 2 and sign < 0:
                continue  # standing on the table
            u, v = (a for a in range(3) if a != axis)
            grid = np.meshgrid(np.arange(lo[u] + spacing_m / 2, hi[u], spacing_m),
                               np.arange(lo[v] + spacing_m / 2, hi[v], spacing_m), indexing="ij")
            p = np.full((grid[0].size, 3), face)
            p[:, u], p[:, v] = grid[0].ravel(), grid[1].ravel()
            n = np.zeros_like(p)
            n[:, axis] = sign
            points.append(p)
            normals.append(n)
    points = np.concatenate(points) + np.random.default_rng(seed).normal(0.0, jitter_m, (sum(map(len, points)), 3))
    return points.astype(np.float32), np.concatenate(normals).astype(np.float32)


# loading


@needs_vn_edge
def test_the_published_checkpoints_load_strictly(net):
    counts = {part: len(getattr(net, part).state_dict()) for part in vn_edge_net.PARTS}
    assert counts == {"local_emd_model": 15, "global_emd_model": 12, "classifier_model": 8, "std": 5}
    stored = torch.load(CHECKPOINTS / "std-ckpt-105.pt", map_location="cpu", weights_only=True)
    assert torch.equal(net.std.vn_lin.weight, stored["vn_lin.weight"])


def copy_checkpoints(to_dir, **doctored):
    """The four checkpoints in `to_dir`: links to the published ones, but `doctored`
    ({part: function(state)}) ones written changed."""
    for part in vn_edge_net.PARTS:
        name = f"{part}-ckpt-105.pt"
        if part in doctored:
            state = torch.load(CHECKPOINTS / name, map_location="cpu", weights_only=True)
            doctored[part](state)
            torch.save(state, to_dir / name)
        else:
            (to_dir / name).symlink_to(CHECKPOINTS / name)


@needs_vn_edge
def test_doctored_checkpoints_name_every_wrong_tensor_in_one_error(tmp_path):
    copy_checkpoints(tmp_path, local_emd_model=lambda s: s.pop("relu3.map_to_dir.weight"),
                     global_emd_model=lambda s: s.update({"vn6.map_to_feat.weight": torch.zeros(3)}),
                     classifier_model=lambda s: s.update({"head.6.weight": torch.zeros(2, 64)}))
    with pytest.raises(vn_edge_net.VNEdgeModelError) as e:
        vn_edge_net.load_vn_edge(tmp_path)
    message = str(e.value)
    assert "3 problems" in message and "\n" not in message
    assert "local_emd_model-ckpt-105.pt: missing relu3.map_to_dir.weight (128, 128)" in message
    assert "global_emd_model-ckpt-105.pt: unexpected vn6.map_to_feat.weight" in message
    assert "classifier_model-ckpt-105.pt: head.6.weight is (2, 64), VN-EdgeGraspNet's is (1, 64)" in message


def test_missing_checkpoints_say_which_and_where_to_get_them(tmp_path):
    with pytest.raises(BaselineFileMissing) as e:
        vn_edge_net.load_vn_edge(baselines=tmp_path)
    message = str(e.value)
    assert all(str(tmp_path / f) in message for f in VN_EDGE_FILES)
    assert "github.com/HaojHuang/Edge-Grasp-Network, vn_edge_pretrained_para/checkpoints/" in message
    assert "--baselines DIR" in message
    (tmp_path / "classifier_model-ckpt-105.pt").write_bytes(b"")
    with pytest.raises(BaselineFileMissing, match=r"checkpoints .*std-ckpt-105\.pt not found: get them from github"):
        vn_edge_net.load_vn_edge(tmp_path / "classifier_model-ckpt-105.pt")


def test_a_file_that_is_not_a_checkpoint_is_one_clear_error(tmp_path):
    for part in vn_edge_net.PARTS:
        (tmp_path / f"{part}-ckpt-105.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(vn_edge_net.VNEdgeModelError, match="is not a PyTorch state dict.*Edge-Grasp-Network"):
        vn_edge_net.load_vn_edge(tmp_path)
    with pytest.raises(vn_edge_net.VNEdgeModelError, match="not named <part>-ckpt-<epoch>.pt"):
        vn_edge_net.load_vn_edge(tmp_path / "weights.pt")


# the input: the project's TSDF -> the authors' point cloud


def test_the_projects_tsdf_gives_the_authors_surface_points():
    """The project's 180^3 TSDF of a rendered box, turned into points from its grid, is
    the cloud the authors' test takes from its own TSDF (their TSDFVolume restated: a
    UniformTSDFVolume of the 0.30 m cube, 180^3, truncation 4 voxels, fed as they feed it,
    then extract_point_cloud): the same points, to float rounding."""
    depth, k, T = benchmark_view(box_on_table()[0])
    volume = vn_edge_cloud.edge_volume()
    volume.integrate(depth, k, T)
    ours = vn_edge_cloud.surface_points(volume.grid(), volume.voxel_size_m, volume.origin)
    voxel_m = 0.30 / 180
    theirs_volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=0.30, resolution=180, sdf_trunc=4 * voxel_m,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor)
    rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.empty_like(depth)), o3d.geometry.Image(depth), depth_scale=1.0, depth_trunc=2.0,
        convert_rgb_to_intensity=False)
    theirs_volume.integrate(rgbd, o3d.camera.PinholeCameraIntrinsic(k.width, k.height, k.fx, k.fy, k.cx, k.cy),
                            np.linalg.inv(T))
    theirs = np.asarray(theirs_volume.extract_point_cloud().points)
    assert len(theirs) > 10000 and len(ours) == len(theirs)
    distance, nearest = cKDTree(theirs).query(ours)
    assert distance.max() < 1e-6 and len(np.unique(nearest)) == len(theirs)  # one to one


def test_the_crop_is_the_authors_workspace():
    lower, upper = vn_edge_cloud.workspace_bounds()
    np.testing.assert_allclose(lower, [0.02, 0.02, TABLE_HEIGHT_M + 0.005])
    np.testing.assert_allclose(upper, [0.28, 0.28, 0.30])
    box, _ = box_cloud(jitter_m=0.0)
    table = np.stack(np.meshgrid(np.arange(0.0, 0.3, 0.003), np.arange(0.0, 0.3, 0.003), [TABLE_HEIGHT_M + 0.001]),
                     -1).reshape(-1, 3)
    points, normals = vn_edge_cloud.edge_point_cloud(np.concatenate([box, table]), np.random.default_rng(0),
                                                     options=vn_edge_cloud.CloudOptions(point_noise_m=0.0))
    assert len(points) > 100 and points[:, 2].min() >= TABLE_HEIGHT_M + 0.005  # the box above the crop, no table
    # each the mean of the unit normals in its 4.5 mm voxel, as Open3D's voxel_down_sample
    # leaves them (not re-normalised: shorter at the box's edges); the network reads them so
    norms = np.linalg.norm(normals, axis=1)
    assert np.median(norms) > 0.999 and norms.max() < 1 + 1e-6 and norms.min() < 0.99


# edges and grasps


def one_edge(apex, contact, normal):
    t = torch.tensor
    return vn_edge.sample_edges(t([apex, contact], dtype=torch.float32), t([normal, normal], dtype=torch.float32),
                                torch.tensor([0]))


def test_an_edge_over_a_box_corner_grasps_top_down_with_the_fingers_on_the_side():
    """Apex on a box's top, 5 mm from its side face (normal +x), contact 1 cm down that
    face: the hand comes straight down, closes along x, and the contact sits 0.065 m
    along the approach from the authors' frame: 7 mm short of the Panda's fingertips."""
    apex, contact = [0.165, 0.15, 0.10], [0.17, 0.15, 0.09]
    edges = one_edge(apex, contact, [1.0, 0.0, 0.0])
    row = 1  # ball 0: the apex itself (length 0), then the contact
    assert vn_edge.kept_edges(edges).tolist() == [False, True]
    np.testing.assert_allclose(edges.approach[row], [0.0, 0.0, -1.0], atol=1e-6)
    assert float(edges.depth[row]) == pytest.approx(0.01, abs=1e-6)
    pose = vn_edge.edge_poses(torch.tensor([apex]), edges.normals[[row]], edges.approach[[row]],
                              edges.depth[[row]])[0].numpy()
    np.testing.assert_allclose(pose[:3, :3], [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-6)  # x = y cross z
    tcp = vn_edge.to_tcp(pose)
    np.testing.assert_allclose(tcp[:3, 3], [0.165, 0.15, 0.10 + 0.065 - 0.01 - 0.022], atol=1e-6)
    tips_z = tcp[2, 3] - FINGER_DEPTH_M
    assert contact[2] - tips_z == pytest.approx(0.0072, abs=5e-4)


@pytest.mark.parametrize("contact, normal, why", [
    ([0.17, 0.15, 0.11], [1.0, 0.0, 0.0], "approach from below"),
    ([0.17, 0.15, 0.06], [1.0, 0.0, 0.0], "edge longer than 38 mm"),
    ([0.166, 0.15, 0.0995], [1.0, 0.0, 0.0], "edge shorter than 3 mm"),
])
def test_edges_the_authors_leave_out(contact, normal, why):
    assert not vn_edge.kept_edges(one_edge([0.165, 0.15, 0.10], contact, normal))[1], why


def test_a_hand_reaching_into_the_table_is_left_out():
    """Top-down poses: the fingertips' outer edges are 0.078 m down the approach from the
    authors' frame, and must stay 4 mm above the table."""
    down = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]], dtype=np.float64)
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, :3, :3] = down
    limit = TABLE_HEIGHT_M + 0.004 + 0.078
    poses[0, :3, 3], poses[1, :3, 3] = [0.15, 0.15, limit + 1e-3], [0.15, 0.15, limit - 1e-3]
    assert vn_edge.above_table(torch.tensor(poses)).tolist() == [True, False]


@needs_panda
def test_the_authors_grasp_frame_is_the_panda_body_frame():
    """Their T_body_tcp is the identity: the pose is PyBullet's body frame, the hand
    link's centre of mass in the URDF; the project's TCP is 0.022 m further."""
    robot = ET.parse(baselines_dir() / "panda_hand" / "hand.urdf").getroot()
    com = robot.find("link[@name='panda_hand']/inertial/origin")
    assert [float(v) for v in com.get("xyz").split()] == [0.0, 0.0, vn_edge.HAND_COM_Z_M]
    assert com.get("rpy") == "0 0 0"
    assert vn_edge.POSE_TO_TCP_M == pytest.approx(HAND_TO_TCP_M - 0.04) == pytest.approx(0.022)
    assert FINGER_TIP_Z_M - vn_edge.HAND_COM_Z_M - vn_edge.CONTACT_DEPTH_M == pytest.approx(0.0072, abs=5e-4)


# the network


@needs_vn_edge
def test_the_network_is_invariant_to_moving_the_cloud(net):
    """SE(3) invariance, the paper's claim: rotating and shifting the cloud (normals
    rotated too) leaves every edge's logit as it was. In float64: in float32 the VN
    max-pools' near-ties (relative gaps down to 1e-6) flip under the rotation's rounding
    and move some logits by up to 0.3 (vn-edge-baseline.md)."""
    net64 = copy.deepcopy(net).double()
    points, normals = box_cloud(size_m=(0.015, 0.02, 0.025))
    apexes = torch.tensor([0])  # one ball: about the whole box
    rotation = Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()
    logits = []
    for p, n in ((points, normals), (points @ rotation.T + [0.3, -0.2, 0.1], normals @ rotation.T)):
        edges = vn_edge.sample_edges(torch.tensor(p, dtype=torch.float64), torch.tensor(n, dtype=torch.float64),
                                     apexes)
        logits.append(vn_edge.score_edges(net64, edges, torch.arange(len(edges.ball))))
    assert len(logits[0]) > 80 and logits[0].std() > 0.5  # scores that differ, to compare
    torch.testing.assert_close(logits[1], logits[0], atol=1e-9, rtol=0)


@needs_vn_edge
def test_the_output_on_a_fixed_cloud(net):
    """Pinned: a 2 x 2.5 x 3 cm box cloud, 8 apexes, seed 1. The same cloud through the
    authors' network code (32 apexes) gave the same 1019 edge scores to 2.4e-7
    (vn-edge-baseline.md)."""
    points, normals = box_cloud()
    grasps = vn_edge.detect_on_cloud(net, points, normals, np.random.default_rng(1), vn_edge.EdgeOptions(apexes=8))
    assert len(grasps) == 213
    scores = [g.validness for g in grasps]
    assert scores == sorted(scores, reverse=True) and all(g.rank_key == g.validness for g in grasps)
    best = grasps[0]
    assert best.validness == pytest.approx(0.98252, abs=1e-4)
    np.testing.assert_allclose(best.pose, [[0.4066, 0.0, 0.9136, 0.1026], [0.0, -1.0, 0.0, 0.1579],
                                           [0.9136, 0.0, -0.4066, 0.0830], [0.0, 0.0, 0.0, 1.0]], atol=2e-4)
    np.testing.assert_allclose(best.contact_m, [0.14189, 0.13665, 0.06547], atol=1e-4)


# the detector


@needs_vn_edge
def test_the_published_network_grasps_a_rendered_box(net):
    """The benchmark's view of a 2 x 2.5 x 4 cm box through the whole detector: the best
    grasp's contact is on the box, its fingertips reach the box from above the table, and
    the hand approaches from above or the side (never from below)."""
    meshes, (lo, hi) = box_on_table(size_m=(0.02, 0.025, 0.04))
    depth, k, T = benchmark_view(meshes)
    volume = vn_edge_cloud.edge_volume()
    volume.integrate(depth, k, T)
    grasps = vn_edge.make_vn_edge_detector(net, vn_edge.EdgeOptions(apexes=16))(
        (volume.grid(), volume.voxel_size_m, volume.origin))
    assert grasps, "VN-EdgeGraspNet found no grasp on a box"
    best = grasps[0]
    assert np.all(best.contact_m > lo - 0.003) and np.all(best.contact_m < hi + 0.003)
    tips = best.pose[:3, 3] + FINGER_DEPTH_M * best.pose[:3, 2]
    assert np.all(tips[:2] > lo[:2] - 0.01) and np.all(tips[:2] < hi[:2] + 0.01) and tips[2] > TABLE_HEIGHT_M
    assert best.pose[2, 2] < 0.1 and best.validness > 0.5
    assert best.voxel_index == tuple(int(i) for i in np.floor(best.pose[:3, 3] / volume.voxel_size_m))


def test_with_clear_hand_only_grasps_whose_open_hand_clears_the_view_are_kept():
    """clearing_grasps, the protocol's --clear-hand: a grasp whose Panda hand would sweep
    through an occupied block is dropped, the next ones kept, best first, up to the
    protocol's number."""
    grid = np.zeros((40, 40, 40), np.float32)
    grid[18:22, 18:22, 8:12] = 0.3  # observed inside: occupied
    down = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]], dtype=np.float64)

    def top_down(x, y, z):
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = down, [x, y, z]
        return vn_edge.VNEdgeGrasp(pose=pose, score_n=float("nan"), validness=0.9, voxel_index=(),
                                   contact_m=np.zeros(3))

    into_block = top_down(0.15, 0.15, 0.08)  # the palm inside the block
    free = [top_down(0.05, 0.05 + 0.04 * i, 0.10) for i in range(3)]
    tsdf = (grid, 0.0075, np.zeros(3))
    assert vn_edge.clearing_grasps([into_block, *free], tsdf, 2) == free[:2]
    assert vn_edge.clearing_grasps([into_block], tsdf, 2) == []


def test_vn_edge_is_a_benchmark_method_on_the_panda_hand():
    m = methods.method_named("vn_edge")
    assert (m.hand, m.where, m.make) == ("panda", methods.BASELINES, vn_edge.make_detector)
    assert m.default_path(baselines_dir="/b") == pathlib.Path("/b/vn_edge_grasp/classifier_model-ckpt-105.pt")
    assert sorted(pathlib.PurePosixPath(f).name for f in (m.file, *m.companions)) == \
        sorted(pathlib.PurePosixPath(f).name for f in VN_EDGE_FILES)


@needs_vn_edge
def test_a_missing_vn_edge_checkpoint_is_skipped_with_one_sentence(tmp_path):
    (tmp_path / "vn_edge_grasp").mkdir()
    for f in VN_EDGE_FILES[:3]:  # all but std
        (tmp_path / f).symlink_to(baselines_dir() / f)
    notes = []
    assert bench_rounds.resolve_methods(["vn_edge"], tmp_path, baselines_dir=tmp_path, note=notes.append) == {}
    (note,) = notes
    assert note.startswith("benchmark: skipping vn_edge: ") and "\n" not in note
    assert "std-ckpt-105.pt not found beside classifier_model-ckpt-105.pt" in note and "Edge-Grasp-Network" in note


@needs_vn_edge
def test_the_benchmark_makes_vn_edge_a_detector_reading_its_own_volume():
    detector = vn_edge.make_detector(methods.method_named("vn_edge").locate(), protocol.Protocol())
    assert detector.target == "binary"
    assert (detector.volume.resolution, detector.volume.size_m, detector.volume.truncation_voxels) == (180, 0.30, 4)
    assert detector.detect((np.zeros((180, 180, 180), np.float32), 0.30 / 180, np.zeros(3))) == []  # nothing seen
