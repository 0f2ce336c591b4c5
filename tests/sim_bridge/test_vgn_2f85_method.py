"""VGN's grasps executed by the 2F-85 (sim_bridge.benchmark.methods.vgn_2f85): the frame
conversion keeps the finger tips where the Panda's were, every VGN width fits the 2F-85,
and the registered method is VGN's detector with each grasp converted and, with
clear_hand, checked with the 2F-85's own hand. A VGN-shaped weights file made here
(its quality bias high, so every voxel near free space is a grasp) stands in for the
published one, which the test does not need."""

import dataclasses

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from gravgrasp_detector.perception import hand_clearance
from gravgrasp_detector.execution.executor import ExecutionLimits
from robotiq_driver import hand_geometry
from sim_bridge.benchmark import methods, sim_cell
from sim_bridge.benchmark.methods import vgn, vgn_2f85
from sim_bridge.benchmark.protocol import Protocol
from sim_bridge.physics import panda_hand


def open_tips_task(pose, tip_z_m):
    """The two open finger tips' centres in the task frame: on the closing axis y at
    +-half the opening, `tip_z_m` along the approach."""
    return [(pose @ np.array([0.0, side, tip_z_m, 1.0]))[:3] for side in (-1.0, 1.0)]


def a_vgn_grasp(seed=0):
    rng = np.random.default_rng(seed)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    pose[:3, 3] = rng.uniform(0.0, 0.3, 3)
    return vgn.VGNGrasp(pose=pose, score_n=float("nan"), validness=0.93, rank_key=0.93, voxel_index=(3, 4, 5),
                        width_m=0.04)


@pytest.mark.parametrize("seed", range(5))
def test_the_converted_grasp_puts_the_2f85s_finger_tips_where_the_pandas_were(seed):
    grasp = a_vgn_grasp(seed)
    converted = vgn_2f85.to_2f85(grasp)
    # the tips' depth along the approach: the Panda's at FINGER_DEPTH_M past VGN's TCP,
    # the 2F-85's at FINGER_TIP_Z_M past its own
    panda_tip = grasp.pose @ np.array([0.0, 0.0, panda_hand.FINGER_DEPTH_M, 1.0])
    f2f85_tip = converted.pose @ np.array([0.0, 0.0, hand_geometry.FINGER_TIP_Z_M, 1.0])
    np.testing.assert_allclose(f2f85_tip, panda_tip, atol=1e-12)
    np.testing.assert_allclose(converted.pose[:3, :3], grasp.pose[:3, :3])  # same approach and closing axes
    # the 2F-85's TCP moved 45.8 mm towards the object, along the approach
    np.testing.assert_allclose(converted.pose[:3, 3] - grasp.pose[:3, 3], 0.0458 * grasp.pose[:3, 2], atol=1e-4)
    assert (converted.validness, converted.rank_key, converted.voxel_index, converted.width_m) == (
        grasp.validness, grasp.rank_key, grasp.voxel_index, grasp.width_m)
    assert not np.shares_memory(converted.pose, grasp.pose)
    np.testing.assert_array_equal(grasp.pose, a_vgn_grasp(seed).pose)  # the original is left as it was


def test_the_pandas_pad_lies_within_the_2f85s_and_its_palm_further_back():
    """The justification of the tip rule, from both hands' geometry (vgn_2f85's doc)."""
    shift_m = vgn_2f85.TIP_DEPTH_SHIFT_M
    finger_base_z_m = panda_hand.FINGER_JOINT_Z_M - panda_hand.HAND_TO_TCP_M
    panda_pad_z_m = [finger_base_z_m + z - shift_m for z in panda_hand.PAD_Z_M]  # in the 2F-85's TCP frame
    f2f85_pad_z_m = (hand_geometry.FINGER_TIP_Z_M - hand_geometry.PAD_LENGTH_M, hand_geometry.FINGER_TIP_Z_M)
    assert f2f85_pad_z_m[0] <= panda_pad_z_m[0] < panda_pad_z_m[1] <= f2f85_pad_z_m[1] + 1e-12
    panda_palm_z_m = panda_hand.PALM_FACE_Z_M - panda_hand.HAND_TO_TCP_M - shift_m
    assert hand_geometry.PALM_FACE_Z_M < panda_palm_z_m  # deeper insertion never hits the 2F-85's palm


