"""Bad input to the running tsdf and detect nodes: one message per cause, nodes keep answering.
Bad startup configuration: exit code 2 and one line."""
import re
import time

import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import model_file, networks
from gravgrasp_detector.perception.tsdf import TSDFVolume
from gravgrasp_detector.ros.tsdf_node import VOLUME_QOS

import ros_testing

W, H = 80, 60  # small images: every message fits one datagram, so best effort loses none
FX = 60.0


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "untrained.pt"
    model_file.save_model(path, networks.GraspNet(), TSDFVolume(), training_data={"note": "untrained test fixture"})
    return path


def stamp(n):
    from builtin_interfaces.msg import Time

    return Time(sec=1000 + n, nanosec=0)


def camera_info(width=W, height=H):
    from sensor_msgs.msg import CameraInfo

    info = CameraInfo(width=width, height=height)
    info.k = [FX, 0.0, (width - 1) / 2, 0.0, FX, (height - 1) / 2, 0.0, 0.0, 1.0]
    return info


def depth_image(n, depth, encoding="32FC1"):
    from sensor_msgs.msg import Image

    depth = np.asarray(depth)
    img = Image(height=depth.shape[0], width=depth.shape[1], encoding=encoding, is_bigendian=0)
    img.header.stamp = stamp(n)
    img.step = depth.shape[1] * depth.itemsize
    img.data = depth.tobytes()
    return img


def camera_pose(n, z=0.65):
    """Looking straight down at the workspace from height z."""
    from geometry_msgs.msg import PoseStamped

    pose = PoseStamped()
    pose.header.stamp, pose.header.frame_id = stamp(n), "task"
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 0.15, 0.15, z
    pose.pose.orientation.x, pose.pose.orientation.w = 1.0, 0.0  # 180 deg about x: optical z down
    return pose


def count(process, text):
    return process.output().count(text)


def publish_until_logged(node, process, publish, text, timeout_s=15.0):
    """Publish (a callable) until `text` appears in the process log, then twice more."""
    deadline = time.monotonic() + timeout_s
    while count(process, text) == 0:
        assert time.monotonic() < deadline, f"{text!r} never logged; log:\n{process.output()[-3000:]}"
        publish()
        ros_testing.spin_until(node, lambda: count(process, text) > 0, 0.5)
    for _ in range(2):
        publish()
        ros_testing.spin_until(node, lambda: False, 0.2)


