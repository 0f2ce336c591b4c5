"""Grasp extraction on hand-made volumes, and the network path that feeds it."""
import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from gravgrasp_detector.execution import executor as grasp_execution
from gravgrasp_detector.perception import detection, hand_clearance, networks, rotation
from gravgrasp_detector.perception.tsdf import InputError

from tabletop_grid import R, VS, table_grid  # noqa: F401  (tests/support)


def top_down_channels(index):
    """Rotation channels (ex-ez) for a top-down grasp: approach -z, fingers close along y."""
    n = len(index)
    return torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, -1.0]).repeat(n, 1)


def hand_made_outputs():
    score = torch.zeros(R, R, R)
    validness = torch.ones(R, R, R)
    peaks = {(10, 10, 8): 5.0, (20, 20, 8): 9.0, (30, 12, 9): 2.0, (30, 30, 8): 12.0, (5, 35, 30): 20.0}
    for index, value in peaks.items():
        score[index] = value
    score[21, 20, 8] = 8.0  # next to the 9 N peak: suppressed by NMS
    score[20, 25, 8] = 7.0  # 5 voxels away: a peak of its own
    validness[30, 30, 8] = 0.2  # best score but not a valid grasp
    # (5, 35, 30) is far above the table: outside the near-surface mask.
    return score, validness


def select(origin=(0.0, 0.0, 0.0), **options):
    """Steps 1-4 on the bare table (step 5, something between the fingers, has its own test)."""
    score, validness = hand_made_outputs()
    options = detection.DetectionOptions(**{"min_surface_voxels": 0, **options})
    return detection.select_grasps(table_grid(), score, validness, top_down_channels, "ex-ez", VS, origin, options)


def test_hand_made_volume_gives_expected_grasps_in_order():
    grasps = select()
    assert [g.voxel_index for g in grasps] == [(20, 20, 8), (20, 25, 8), (10, 10, 8), (30, 12, 9)]
    assert [g.score_n for g in grasps] == [9.0, 7.0, 5.0, 2.0]
    assert [g.rank_key for g in grasps] == [9.0, 7.0, 5.0, 2.0]  # ranked by the score in N
    expected_R = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    for g in grasps:
        np.testing.assert_allclose(g.pose[:3, :3], expected_R, atol=1e-7)
        np.testing.assert_allclose(g.pose[:3, 3], (np.array(g.voxel_index) + 0.5) * VS)
        np.testing.assert_array_equal(g.pose[3], [0, 0, 0, 1])
        assert g.validness == 1.0


def test_min_score_max_grasps_and_threshold():
    assert [g.score_n for g in select(min_score_n=5.0)] == [9.0, 7.0, 5.0]
    assert [g.score_n for g in select(max_grasps=2)] == [9.0, 7.0]
    # Threshold below the invalid peak's validness lets the 12 N grasp through and it
    # suppresses nothing else (its neighbours are empty).
    assert [g.score_n for g in select(validness_threshold=0.1)] == [12.0, 9.0, 7.0, 5.0, 2.0]
    # Without NMS the 8 N neighbour of the 9 N peak survives.
    assert 8.0 in [g.score_n for g in select(nms_radius_voxels=0)]
    # A wider surface distance admits the far peak.
    assert select(surface_distance_voxels=30)[0].score_n == 20.0


@pytest.mark.parametrize("radius", [0, 1, 2, 3, 5, 6, 45])
def test_cube_max_equals_max_filter(radius):
    volume = torch.rand(R, R, R) - 0.5
    expected = ndimage.maximum_filter(volume.numpy(), size=2 * radius + 1, mode="constant", cval=-np.inf)
    np.testing.assert_array_equal(detection.cube_max(volume, radius).numpy(), expected)


@pytest.mark.parametrize("radius", [0, 1, 2, 3, 6, 45])
def test_cube_max_of_a_mask_is_dilation(radius):
    mask = torch.rand(R, R, R) > 0.995
    expected = ndimage.binary_dilation(mask.numpy(), structure=np.ones((3, 3, 3)), iterations=radius) if radius else mask.numpy()
    np.testing.assert_array_equal(detection.cube_max(mask, radius).numpy(), expected)


