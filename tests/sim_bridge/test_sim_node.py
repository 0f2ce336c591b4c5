"""The installed sim bridge (`ros2 run sim_bridge sim`) as a real process: camera topics over
DDS, the arm interface, and the emulated 2F-85 over Modbus RTU on its pty."""
import math
import os

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from gravgrasp_msgs.msg import ObjectStates
from gravgrasp_msgs.srv import LoadScene, MoveToPose, RemoveObject, SetObjectMass
from rclpy.duration import Duration
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import SetBool, Trigger

from robotiq_driver.gripper_client import GripperLinkError, Robotiq2F85
from robotiq_driver.modbus_client import ModbusTimeout
from ros_testing import call_service, spin_until

pytestmark = pytest.mark.drake


def target(x, y, z, frame="task", q=(1.0, 0.0, 0.0, 0.0)):
    """TCP pose; the default quaternion (x, y, z, w) = (1, 0, 0, 0) points the hand down."""
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


def test_sim_node_camera_arm_and_gripper(ros_node, ros_process, tmp_path):
    link = tmp_path / "ttySimGripper"
    sim = ros_process("sim_bridge", "sim", params={
        "n_objects": 1, "seed": 1, "gripper_link": str(link), "publish_rate_hz": 4.0,
        "depth_encoding": "16UC1"})
    sim.wait_for_output(r"sim ready: gripper on \S+", timeout_s=90)
    assert os.path.islink(link)

    got, all_states, info_stamps = {}, [], []
    ros_node.create_subscription(ObjectStates, "object_states", all_states.append, 10)
    ros_node.create_subscription(CameraInfo, "depth/camera_info", lambda m: info_stamps.append(m.header.stamp),
                                 qos_profile_sensor_data)
    for name, kind, qos in (("depth/image", Image, qos_profile_sensor_data),
                            ("depth/camera_info", CameraInfo, qos_profile_sensor_data),
                            ("camera_pose", PoseStamped, qos_profile_sensor_data),
                            ("object_states", ObjectStates, 10)):
        ros_node.create_subscription(kind, name, lambda m, n=name: got.__setitem__(n, m), qos)
    assert spin_until(ros_node, lambda: len(got) == 4, 30), f"received only {sorted(got)}"
    image, info = got["depth/image"], got["depth/camera_info"]
    assert (image.encoding, image.width, image.height) == ("16UC1", info.width, info.height)
    depth_mm = np.frombuffer(bytes(image.data), np.uint16).reshape(image.height, image.width)
    assert 300 < np.median(depth_mm) < 1500  # the table, 0.3-1.5 m away
    # Each image has a CameraInfo of the same stamp (the latest of each can be a frame
    # apart: on a loaded machine the next frame's CameraInfo may arrive before its image).
    assert info.k[0] > 0
    assert spin_until(ros_node, lambda: image.header.stamp in info_stamps, 10), (image.header.stamp, info_stamps[-3:])
    assert got["camera_pose"].header.frame_id == "task"
    states = got["object_states"]
    assert len(states.names) == 1 and not states.lifted[0] and not states.out_of_workspace[0]

    move = ros_node.create_client(MoveToPose, "move_to_pose")

    def call(pose, speed=0.25, check_only=False):
        return call_service(ros_node, move, MoveToPose.Request(target=pose, speed_mps=speed,
                                                               check_only=check_only), timeout_s=60)

    far = call(target(2.0, 0.15, 0.4), check_only=True)
    assert not far.reachable and not far.success and "outside" in far.message
    assert math.isnan(far.distance_left_m) and not far.stopped_by_contact  # nothing moved
    near = call(target(0.15, 0.15, 0.45), check_only=True)
    assert near.reachable and not near.success
    moved = call(target(0.15, 0.15, 0.45))
    assert moved.reachable and moved.success, moved.message
    assert moved.distance_left_m == 0.0 and not moved.stopped_by_contact
    # a slow motion, halted from another call (the executor's emergency stop would)
    future = move.call_async(MoveToPose.Request(target=target(0.15, 0.15, 0.30), speed_mps=0.02))
    stop = ros_node.create_client(Trigger, "stop_motion")
    stopped = None
    while stopped is None or not stopped.success:  # until the motion has started
        assert not future.done(), future.result()
        stopped = call_service(ros_node, stop, Trigger.Request())
    assert spin_until(ros_node, future.done, 15)
    assert not future.result().success and future.result().message == "stopped on request"
    # stopped on the way (the stop can land before the reference has moved: all 0.15 m left)
    assert 0.0 < future.result().distance_left_m <= 0.15 + 1e-9 and not future.result().stopped_by_contact
    # the request's deadline, as ur_arm keeps it: a stale request is refused, a late motion stopped
    stale = MoveToPose.Request(target=target(0.15, 0.15, 0.45), speed_mps=0.25)
    stale.deadline = (ros_node.get_clock().now() - Duration(seconds=1.0)).to_msg()
    refused = call_service(ros_node, move, stale, timeout_s=60)
    assert not refused.reachable and "deadline passed" in refused.message and math.isnan(refused.distance_left_m)
    late = MoveToPose.Request(target=target(0.25, 0.15, 0.40), speed_mps=0.02)  # >= 0.1 m away: > 9 s
    late.deadline = (ros_node.get_clock().now() + Duration(seconds=3.0)).to_msg()  # a slow DDS call still arrives in time
    cut = call_service(ros_node, move, late, timeout_s=60)
    assert not cut.success and "stopped at the request's deadline" in cut.message, cut.message
    assert 0.0 < cut.distance_left_m < 0.2
    nan = call(target(math.nan, 0.15, 0.45))
    assert not nan.success and "NaN" in nan.message
    frame = call(target(0.15, 0.15, 0.45, frame="base_link"))
    assert not frame.success and "frame 'base_link' is unknown" in frame.message
    skewed = call(target(0.15, 0.15, 0.45, q=(1.0, 1.0, 0.0, 0.0)))
    assert not skewed.success and "unit quaternion" in skewed.message

    mass = call_service(ros_node, ros_node.create_client(SetObjectMass, "set_object_mass"),
                        SetObjectMass.Request(name="no_such_object", mass_kg=1.0))
    assert not mass.success and "no object named 'no_such_object'" in mass.message
    load = ros_node.create_client(LoadScene, "load_scene")
    bad_scene = call_service(ros_node, load, LoadScene.Request(seed=1, n_objects=1, arrangement="heap"), timeout_s=30)
    assert not bad_scene.success and "arrangement 'heap'" in bad_scene.message
    scene = call_service(ros_node, load, LoadScene.Request(seed=24, n_objects=1, arrangement="packed",
                                                           object_mass_kg=0.8), timeout_s=60)
    assert scene.success and scene.object_names == ["obj000_cylinder"], scene.message
    removed = call_service(ros_node, ros_node.create_client(RemoveObject, "remove_object"),
                           RemoveObject.Request(name="obj000_cylinder"))
    assert removed.success, removed.message
    n = len(all_states)
    assert spin_until(ros_node, lambda: len(all_states) > n + 1, 15)
    assert list(all_states[-1].names) == []

    # the emulated 2F-85, exactly as a real one: nothing between the fingers, and they
    # stop where the pads meet (~1.1 mm) reporting an object, as a real 2F-85 can
    # 0.5 s per answer: the emulated 2F-85 answers from the sim process, which a loaded
    # CI machine can keep busy longer than a real one's 0.1 s default allows.
    with Robotiq2F85(str(link), timeout_s=0.5) as gripper:
        gripper.activate(timeout_s=10.0)
        state = gripper.move_and_wait(0.0, speed_mps=0.15, force_n=40.0, timeout_s=10.0)
        assert state.object_detected and gripper.width_m(state) == pytest.approx(0.0011, abs=1e-3)
        state = gripper.move_and_wait(0.085, speed_mps=0.15, force_n=40.0, timeout_s=10.0)
        assert gripper.width_m(state) == pytest.approx(0.085, abs=1e-3)
        # the test hooks: a gripper fault, and a gripper that stops answering
        fault = call_service(ros_node, ros_node.create_client(Trigger, "inject_gripper_fault"), Trigger.Request())
        assert fault.success and gripper.read_state().fault == 0x0E
        silent = ros_node.create_client(SetBool, "set_gripper_silent")
        assert call_service(ros_node, silent, SetBool.Request(data=True)).success
        with pytest.raises(GripperLinkError) as error:
            gripper.read_state()
        assert isinstance(error.value.__cause__, ModbusTimeout)
        assert call_service(ros_node, silent, SetBool.Request(data=False)).success
        assert gripper.read_state().fault == 0x0E

    assert sim.alive()
    assert sim.stop() == 0
    assert not os.path.lexists(link)  # the pty link goes with the node