def test_every_width_vgn_keeps_fits_the_2f85():
    options = vgn.VGNOptions()
    assert options.max_width_voxels * vgn.VOXEL_SIZE_M <= min(hand_geometry.MAX_STROKE_M, panda_hand.MAX_OPENING_M)
    assert sim_cell.HAND_GEOMETRY["2f85"].open_width_m == pytest.approx(hand_geometry.MAX_STROKE_M)


def test_the_registered_method_is_vgns_file_on_the_2f85():
    m = methods.METHODS["vgn_2f85"]
    assert m.hand == "2f85" and m.file == methods.METHODS["vgn"].file and m.where == methods.METHODS["vgn"].where
    assert m.make is vgn_2f85.make_detector
    assert "vgn_2f85" not in methods.DEFAULT_METHODS  # a baseline: run when named


# the detector, from a VGN-shaped weights file


R_TOP_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # x = y cross z


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory):
    torch.manual_seed(0)
    net = vgn.VGNNet()
    with torch.no_grad():
        net.conv_qual.bias.fill_(12.0)  # quality ~1 everywhere: the mask decides where grasps are
        net.conv_width.weight.zero_()
        net.conv_width.bias.fill_(4.0)  # 30 mm: in range
        net.conv_rot.weight.zero_()  # every grasp top-down, closing along task x
        net.conv_rot.bias.copy_(torch.as_tensor(Rotation.from_matrix(R_TOP_DOWN).as_quat(), dtype=torch.float32))
    path = tmp_path_factory.mktemp("vgn") / "vgn_conv.pth"
    torch.save(net.state_dict(), path)
    return path


def table_view():
    """Observed inside (0.3) at k = 5, 6 under observed free space (0.7) at k = 7..9, and a
    block of inside (an object) at i, j 15..24 up to k = 14 with free space around it."""
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 5:7], grid[:, :, 7:10] = 0.3, 0.7
    grid[15:25, 15:25, 7:15] = 0.3
    grid[13:27, 13:27, 15:17] = 0.7
    return grid, vgn.VOXEL_SIZE_M, np.array([0.0, 0.0, 0.0])


@pytest.mark.parametrize("clear_hand", [False, True])
def test_the_detector_is_vgns_with_every_grasp_converted(weights_file, clear_hand):
    protocol = dataclasses.replace(Protocol(), clear_hand=clear_hand)
    panda, f2f85 = vgn.make_detector(weights_file, dataclasses.replace(protocol, clear_hand=False, max_grasps=10**6)), \
        vgn_2f85.make_detector(weights_file, protocol)
    assert f2f85.target == "binary" and f2f85.volume.resolution == vgn.RESOLUTION
    tsdf = table_view()
    vgn_grasps, grasps = panda.detect(tsdf), f2f85.detect(tsdf)
    assert len(vgn_grasps) > protocol.max_grasps  # enough for the selection to matter
    expected = [vgn_2f85.to_2f85(g) for g in vgn_grasps]
    if clear_hand:  # the 2F-85's own open hand, swept from the pre-grasp, against the view
        points = hand_clearance.occupied_points(tsdf[0], tsdf[1], tsdf[2])
        hit = hand_clearance.hands_collide(np.array([g.pose for g in expected]), points, tsdf[1],
                                           ExecutionLimits.pregrasp_distance_m, sim_cell.HAND_GEOMETRY["2f85"])
        assert hit.any() and not hit.all()  # the check keeps some and drops some
        expected = [g for g, h in zip(expected, hit) if not h]
    expected = expected[:protocol.max_grasps]
    assert len(grasps) == len(expected) > 0
    for g, e in zip(grasps, expected):
        np.testing.assert_allclose(g.pose, e.pose)
        assert (g.validness, g.voxel_index) == (e.validness, e.voxel_index)