def test_origin_transform_moves_poses():
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # grid turned 90 deg about z
    T[:3, 3] = (0.5, -0.2, 0.1)
    moved = select(origin=T)
    plain = select()
    for a, b in zip(moved, plain):
        np.testing.assert_allclose(a.pose, T @ b.pose, atol=1e-12)
    shifted = select(origin=np.array([0.5, -0.2, 0.1]))
    np.testing.assert_allclose(shifted[0].pose[:3, 3], plain[0].pose[:3, 3] + [0.5, -0.2, 0.1])


def test_a_grasp_with_nothing_between_the_fingers_is_not_published():
    grid = table_grid().numpy().copy()
    grid[19:22, 19:22, 7:13] = 0.3        # a 22 mm post on the table, 45 mm tall
    score, validness = torch.zeros(R, R, R), torch.ones(R, R, R)
    score[20, 20, 10] = 9.0                # on the post
    score[10, 10, 8] = 12.0                # over the bare table: the fingers close on nothing
    score[20, 27, 10] = 11.0               # 45 mm from the post along the closing axis (y)
    score[27, 20, 10] = 10.0               # 52 mm from it across the pads (x)
    score[20, 25, 10] = 8.0                # 30 mm along y: the post is between the open fingers
    grasps = detection.select_grasps(torch.from_numpy(grid), score, validness, top_down_channels, "ex-ez", VS,
                                     options=detection.DetectionOptions(nms_radius_voxels=0))
    assert [g.voxel_index for g in grasps] == [(20, 20, 10), (20, 25, 10)]
    # the veto is what removed the others
    everything = detection.select_grasps(torch.from_numpy(grid), score, validness, top_down_channels, "ex-ez", VS,
                                         options=detection.DetectionOptions(nms_radius_voxels=0, min_surface_voxels=0))
    assert len(everything) == 5
    counts = detection.surface_voxels_in_closing_region(grid, np.array([g.pose for g in everything]), VS)
    assert [int(c > 0) for c in counts] == [0, 0, 0, 1, 1]   # 12, 11, 10 N vetoed; 9 and 8 N kept


def test_nothing_valid_gives_no_grasps():
    score, validness = hand_made_outputs()
    assert detection.select_grasps(table_grid(), score, validness * 0, top_down_channels, "ex-ez", VS) == []


@pytest.mark.parametrize("representation", list(rotation.CHANNELS))
def test_rotation_at_equals_dense_head(representation):
    torch.manual_seed(0)
    net = networks.GraspNet(representation).eval()
    x = torch.rand(1, 1, R, R, R)
    index = torch.tensor([[0, 0, 0], [39, 39, 39], [0, 39, 17], [20, 3, 38], [11, 22, 33]])
    with torch.inference_mode():
        f = net.features(x)
        dense = net.rotation_channels(f)[0][:, index[:, 0], index[:, 1], index[:, 2]].T
        torch.testing.assert_close(net.rotation_at(f, index), dense, atol=1e-5, rtol=1e-4)