def test_grasp_and_lift_through_ros_and_modbus(ros_node, ros_process, tmp_path):
    """What the executor does, by hand: arm over DDS, gripper over Modbus RTU, ground
    truth says the object left the table in the hand. Seed 24 draws one upright
    cylinder, 50 mm across and 143 mm tall."""
    link = tmp_path / "ttySimGripper"
    sim = ros_process("sim_bridge", "sim", params={
        "n_objects": 1, "seed": 24, "object_mass_kg": 0.5, "gripper_link": str(link)})
    sim.wait_for_output(r"sim ready: gripper on \S+", timeout_s=90)
    states = []
    ros_node.create_subscription(ObjectStates, "object_states", states.append, 10)
    assert spin_until(ros_node, lambda: states, 30)
    (name,) = states[-1].names
    assert states[-1].mass_kg[0] == pytest.approx(0.5)
    p = states[-1].poses[0].position
    top = p.z + 0.143 / 2
    move = ros_node.create_client(MoveToPose, "move_to_pose")

    def go(z, speed=0.25):
        response = call_service(ros_node, move, MoveToPose.Request(
            target=target(p.x, p.y, z), speed_mps=speed), timeout_s=60)
        assert response.success, response.message

    # 0.5 s per answer: the emulated 2F-85 answers from the sim process, which a loaded
    # CI machine can keep busy longer than a real one's 0.1 s default allows.
    with Robotiq2F85(str(link), timeout_s=0.5) as gripper:
        gripper.activate(timeout_s=10.0)
        go(top + 0.07)
        go(top - 0.03)
        state = gripper.move_and_wait(0.0, speed_mps=0.15, force_n=60.0, timeout_s=10.0)
        assert state.object_detected, state
        assert gripper.width_m(state) == pytest.approx(0.05, abs=0.005)
        go(top + 0.10)
        assert gripper.read_state().object_detected  # still holding
    n = len(states)
    assert spin_until(ros_node, lambda: len(states) > n + 1, 15)
    last = states[-1]
    assert last.names == [name] and last.in_hand[0] and last.lifted[0], last
    assert last.poses[0].position.z - p.z > 0.12  # of the 0.13 m lift
