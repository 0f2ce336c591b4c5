"""The ur_arm node over real DDS: move_to_pose and stop_motion as the sim bridge serves
them, served here by the node class with a recording stand-in of ur_rtde injected
(tests/support/fake_rtde.py); the executor (a real process) driving it through a grasp; and
the installed executable with the real ur_rtde against an address where no robot answers."""
import math
import threading

import numpy as np
import pytest
import rclpy.duration
from geometry_msgs.msg import PoseStamped
from gravgrasp_msgs.msg import Grasp
from gravgrasp_msgs.srv import ExecuteGrasp, MoveToPose
from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from fake_rtde import FakeURController
from gravgrasp_detector.ros.ur_arm_node import URArmNode
from ros_testing import call_spun as call
from ros_testing import wait_until


# The 2F-85's TCP at task (0.15, 0.15, 0.30), pointing down, for the node's default base
# (0.15, -0.45, 0): inside the protective box, which holds the hand at the start of a motion too.
START_IN_BASE = (0.0, 0.6, 0.3, math.pi, 0.0, 0.0)


def move_request(x, y, z, speed=0.1, frame="task", check_only=False):
    request = MoveToPose.Request(speed_mps=float(speed), check_only=check_only)
    request.target.header.frame_id = frame
    p, q = request.target.pose.position, request.target.pose.orientation
    p.x, p.y, p.z = float(x), float(y), float(z)
    q.x, q.w = 1.0, 0.0  # TCP z pointing down
    return request