def test_polyphase_head_on_half_features_equals_dense_head():
    torch.manual_seed(0)
    net = networks.GraspNet(score_scale_n=3.0).eval()
    x = torch.rand(1, 1, R, R, R)
    with torch.inference_mode():
        dense_score, dense_logit = net.score_and_validness(net.features(x))
        half = net.half_features(x)
        score, logit = net.score_and_validness_from_half(half)
        index = torch.tensor([[0, 0, 0], [39, 39, 39], [7, 30, 2], [1, 38, 20]])
        rot_half = net.rotation_at(half, index, half=True)
        rot_full = net.rotation_at(net.features(x), index)
    torch.testing.assert_close(score, dense_score, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(logit, dense_logit, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(rot_half, rot_full, atol=1e-5, rtol=1e-4)


def test_polyphase_dec3_at_inference_equals_the_conv_on_the_upsampled_grid():
    """Inference runs dec3 (5^3 on a nearest 2x upsampling) as a 3^3 polyphase conv on
    the coarse grid; training runs the plain conv. Same features, in both layouts."""
    torch.manual_seed(2)
    net = networks.GraspNet().eval()
    x = torch.rand(1, 1, R, R, R)
    with torch.enable_grad():
        plain = net.half_features(x).detach()
    for layout in (torch.contiguous_format, torch.channels_last_3d):
        net.to(memory_format=layout)
        with torch.inference_mode():
            fast = net.half_features(x.contiguous(memory_format=layout))
        torch.testing.assert_close(fast, plain, atol=1e-5, rtol=1e-4)
    # the cached polyphase weights follow a weight update
    with torch.no_grad():
        net.dec3.weight.mul_(2.0)
    with torch.enable_grad():
        plain = net.half_features(x).detach()
    with torch.inference_mode():
        torch.testing.assert_close(net.half_features(x), plain, atol=1e-5, rtol=1e-4)


def test_detect_grasps_fp32_matches_dense_forward():
    torch.manual_seed(1)
    net = networks.GraspNet("ex-ez").eval()
    grid = table_grid()
    options = detection.DetectionOptions(validness_threshold=0.5, max_grasps=30, precision="fp32")
    grasps = detection.detect_grasps(net, grid.numpy(), VS, options=options)
    with torch.inference_mode():
        out = net(grid[None, None])
    validness = torch.sigmoid(out["validness_logit"][0])
    rot = out["rotation"][0]
    reference = detection.select_grasps(
        grid, out["score_n"][0], validness, lambda i: rot[:, i[:, 0], i[:, 1], i[:, 2]].T, "ex-ez", VS,
        options=options,
    )
    assert len(grasps) == len(reference) > 0
    for a, b in zip(grasps, reference):
        assert a.voxel_index == b.voxel_index
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-5)
    scores = [g.score_n for g in grasps]
    assert scores == sorted(scores, reverse=True) and min(scores) >= 0
    assert all(g.validness >= 0.5 for g in grasps)
    for g in grasps:
        np.testing.assert_allclose(g.pose[:3, :3].T @ g.pose[:3, :3], np.eye(3), atol=1e-5)
        assert np.linalg.det(g.pose[:3, :3]) == pytest.approx(1.0, abs=1e-5)
        assert ((0 <= g.pose[:3, 3]) & (g.pose[:3, 3] <= R * VS)).all()


def test_float32_inference_convolutions_match_autograd_path():
    """Without grad, float32 convs go straight to oneDNN; same numbers as F.conv3d."""
    torch.manual_seed(2)
    net = networks.GraspNet().eval()
    x = torch.rand(1, 1, R, R, R)
    with torch.no_grad():
        fast = net.half_features(x)
    reference = net.half_features(x).detach()  # grad enabled: plain F.conv3d
    torch.testing.assert_close(fast, reference, atol=1e-6, rtol=1e-5)
    net.to(memory_format=torch.channels_last_3d)
    with torch.no_grad():
        fast_cl = net.half_features(x.contiguous(memory_format=torch.channels_last_3d))
    torch.testing.assert_close(fast_cl, reference, atol=1e-6, rtol=1e-5)


def test_detect_grasps_bf16_path_runs_and_ranks():
    torch.manual_seed(1)
    net = networks.GraspNet("ex-ez").eval()
    grasps = detection.detect_grasps(net, table_grid().numpy(), VS,
                                     options=detection.DetectionOptions(precision="bf16", max_grasps=10))
    scores = [g.score_n for g in grasps]
    assert scores == sorted(scores, reverse=True)
    assert net.enc1.weight.is_contiguous(memory_format=torch.channels_last_3d)


@pytest.mark.parametrize("native, amx, expected", [(True, True, "bf16"), (True, False, "fp32"),
                                                    (False, False, "fp32")])
def test_auto_precision_is_bf16_only_where_the_cpu_has_amx(monkeypatch, native, amx, expected):
    """AVX-512 BF16 without AMX ran detection slower in bf16 than in fp32: 'auto' keeps fp32 there."""
    monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda: native)
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx, raising=False)
    assert detection.resolve_precision("auto") == expected
    assert detection.resolve_precision("bf16") == "bf16"  # asked for explicitly, it is used


