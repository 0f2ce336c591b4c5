"""The detect node's score_model_path (issue 42's "Binary places, Ours ranks"): one model's
grasps ranked by another's score, over real DDS; a score model that cannot rank refuses
to start with one line."""
import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import detection, model_file, networks
from gravgrasp_detector.perception.tsdf import TSDFVolume
from gravgrasp_detector.ros.tsdf_node import VOLUME_QOS

import ros_testing


def save(path, target, seed, resolution=40):
    torch.manual_seed(seed)
    model_file.save_model(path, networks.GraspNet(resolution=resolution, score_scale_n=10.0),
                          TSDFVolume(resolution=resolution), training_data={"target": target})
    return path


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("models")
    return save(d / "binary.pt", "binary", 0), save(d / "score.pt", "gravity-score", 1)


def table_grid():
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7
    return grid


def test_grasps_of_one_model_ranked_by_anothers_score(ros_node, ros_process, models):
    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg

    binary, score = models
    detect = ros_process("gravgrasp_detector", "detect", params={
        "model_path": str(binary), "score_model_path": str(score), "validness_threshold": 0.49, "precision": "fp32"})
    pub = ros_node.create_publisher(TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    got = []
    ros_node.create_subscription(GraspArray, "/grasps", got.append, 10)
    assert ros_testing.wait_for_subscriber(ros_node, "/tsdf", 30)
    grid = table_grid()
    msg = TSDFVolumeMsg(resolution=40, voxel_size_m=0.0075, truncation_m=0.03)
    msg.header.frame_id = "task"
    msg.origin.orientation.w = 1.0
    msg.tsdf, msg.weights = grid.ravel(), (grid > 0).astype(np.float32).ravel()
    pub.publish(msg)
    assert ros_testing.spin_until(ros_node, lambda: any(len(g.grasps) for g in got), 30), detect.output()[-2000:]
    published = next(g for g in got if len(g.grasps)).grasps

    # the same detection in this process: the binary model places, the score model ranks
    placing, _ = model_file.load_model(binary)
    scorer, _ = model_file.load_model(score)
    options = detection.DetectionOptions(validness_threshold=0.49, max_grasps=20, surface_distance_voxels=6,
                                         nms_radius_voxels=2, precision="fp32", rank_by="score", has_score=True)
    expected = detection.detect_grasps(placing, grid, 0.0075, np.eye(4), options, score_model=scorer)
    scores = [g.gravity_rejection_score for g in published]
    assert all(np.isfinite(scores)), "a binary model's own grasps carry NaN: the score model's did not arrive"
    assert scores == sorted(scores, reverse=True)
    assert [list(g.voxel_index) for g in published] == [list(g.voxel_index) for g in expected]
    np.testing.assert_allclose(scores, [g.score_n for g in expected], rtol=1e-5)
    assert all(g.validness >= 0.49 for g in published)
    assert "ranked by the score in N of" in detect.output()


@pytest.mark.parametrize("problem", ["binary", "other_grid"])
def test_a_score_model_that_cannot_rank_exits_with_one_line(ros_process, tmp_path, models, problem):
    binary, _ = models
    bad = save(tmp_path / "bad.pt", "binary", 2) if problem == "binary" else save(
        tmp_path / "bad.pt", "gravity-score", 2, resolution=32)
    detect = ros_process("gravgrasp_detector", "detect", params={"model_path": str(binary),
                                                                 "score_model_path": str(bad)})
    assert detect.wait_exit(60) == 2
    lines = [line for line in detect.output().splitlines() if line.strip()]
    assert len(lines) == 1, lines
    expected = {"binary": "was trained with --target binary: it has no gravity-rejection score",
                "other_grid": "reads another TSDF than the model that places the grasps: resolution 32"}[problem]
    assert "cannot start: score model" in lines[0] and expected in lines[0], lines[0]
