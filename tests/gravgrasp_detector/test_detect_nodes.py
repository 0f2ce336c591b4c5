"""The tsdf and detect nodes as real processes over loopback DDS, fed by the committed bag."""
import pathlib

import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import model_file, networks
from gravgrasp_detector.perception.tsdf import TSDFVolume
from gravgrasp_detector.ros.bag_replay import BagPlayer, read_bag
from gravgrasp_detector.ros.tsdf_node import VOLUME_QOS

import ros_testing

BAG = pathlib.Path(__file__).resolve().parents[1] / "data" / "tabletop_bag"
THRESHOLD = 0.49
REMAP = {
    "depth/image": "/camera/depth/image",
    "depth/camera_info": "/camera/depth/camera_info",
    "camera_pose": "/camera/pose",
}


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """A model file of a freshly initialised (untrained) network, until a trained one exists."""
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "untrained.pt"
    model_file.save_model(path, networks.GraspNet("ex-ez"), TSDFVolume(),
                          training_data={"note": "freshly initialised, untrained (test fixture)"})
    return path


def collect(node, msg_type, topic, qos=10):
    received = []
    node.create_subscription(msg_type, topic, received.append, qos)
    return received


def test_bag_replay_through_tsdf_and_detect(ros_node, ros_process, model_path):
    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
    from visualization_msgs.msg import MarkerArray

    # The bag is replayed reliably; best-effort 1 MB images (the default sensor-data QoS)
    # are lost when other processes keep this small CPU busy, so ask for reliable
    # delivery with the standard QoS override parameters.
    # Right after discovery a reliable sample can wait for a heartbeat round (~seconds
    # here), so images may wait longer than the default 1 s for their CameraInfo.
    overrides = {f"qos_overrides.{topic}.subscription.reliability": "reliable" for topic in REMAP.values()}
    tsdf = ros_process("gravgrasp_detector", "tsdf", remap=REMAP,
                       params={"publish_rate_hz": 20.0, "sync_timeout_s": 10.0, **overrides})
    # An untrained net predicts validness ~0.497 everywhere: threshold just below it.
    detect = ros_process("gravgrasp_detector", "detect",
                         params={"model_path": str(model_path), "validness_threshold": THRESHOLD})
    volumes = collect(ros_node, TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    grasps = collect(ros_node, GraspArray, "/grasps")
    markers = collect(ros_node, MarkerArray, "/grasp_markers")
    detect.wait_for_output(r"model: .*untrained\.pt", timeout_s=30)

    player = BagPlayer(ros_node, BAG)
    assert player.wait_for_subscribers(list(REMAP.values()), timeout_s=20), "tsdf node did not subscribe"
    assert ros_testing.wait_for_publisher(ros_node, "/grasps")
    last_stamp = max(t for _, _, t in read_bag(BAG))

    def stamp_ns(msg):
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def last_frame_detected():
        return any(stamp_ns(g) == last_stamp for g in grasps)

    player.play(rate=1.0)  # recorded timing: 5 Hz, as from the camera
    ros_testing.spin_until(ros_node, last_frame_detected, 30)
    assert last_frame_detected(), (
        f"no /grasps for the last frame; volumes stamped {[stamp_ns(v) for v in volumes]}; tsdf log:\n"
        f"{tsdf.output()[-2000:]}\ndetect log:\n{detect.output()[-2000:]}")
    final = next(g for g in grasps if stamp_ns(g) == last_stamp)
    assert final.header.frame_id == "task" and final.model_name == "untrained.pt"
    assert 0 < len(final.grasps) <= 20
    scores = [g.gravity_rejection_score for g in final.grasps]
    assert scores == sorted(scores, reverse=True) and min(scores) > 0
    for g in final.grasps:
        p, q = g.pose.position, g.pose.orientation
        assert all(0.0 <= c <= 0.30 for c in (p.x, p.y, p.z)), "grasp outside the workspace"
        assert g.validness >= THRESHOLD
        assert np.linalg.norm([q.x, q.y, q.z, q.w]) == pytest.approx(1.0, abs=1e-6)
        # The TCP is the centre of its voxel.
        np.testing.assert_allclose([p.x, p.y, p.z], (np.array(g.voxel_index) + 0.5) * 0.0075, atol=1e-6)
        assert g.pregrasp_distance_m == pytest.approx(0.05)
    latency_s = final.detection_latency.sec + final.detection_latency.nanosec * 1e-9
    assert 0 < latency_s < 5
    detect.wait_for_output(r"grasps.*latency [0-9.]+ ms")

    # The published volume is the bag's scene: the table top (z = 0.05 m) lies between
    # k = 6 and k = 7 wherever both were observed.
    volume = next(v for v in volumes if stamp_ns(v) == last_stamp)
    assert volume.resolution == 40 and volume.voxel_size_m == pytest.approx(0.0075)
    grid = np.asarray(volume.tsdf, np.float32).reshape(40, 40, 40)
    weights = np.asarray(volume.weights, np.float32).reshape(40, 40, 40)
    assert (weights > 0).mean() > 0.5
    free_columns = np.ones((40, 40), bool)
    free_columns[8:40, 8:32] = False  # under and around the objects
    seen = free_columns & (weights[:, :, 6] > 0) & (weights[:, :, 7] > 0)
    assert seen.sum() > 200
    assert (grid[:, :, 6][seen] < 0.5).all() and (grid[:, :, 7][seen] >= 0.5).all()

    assert ros_testing.spin_until(ros_node, lambda: len(markers) > 0, 10)
    latest = markers[-1]
    assert latest.markers[0].action == latest.markers[0].DELETEALL
    outlines = latest.markers[1:]
    assert len(outlines) == len(grasps[-1].grasps) and all(m.type == m.LINE_LIST for m in outlines)
    # Coloured by score: the best grasp is green, the weakest the reddest.
    assert outlines[0].color.g == pytest.approx(1.0) and outlines[-1].color.r >= outlines[0].color.r
    assert tsdf.alive() and detect.alive()


def test_tsdf_with_static_extrinsic_parameter(ros_node, ros_process):
    """camera_pose_source:=parameter: no pose topic needed; the table lands at z = 0.05 m."""
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    # Looking straight down from 0.65 m above the cube's centre: 180 deg about x.
    tsdf = ros_process("gravgrasp_detector", "tsdf", params={
        "camera_pose_source": "parameter", "camera_pose": [0.15, 0.15, 0.65, 1.0, 0.0, 0.0, 0.0],
        "publish_rate_hz": 20.0})
    width, height, f = 80, 60, 60.0
    info = CameraInfo(width=width, height=height)
    info.k = [f, 0.0, (width - 1) / 2, 0.0, f, (height - 1) / 2, 0.0, 0.0, 1.0]
    depth = np.full((height, width), 600, np.uint16)  # 0.6 m in mm: table top at z = 0.05 m
    image = Image(width=width, height=height, encoding="16UC1", step=2 * width, data=depth.tobytes())
    volumes = collect(ros_node, TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    info_pub = ros_node.create_publisher(CameraInfo, "/depth/camera_info", qos_profile_sensor_data)
    image_pub = ros_node.create_publisher(Image, "/depth/image", qos_profile_sensor_data)
    assert ros_testing.wait_for_subscriber(ros_node, "/depth/image", 20)

    def publish_and_wait():
        info_pub.publish(info)
        image_pub.publish(image)
        return ros_testing.spin_until(ros_node, lambda: bool(volumes), 0.5)

    assert ros_testing.spin_until(ros_node, publish_and_wait, 20), tsdf.output()[-2000:]
    grid = np.asarray(volumes[-1].tsdf, np.float32).reshape(40, 40, 40)
    weights = np.asarray(volumes[-1].weights, np.float32).reshape(40, 40, 40)
    seen = (weights[:, :, 6] > 0) & (weights[:, :, 7] > 0)
    assert seen.sum() > 100
    assert (grid[:, :, 6][seen] < 0.5).all() and (grid[:, :, 7][seen] >= 0.5).all()


def test_detect_parameters_change_at_run_time(ros_node, ros_process, model_path):
    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    detect = ros_process("gravgrasp_detector", "detect", params={"model_path": str(model_path), "validness_threshold": THRESHOLD})
    pub = ros_node.create_publisher(TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    grasps = collect(ros_node, GraspArray, "/grasps")
    assert ros_testing.wait_for_subscriber(ros_node, "/tsdf", 30)
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7
    msg = TSDFVolumeMsg(resolution=40, voxel_size_m=0.0075, truncation_m=0.03)
    msg.header.frame_id = "task"
    msg.origin.orientation.w = 1.0
    msg.tsdf, msg.weights = grid.ravel(), (grid > 0).astype(np.float32).ravel()

    def detect_once():
        before = len(grasps)
        pub.publish(msg)
        assert ros_testing.spin_until(ros_node, lambda: len(grasps) > before, 20), detect.output()[-2000:]
        return grasps[-1].grasps

    assert len(detect_once()) == 20
    client = ros_node.create_client(SetParameters, "/detect/set_parameters")
    request = SetParameters.Request(parameters=[Parameter("max_grasps", value=3).to_parameter_msg()])
    assert ros_testing.call_service(ros_node, client, request).results[0].successful
    assert len(detect_once()) == 3
    # Out of the declared range: refused, the node keeps its value.
    request = SetParameters.Request(parameters=[Parameter("validness_threshold", value=1.5).to_parameter_msg()])
    assert not ros_testing.call_service(ros_node, client, request).results[0].successful
    best = max(g.gravity_rejection_score for g in detect_once())
    request = SetParameters.Request(parameters=[Parameter("min_score_n", value=float(best) + 1.0).to_parameter_msg()])
    assert ros_testing.call_service(ros_node, client, request).results[0].successful
    assert detect_once() == []  # nothing holds that much: an empty, still published, answer


def test_a_binary_model_publishes_nan_scores_ranked_by_validness(ros_node, ros_process, tmp_path):
    """A model trained with --target binary has no score in N (its score head is untrained):
    the node publishes gravity_rejection_score NaN, never its probability under a newton's
    name, ranks by validness and applies no min_score_n in N."""
    import math

    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg

    torch.manual_seed(0)
    path = tmp_path / "binary.pt"
    model_file.save_model(path, networks.GraspNet("ex-ez"), TSDFVolume(),
                          training_data={"target": "binary", "note": "untrained (test fixture)"})
    detect = ros_process("gravgrasp_detector", "detect", params={
        "model_path": str(path), "validness_threshold": THRESHOLD, "min_score_n": 1e4, "max_grasps": 10})
    pub = ros_node.create_publisher(TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    grasps = collect(ros_node, GraspArray, "/grasps")
    assert ros_testing.wait_for_subscriber(ros_node, "/tsdf", 30)
    detect.wait_for_output("no score in N, it publishes NaN", timeout_s=30)
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7
    msg = TSDFVolumeMsg(resolution=40, voxel_size_m=0.0075, truncation_m=0.03)
    msg.header.frame_id = "task"
    msg.origin.orientation.w = 1.0
    msg.tsdf, msg.weights = grid.ravel(), (grid > 0).astype(np.float32).ravel()
    pub.publish(msg)
    assert ros_testing.spin_until(ros_node, lambda: bool(grasps), 20), detect.output()[-2000:]
    published = grasps[-1].grasps
    assert len(published) == 10  # min_score_n 1e4 N does not apply to a probability
    assert all(math.isnan(g.gravity_rejection_score) for g in published)
    validness = [g.validness for g in published]
    assert validness == sorted(validness, reverse=True) and all(v >= THRESHOLD for v in validness)