@pytest.mark.parametrize(
    "grid, cause, words",
    [
        (np.zeros((32, 32, 32), np.float32), "grid_shape", "the model expects (40, 40, 40)"),
        (np.full((R, R, R), np.nan, np.float32), "grid_values", "NaN or inf"),
        (np.zeros((R, R, R), np.float32), "empty_tsdf", "no observed surface"),
    ],
)
def test_bad_grids_raise_one_clear_error(grid, cause, words):
    with pytest.raises(InputError) as e:
        detection.detect_grasps(networks.GraspNet().eval(), grid, VS)
    assert e.value.cause == cause and words in str(e.value)


def test_validness_ranking_for_a_binary_model():
    """rank_by="validness" (a --target binary model): ranked by validness, min_score_n in N
    does not apply; a binary model's grasps carry score_n NaN (its score head is untrained,
    and score_n is newtons, never a probability) and rank_key = validness. A score model
    ranked by validness gives the same grasps, each with its score in N, and applies
    min_score_n (a known payload's floor) before ranking by validness."""
    torch.manual_seed(0)
    net = networks.GraspNet().eval()
    grid = table_grid().numpy()
    options = detection.DetectionOptions(validness_threshold=0.0, min_score_n=1e6, max_grasps=10)
    by_score = detection.detect_grasps(net, grid, VS, options=options)
    binary = dataclasses.replace(options, rank_by="validness", has_score=False)
    by_validness = detection.detect_grasps(net, grid, VS, options=binary)
    assert not by_score and by_validness  # no grasp holds 1e6 N; probabilities ignore it
    assert [g.validness for g in by_validness] == sorted((g.validness for g in by_validness), reverse=True)
    assert all(math.isnan(g.score_n) and g.rank_key == g.validness for g in by_validness)
    scored = dataclasses.replace(binary, has_score=True, min_score_n=0.0)
    by_validness_n = detection.detect_grasps(net, grid, VS, options=scored)
    assert [g.voxel_index for g in by_validness_n] == [g.voxel_index for g in by_validness]
    with torch.inference_mode():
        score_n = net.score_and_validness_from_half(net.half_features(torch.from_numpy(grid)[None, None]))[0][0]
    assert [g.score_n for g in by_validness_n] == pytest.approx(
        [float(score_n[g.voxel_index]) for g in by_validness_n], abs=1e-5)
    assert all(g.rank_key == g.validness for g in by_validness_n)
    assert not detection.detect_grasps(net, grid, VS, options=dataclasses.replace(scored, min_score_n=1e6))
    floor_n = float(np.median([g.score_n for g in by_validness_n]))  # some grasps above it, some below
    payload = detection.detect_grasps(net, grid, VS, options=dataclasses.replace(scored, min_score_n=floor_n))
    assert payload and all(g.score_n >= floor_n for g in payload)
    assert [g.validness for g in payload] == sorted((g.validness for g in payload), reverse=True)
    assert {g.voxel_index for g in payload} != {g.voxel_index for g in by_validness_n}
    assert detection.payload_min_score_n(1.5) == pytest.approx(1.5 * 9.81 * detection.PAYLOAD_SAFETY_FACTOR)
    for mass_kg, factor in ((-1.0, 1.5), (math.nan, 1.5), (1.0, 0.5)):
        with pytest.raises(ValueError, match="give a mass >= 0 kg and a factor >= 1"):
            detection.payload_min_score_n(mass_kg, factor)
    with pytest.raises(ValueError, match="rank_by"):
        detection.DetectionOptions(rank_by="probability")
    with pytest.raises(ValueError, match="has_score is False"):
        detection.DetectionOptions(rank_by="score", has_score=False)
    with pytest.raises(ValueError, match="precision"):
        detection.DetectionOptions(precision="fp16")