def test_tsdf_node_reports_each_bad_input_once_and_keeps_answering(ros_node, ros_process):
    from geometry_msgs.msg import PoseStamped
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image
    from std_srvs.srv import SetBool, Trigger

    node = ros_node
    tsdf = ros_process("gravgrasp_detector", "tsdf", params={"sync_timeout_s": 0.3, "publish_rate_hz": 20.0})
    depth_pub = node.create_publisher(Image, "/depth/image", qos_profile_sensor_data)
    info_pub = node.create_publisher(CameraInfo, "/depth/camera_info", qos_profile_sensor_data)
    pose_pub = node.create_publisher(PoseStamped, "/camera_pose", qos_profile_sensor_data)
    volumes = []
    node.create_subscription(TSDFVolumeMsg, "/tsdf", volumes.append, VOLUME_QOS)
    for pub in (depth_pub, info_pub, pose_pub):
        assert ros_testing.wait_for_subscriber(node, pub.topic_name)
    good = np.full((H, W), 0.6, np.float32)  # table at z = 0.05 seen from 0.65 m

    # Depth before any CameraInfo.
    publish_until_logged(node, tsdf, lambda: depth_pub.publish(depth_image(0, good)), "no CameraInfo received on /depth/camera_info")

    n = iter(range(1, 10**6))

    def send(depth, encoding="32FC1", pose_z=0.65):
        i = next(n)
        info_pub.publish(camera_info())
        pose_pub.publish(camera_pose(i, pose_z))
        depth_pub.publish(depth_image(i, depth, encoding))

    cases = [
        (lambda: send(np.zeros((H, W, 3), np.uint8).reshape(H, W * 3), "rgb8"), "encoding is 'rgb8': publish 16UC1"),
        (lambda: send(np.full((H // 2, W // 2), 0.6, np.float32)), "depth image is 40x30 but CameraInfo says 80x60"),
        (lambda: send(np.full((H, W), np.nan, np.float32)), "depth image has no valid pixel"),
        (lambda: send(good, pose_z=12.0), "from the workspace centre"),
        (lambda: send(good, pose_z=-0.5), "the workspace is behind the camera"),
    ]
    for publish, text in cases:
        publish_until_logged(node, tsdf, publish, text)
    for _, text in cases:
        assert count(tsdf, text) == 1, f"{text!r} logged {count(tsdf, text)} times"
    assert not volumes, "a volume was published from bad input only"

    # Still answering: good input is fused and published, services respond.
    assert ros_testing.spin_until(node, lambda: (send(good), ros_testing.spin_until(node, lambda: bool(volumes), 0.5))[1], 15)
    weights = np.asarray(volumes[-1].weights).reshape(40, 40, 40)
    assert weights[:, :, 6].any() and not weights[:, :, :2].any()  # the table, nothing deep below it
    reset = node.create_client(Trigger, "/tsdf/reset")
    assert ros_testing.call_service(node, reset, Trigger.Request()).success
    toggle = node.create_client(SetBool, "/tsdf/set_integrating")
    assert ros_testing.call_service(node, toggle, SetBool.Request(data=False)).message == "paused"
    published = len(volumes)
    for _ in range(5):
        send(good)
        ros_testing.spin_until(node, lambda: False, 0.2)
    assert len(volumes) == published, "a paused tsdf node fused and published"
    assert ros_testing.call_service(node, toggle, SetBool.Request(data=True)).message == "integrating"
    assert ros_testing.spin_until(node, lambda: (send(good), ros_testing.spin_until(node, lambda: len(volumes) > published, 0.5))[1], 15)
    assert tsdf.alive()


def test_detect_node_reports_each_bad_volume_once_and_keeps_answering(ros_node, ros_process, model_path):
    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg

    node = ros_node
    detect = ros_process("gravgrasp_detector", "detect", params={"model_path": str(model_path), "validness_threshold": 0.49})
    pub = node.create_publisher(TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    grasps = []
    node.create_subscription(GraspArray, "/grasps", grasps.append, 10)
    assert ros_testing.wait_for_subscriber(node, "/tsdf", 30)

    def volume(resolution=40, values=None, weights=None):
        msg = TSDFVolumeMsg(resolution=resolution, voxel_size_m=0.3 / resolution, truncation_m=4 * 0.3 / resolution)
        msg.header.frame_id = "task"
        msg.origin.orientation.w = 1.0
        n = resolution**3
        msg.tsdf = np.zeros(n, np.float32) if values is None else values
        msg.weights = np.zeros(n, np.float32) if weights is None else weights
        return msg

    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7
    good = volume(values=grid.ravel(), weights=(grid > 0).astype(np.float32).ravel())
    cases = [
        (volume(), "TSDF volume is empty (no voxel ever observed)"),
        (volume(resolution=32), "TSDF does not match the model: resolution 32 (model: 40)"),
        (volume(values=np.zeros(1000, np.float32)), "TSDF volume has 1000 values and 64000 weights"),
    ]
    for msg, text in cases:
        publish_until_logged(node, detect, lambda: pub.publish(msg), text, timeout_s=30)
    pub.publish(good)
    assert ros_testing.spin_until(node, lambda: any(len(g.grasps) for g in grasps), 15), detect.output()[-2000:]
    for _, text in cases:
        assert count(detect, text) == 1, f"{text!r} logged {count(detect, text)} times"
    assert detect.alive()


def test_detect_processes_only_the_latest_volume(ros_node, ros_process, model_path):
    """A burst of volumes faster than detection: no queue; the newest one is always answered."""
    from gravgrasp_msgs.msg import GraspArray
    from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg

    node = ros_node
    detect = ros_process("gravgrasp_detector", "detect", params={"model_path": str(model_path), "validness_threshold": 0.49})
    pub = node.create_publisher(TSDFVolumeMsg, "/tsdf", VOLUME_QOS)
    grasps = []
    node.create_subscription(GraspArray, "/grasps", grasps.append, 100)
    assert ros_testing.wait_for_subscriber(node, "/tsdf", 30)
    assert ros_testing.wait_for_publisher(node, "/grasps", 30)
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7
    msg = TSDFVolumeMsg(resolution=40, voxel_size_m=0.0075, truncation_m=0.03)
    msg.header.frame_id = "task"
    msg.origin.orientation.w = 1.0
    msg.tsdf, msg.weights = grid.ravel(), (grid > 0).astype(np.float32).ravel()
    burst = 30
    for n in range(burst):
        msg.header.stamp = stamp(n)
        pub.publish(msg)
    last = stamp(burst - 1)
    assert ros_testing.spin_until(node, lambda: any(g.header.stamp == last for g in grasps), 30), detect.output()[-2000:]
    ros_testing.spin_until(node, lambda: False, 1.0)  # anything still queued would arrive now
    answered = [g.header.stamp.sec for g in grasps]
    assert answered == sorted(answered), "volumes answered out of order"
    assert len(answered) < burst, f"all {burst} volumes of a burst were processed: a queue, not latest-only"
    assert answered[-1] == last.sec


def _exit_line(process):
    code = process.wait_exit(60)
    lines = [line for line in process.output().splitlines() if line.strip()]
    return code, lines


@pytest.mark.parametrize("problem", ["missing", "corrupt", "mismatched"])
def test_detect_bad_model_file_exits_with_one_line(ros_process, tmp_path, problem):
    path = tmp_path / "model.pt"
    if problem == "corrupt":
        path.write_bytes(b"not a model" * 100)
    elif problem == "mismatched":
        model_file.save_model(path, networks.GraspNet("quat"), TSDFVolume())
        payload = torch.load(path, weights_only=True)
        payload["metadata"]["network"]["rotation_representation"] = "ex-ez"
        torch.save(payload, path)
    detect = ros_process("gravgrasp_detector", "detect", params={"model_path": str(path)})
    code, lines = _exit_line(detect)
    assert code == 2
    assert len(lines) == 1, lines
    expected = {"missing": "does not exist", "corrupt": "cannot be read", "mismatched": "weights do not match its metadata"}
    assert re.search(r"\[FATAL\].*\[detect\]: cannot start: model file .*" + expected[problem], lines[0])


def test_tsdf_bad_static_pose_exits_with_one_line(ros_process):
    tsdf = ros_process("gravgrasp_detector", "tsdf", params={
        "camera_pose_source": "parameter", "camera_pose": [0.15, 0.15, 0.65, 0.0, 0.0, 0.0, 2.0]})
    code, lines = _exit_line(tsdf)
    assert code == 2 and len(lines) == 1, lines
    assert "camera_pose parameter" in lines[0] and "unit quaternion" in lines[0]