@pytest.fixture
def served(ros_node):
    """URArmNode with the stand-in controller, spun with the test's client node."""
    ur = FakeURController(tcp_pose=START_IN_BASE)
    ur.time_scale = 0.3
    arm_node = URArmNode(connect=ur.connect, parameter_overrides=[
        Parameter("call_timeout_s", value=2.0), Parameter("motion_timeout_margin_s", value=2.0),
        Parameter("reconnect_period_s", value=0.2), Parameter("tcp_in_flange", value=[0.0, 0.0, 0.1558, 0.0, 0.0, 0.0])])
    executor = MultiThreadedExecutor(num_threads=6)
    executor.add_node(arm_node)
    executor.add_node(ros_node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    assert wait_until(lambda: arm_node.arm.connected, 10), "the node did not connect to the stand-in"
    yield {"ur": ur, "node": ros_node, "arm_node": arm_node}
    executor.shutdown()
    arm_node.close()
    arm_node.destroy_node()


def test_move_stop_and_refusals_over_dds(served):
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    stop = node.create_client(Trigger, "stop_motion")
    ok = call(move, move_request(0.15, 0.15, 0.20, speed=0.25))
    assert ok.reachable and ok.success, ok.message
    assert len(ok.joint_positions) == 6
    pose = ur.called("moveL")[-1][0]
    # Default base (0.15, -0.45, 0), yaw 0: the task point is 0.6 m along the base's y.
    np.testing.assert_allclose(pose[:3], [0.0, 0.6, 0.2], atol=1e-9)

    out = call(move, move_request(0.15, 0.15, 0.90))
    assert not out.reachable and "outside the protective box" in out.message
    frame = call(move, move_request(0.15, 0.15, 0.2, frame="base_link"))
    assert not frame.reachable and frame.message.startswith("rejected: target frame 'base_link'")
    check = call(move, move_request(0.15, 0.10, 0.20, check_only=True))
    assert check.reachable and not check.success
    moves = len(ur.called("moveL"))
    assert moves == 1, "refusals and check_only must not move"
    # flange_pose: the flange 0.1558 m above the TCP that points down (calibrate_camera's input).
    flange = {}
    node.create_subscription(PoseStamped, "flange_pose", lambda m: flange.setdefault("m", m), 10)
    assert wait_until(lambda: "m" in flange, 10), "no flange_pose"
    p = flange["m"].pose.position
    assert flange["m"].header.frame_id == "task"
    np.testing.assert_allclose([p.x, p.y, p.z], [0.15, 0.15, 0.20 + 0.1558], atol=1e-6)

    assert call(stop, Trigger.Request()).message == "no motion was running"
    results = {}
    worker = threading.Thread(target=lambda: results.setdefault("r", call(move, move_request(0.15, 0.15, 0.45, speed=0.02))))
    worker.start()
    assert wait_until(lambda: len(ur.called("moveL")) == 2, 10)
    stopped = call(stop, Trigger.Request())
    worker.join(10)
    assert stopped.success and stopped.message == "motion stopped"
    assert not results["r"].success and "stopped by stop_motion" in results["r"].message, results["r"].message
    assert ur.called("stopL")


def test_lost_link_is_answered_then_the_node_reconnects(served):
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    ur.lose_link_after_s = 0.05
    lost = call(move, move_request(0.15, 0.15, 0.40, speed=0.05))
    assert not lost.success and lost.message.startswith("arm connection lost"), lost.message
    ur.lose_link_after_s = None
    assert wait_until(lambda: ur.connects >= 2 and served["arm_node"].arm.connected, 10), "no reconnect"
    again = call(move, move_request(0.15, 0.15, 0.30, speed=0.25))
    assert again.success, again.message


def test_a_stale_request_is_refused_and_a_late_motion_stopped_by_its_deadline(served):
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    stale = move_request(0.15, 0.15, 0.25)
    stale.deadline = (node.get_clock().now() - rclpy.duration.Duration(seconds=1.0)).to_msg()
    out = call(move, stale)
    assert not out.reachable and "deadline passed" in out.message and ur.called("moveL") == [], out.message
    slow = move_request(0.15, 0.15, 0.40, speed=0.02)  # 4 s at time_scale 0.3
    slow.deadline = (node.get_clock().now() + rclpy.duration.Duration(seconds=0.8)).to_msg()
    cut = call(move, slow)
    assert not cut.success and "stopped at the request's deadline" in cut.message, cut.message


def test_a_motion_nobody_asked_for_is_stopped_by_the_nodes_state_timer(served):
    """The node runs URArm.watch() at state_rate_hz: a move the given-up interface sends
    again after ur_rtde's own reconnect (modelled by a second control interface) is halted
    and latched without any request."""
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    assert call(move, move_request(0.15, 0.15, 0.25, speed=0.25)).success
    stale, _ = ur.connect()  # another interface on the controller, as a given-up one
    start = len(ur.motions)
    assert stale.moveL(ur.tcp_pose_in([0.0] * 6)[:2] + [0.45, math.pi, 0.0, 0.0], 0.02, 0.5, True)  # flange up 44 mm
    assert wait_until(lambda: served["arm_node"].arm.latched == "a motion no request asked for", 10), "not latched"
    assert wait_until(lambda: not ur.motion_running, 2)
    assert ur.travelled_m(ur.motions[start]) < 0.01
    refused = call(move, move_request(0.15, 0.15, 0.30, speed=0.25))
    assert not refused.success and "a motion no request asked for is latched" in refused.message, refused.message


def test_emergency_stop_topic_halts_and_latches_until_armed(served):
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    arm = node.create_client(SetBool, "ur_arm/arm")
    estop = node.create_publisher(Bool, "emergency_stop", 10)
    assert wait_until(lambda: estop.get_subscription_count() >= 1, 10), "ur_arm does not listen to emergency_stop"
    results = {}
    worker = threading.Thread(target=lambda: results.setdefault("r", call(move, move_request(0.15, 0.15, 0.45, speed=0.02))))
    worker.start()
    assert wait_until(lambda: len(ur.called("moveL")) == 1, 10)
    estop.publish(Bool(data=True))
    worker.join(10)
    assert "motion stopped by the emergency stop" in results["r"].message, results["r"].message
    latched = call(move, move_request(0.15, 0.15, 0.30, speed=0.25))
    assert not latched.success and "is latched" in latched.message and len(ur.called("moveL")) == 1, latched.message
    armed = call(arm, SetBool.Request(data=True))
    assert armed.success and armed.message.startswith("armed"), armed.message
    assert call(move, move_request(0.15, 0.15, 0.30, speed=0.25)).success


def test_a_cleared_protective_stop_is_recovered_without_any_call(served):
    ur, node = served["ur"], served["node"]
    move = node.create_client(MoveToPose, "move_to_pose")
    ur.protective_stop_after_s = 0.05
    hit = call(move, move_request(0.15, 0.15, 0.40, speed=0.05))
    assert hit.message.startswith("PROTECTIVE_STOP during the motion"), hit.message
    ur.protective_stop_after_s = None
    ur.clear_protective_stop()
    # reconnect_period_s 0.2: the node's own timer restarts the control script
    assert wait_until(lambda: ur.program_running and ur.called("reuploadScript"), 10), "control was not restored"
    assert ur.connects == 1
    assert call(move, move_request(0.15, 0.15, 0.30, speed=0.25)).success


def top_down_grasp(x=0.15, y=0.15, z=0.08) -> Grasp:
    g = Grasp()
    g.pose.position.x, g.pose.position.y, g.pose.position.z = x, y, z
    g.pose.orientation.x, g.pose.orientation.w = 1.0, 0.0
    g.gravity_rejection_score, g.validness = 20.0, 0.9
    return g


def test_the_executor_grasps_through_the_ur_adapter(served, ros_process, tmp_path):
    """execute (a process) -> move_to_pose -> ur_arm -> the controller stand-in; the
    gripper is the 2F-85 emulator on a pty holding a 5 cm object."""
    ur, node = served["ur"], served["node"]
    link = str(tmp_path / "ttyGripper")
    ros_process("robotiq_driver", "gripper_emulator",
                args=["--link", link, "--object-width-m", "0.05", "--activation-time-s", "0.1"])
    # No camera here (max_tsdf_age_s 0), and the emulator always holds its 5 cm object, so
    # the executor gets a stored empty-closed calibration instead of measuring one.
    execute = ros_process("gravgrasp_detector", "execute",
                          params={"gripper_port": link, "check_ik": True, "tcp_offset_m": 0.1558,
                                  "max_tsdf_age_s": 0.0, "gripper_empty_closed_m": 0.0})
    execute.wait_for_output("execute ready", timeout_s=60)
    assert call(node.create_client(SetBool, "execute/arm"), SetBool.Request(data=True), resend_s=5.0).success
    request = ExecuteGrasp.Request()
    request.header.frame_id, request.grasp = "task", top_down_grasp()
    result = call(node.create_client(ExecuteGrasp, "execute_grasp"), request, timeout_s=120)
    assert result.result_code == ExecuteGrasp.Response.SUCCESS, result.message
    targets = [args[0] for args in ur.called("moveL")]
    heights = [round(p[2], 3) for p in targets]
    print(f"moveL targets (base frame): {[np.round(p[:3], 3).tolist() for p in targets]}")
    assert heights[:3] == [0.13, 0.08, 0.23], heights  # pre-grasp 5 cm above, grasp, lift 15 cm
    assert all(np.allclose(p[:2], [0.0, 0.6]) for p in targets[:3])


def test_installed_executable_without_a_robot(ros_process, ros_node):
    """The real ur_rtde against loopback, where no controller listens: the node says so,
    keeps serving, and answers requests with the reason."""
    empty = ros_process("gravgrasp_detector", "ur_arm")
    assert empty.wait_exit(30) == 2
    assert "robot_ip is empty" in empty.output()

    node = ros_process("gravgrasp_detector", "ur_arm",
                       params={"robot_ip": "127.0.0.1", "reconnect_period_s": 1.0})
    node.wait_for_output("ur_arm ready", timeout_s=30)
    line = node.wait_for_output(r"cannot reach the UR controller at 127\.0\.0\.1: .*", timeout_s=30).group(0)
    print(line)
    assert "Could not connect" in line and "Remote Control" in line
    move = ros_node.create_client(MoveToPose, "move_to_pose")
    from ros_testing import call_service
    answer = call_service(ros_node, move, move_request(0.15, 0.15, 0.2), timeout_s=30, resend_s=5.0)  # no robot: safe to repeat
    assert not answer.success and answer.message.startswith("arm connection lost"), answer.message
    assert node.alive()


def test_flange_pose_base_only_while_the_pendants_tcp_is_tcp_in_flange(ros_node):
    """Pendant in Local mode (monitoring only): calibrate_camera's robot poses come in the
    base frame, and none while the controller's TCP is not tcp_in_flange."""
    ur = FakeURController()
    ur.control_unavailable = True
    arm_node = URArmNode(connect=ur.connect, parameter_overrides=[
        Parameter("reconnect_period_s", value=0.2), Parameter("base_xyz_yaw", value=[0.15, -0.45, 0.0, 0.0])])
    seen = {"base": [], "task": []}
    ros_node.create_subscription(PoseStamped, "flange_pose_base", seen["base"].append, 10)
    ros_node.create_subscription(PoseStamped, "flange_pose", seen["task"].append, 10)
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(arm_node)
    executor.add_node(ros_node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: arm_node.arm.receiving and len(ur.called("getActualQ")) > 5, 15)
        assert seen["base"] == [] and seen["task"] == [], "a wrong TCP gives no flange pose"
        ur.controller_tcp = [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]  # set on the pendant
        assert wait_until(lambda: seen["base"] and seen["task"], 15), "no flange pose once the TCP is right"
        base, task = seen["base"][-1], seen["task"][-1]
        assert base.header.frame_id == "base" and task.header.frame_id == "task"
        p, t = base.pose.position, task.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], [0.4, 0.0, 0.4 + 0.1558], atol=1e-9)
        np.testing.assert_allclose([t.x, t.y, t.z], [0.4 + 0.15, -0.45, 0.4 + 0.1558], atol=1e-9)
    finally:
        executor.shutdown()
        arm_node.close()
        arm_node.destroy_node()