def test_a_model_without_a_score_is_selected_and_ranked_by_validness_alone():
    """score_n None (a binary model): candidates and order come from validness only (min_score_n
    in N does not apply), every grasp carries score_n NaN and rank_key = its validness. A NaN
    score is refused, not let drop (or keep) every voxel."""
    _, validness = hand_made_outputs()
    validness[:] = 0.1
    for index, v in {(10, 10, 8): 0.9, (30, 12, 9): 0.8, (20, 20, 8): 0.6, (5, 35, 30): 0.99}.items():
        validness[index] = v
    options = detection.DetectionOptions(min_surface_voxels=0, rank_by="validness", has_score=False, min_score_n=50.0)
    grasps = detection.select_grasps(table_grid(), None, validness, top_down_channels, "ex-ez", VS, options=options)
    assert [g.voxel_index for g in grasps] == [(10, 10, 8), (30, 12, 9), (20, 20, 8)]  # (5, 35, 30): off the surface
    assert [g.rank_key for g in grasps] == pytest.approx([0.9, 0.8, 0.6])
    assert [g.validness for g in grasps] == pytest.approx([0.9, 0.8, 0.6])
    assert all(math.isnan(g.score_n) for g in grasps)
    with pytest.raises(ValueError, match="score_n has NaN"):
        detection.select_grasps(table_grid(), torch.full((R, R, R), math.nan), validness, top_down_channels,
                                "ex-ez", VS, options=options)
    with pytest.raises(ValueError, match="needs a gravity-rejection score"):
        detection.select_grasps(table_grid(), None, validness, top_down_channels, "ex-ez", VS)


def test_a_callers_rank_key_ranks_and_suppresses_and_each_grasp_keeps_its_score():
    """rank_key (a study's ranking, here validness x score): ranked (and suppressed) by the
    key; each grasp still publishes its score in N."""
    score, validness = hand_made_outputs()
    validness[20, 20, 8] = 0.55  # 9 N, barely valid: 4.95 expected
    validness[10, 10, 8] = 0.95  # 5 N, sure: 4.75 expected
    validness[20, 25, 8] = 0.6  # 7 N: 4.2 expected
    validness[21, 20, 8] = 0.5  # 8 N beside the 9 N peak: 4.0, suppressed by it
    options = detection.DetectionOptions(min_surface_voxels=0, validness_threshold=0.5)
    by_score = detection.select_grasps(table_grid(), score, validness, top_down_channels, "ex-ez", VS, options=options)
    assert [g.score_n for g in by_score] == [9.0, 7.0, 5.0, 2.0]
    expected = validness * score
    by_expected = detection.select_grasps(table_grid(), score, validness, top_down_channels, "ex-ez", VS,
                                          options=options, rank_key=expected)
    assert [g.voxel_index for g in by_expected] == [(20, 20, 8), (10, 10, 8), (20, 25, 8), (30, 12, 9)]
    assert [g.score_n for g in by_expected] == [9.0, 5.0, 7.0, 2.0]
    assert [g.rank_key for g in by_expected] == pytest.approx([4.95, 4.75, 4.2, 2.0])
    # the 8 N neighbour of the 9 N peak, made sure, outranks it and suppresses it (NMS on the key)
    validness[21, 20, 8] = 1.0
    by_expected = detection.select_grasps(table_grid(), score, validness, top_down_channels, "ex-ez", VS,
                                          options=options, rank_key=validness * score)
    assert by_expected[0].voxel_index == (21, 20, 8) and (20, 20, 8) not in [g.voxel_index for g in by_expected]


def test_hands_collide_agrees_with_the_executors_check():
    # step 6 decides with hands_collide, the executor with first_collision: on a table with
    # a box, random grasps near it must get the same verdict from both
    grid = table_grid().numpy().copy()
    grid[16:24, 16:24, 7:15] = 0.3  # a 6 cm box on the table
    tsdf = (grid, VS, np.zeros(3))
    points = hand_clearance.occupied_points(grid, VS)
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(300):
        axis = rng.normal(size=3)
        angle = rng.uniform(0, 0.8)
        K = np.cross(np.eye(3), axis / np.linalg.norm(axis))
        R_tilt = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
        X = np.eye(4)
        X[:3, :3] = R_tilt @ np.diag([1.0, -1.0, -1.0])
        X[:3, 3] = rng.uniform([0.09, 0.09, 0.05], [0.2, 0.2, 0.15])
        poses.append(X)
    hit = hand_clearance.hands_collide(np.array(poses), points, VS, 0.05)
    expected = [bool(hand_clearance.first_collision(grasp_execution.plan_poses(X, 0.05, 0.1), tsdf)) for X in poses]
    assert hit.tolist() == expected
    assert 30 < hit.sum() < 270  # both verdicts occur
