"""gravgrasp_msgs over real DDS between two processes, and rosbag2 record/replay."""
import subprocess
import sys

import pytest
from gravgrasp_msgs.msg import GraspArray
from gravgrasp_msgs.srv import ExecuteGrasp
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image

import interface_peer
from gravgrasp_detector.ros import bag_replay
from ros_testing import ROOT, call_service, spin_until


def _wire(msg) -> bytes:
    """CDR bytes: equal iff every field arrived exactly (float32 fields included)."""
    return serialize_message(msg)


@pytest.fixture
def peer(ros_process):
    proc = ros_process("tests", "interface_peer", cmd=[sys.executable, str(ROOT / "tests" / "support" / "interface_peer.py")])
    proc.wait_for_output("interface_peer ready")
    return proc


def test_grasp_array_round_trips_exactly_between_processes(ros_node, peer):
    received = []
    ros_node.create_subscription(GraspArray, "/peer/grasps", received.append, 10)
    assert spin_until(ros_node, lambda: received, timeout_s=20), "no GraspArray from the peer process"
    assert _wire(received[0]) == _wire(interface_peer.sample_grasp_array())
    assert received[0].grasps[4].voxel_index.tolist() == [4, 35, 65535]


def test_execute_grasp_service_round_trips(ros_node, peer):
    client = ros_node.create_client(ExecuteGrasp, "/peer/execute_grasp")
    request = ExecuteGrasp.Request()
    request.header.frame_id = "task"
    request.grasp = interface_peer.sample_grasp_array().grasps[2]
    response = call_service(ros_node, client, request, timeout_s=20)
    assert response.success and response.result_code == ExecuteGrasp.Response.SUCCESS
    assert response.message == "echo frame=task index=0"
    assert _wire(response.executed_grasp) == _wire(request.grasp)

    request.use_index, request.grasp_index = True, 3
    response = call_service(ros_node, client, request)
    assert not response.success and response.result_code == ExecuteGrasp.Response.INVALID_REQUEST
    assert response.message.endswith("index=3")


def _camera_frames(n):
    """n (Image, CameraInfo) pairs with distinct content per frame."""
    import numpy as np
    out = []
    for i in range(n):
        info = CameraInfo(width=64, height=48, distortion_model="plumb_bob")
        info.header.frame_id = "camera_optical"
        info.header.stamp.sec = 100 + i
        info.k = [50.0, 0.0, 32.0, 0.0, 50.0, 24.0, 0.0, 0.0, 1.0]
        depth = np.full((48, 64), 0.5 + 0.01 * i, dtype=np.float32)
        image = Image(height=48, width=64, encoding="32FC1", step=64 * 4, data=depth.tobytes())
        image.header = info.header
        out.append((image, info))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_rosbag_replay_delivers_every_message_in_order(ros_node, tmp_path, storage):
    frames = _camera_frames(6)
    grasps = interface_peer.sample_grasp_array()
    messages = []
    for i, (image, info) in enumerate(frames):
        t = (100 + i) * 10**9
        messages += [("/camera/depth/image_raw", image, t), ("/camera/depth/camera_info", info, t + 1)]
    messages.append(("/grasps", grasps, 200 * 10**9))
    bag = bag_replay.write_bag(tmp_path / "bag", messages, storage=storage)
    assert [m for _, m, _ in bag_replay.read_bag(bag)][-1].grasps[0].gravity_rejection_score == pytest.approx(42.5)

    received = []
    for topic, msg_type in [("/camera/depth/image_raw", Image), ("/camera/depth/camera_info", CameraInfo),
                            ("/grasps", GraspArray)]:
        ros_node.create_subscription(msg_type, topic, lambda m, t=topic: received.append((t, m)),
                                     qos_profile_sensor_data if msg_type is not GraspArray else 10)

    player = bag_replay.BagPlayer(ros_node, bag)
    assert player.wait_for_subscribers(player.publishers, timeout_s=20)
    # Let each message be received before the next goes out, so order is observable.
    played = player.play(on_message=lambda *_: spin_until(ros_node, lambda: False, timeout_s=0.02))
    assert played == len(messages)
    assert spin_until(ros_node, lambda: len(received) == len(messages), timeout_s=20), \
        f"received {len(received)} of {len(messages)}"
    assert [t for t, _ in received] == [t for t, _, _ in messages]
    assert [m.header.stamp.sec for t, m in received if t.endswith("image_raw")] == list(range(100, 106))
    assert bytes(received[2][1].data) == bytes(frames[1][0].data)
    assert _wire(received[-1][1]) == _wire(grasps)



def test_bag_play_names_a_missing_topic_and_a_damaged_bag_in_one_line(tmp_path):
    image, info = _camera_frames(1)[0]
    bag = bag_replay.write_bag(tmp_path / "bag", [("/camera/depth/image_raw", image, 10**9),
                                                  ("/camera/depth/camera_info", info, 10**9 + 1)])
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    (damaged / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9, storage_identifier: mcap")
    for args, expected in [([str(bag), "--rate", "0", "--topics", "/camera/depth/image_raw", "/depth"],
                            "has no topic /depth; its topics: /camera/depth/camera_info, /camera/depth/image_raw"),
                           ([str(damaged)], "cannot be read as a rosbag2 directory")]:
        run = subprocess.run([sys.executable, "-m", "gravgrasp_detector.ros.bag_replay", *args],
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 1, run.stderr
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("bag_play: ") and expected in lines[0], run.stderr
